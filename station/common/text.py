"""Text a unit supplies (its serial, model, firmware), made safe to show an operator.

A unit's DEVICE_INFO is whatever its firmware, or a faulty link, sends: an escape sequence in a
serial number would clear the operator's screen or retitle the terminal, a bidirectional override
would show the text reversed, Rich markup would restyle a TUI table. Everything printed from a
unit goes through :func:`printable` (the files the station writes escape in their own syntax: C
string literals, YAML and JSON quoting, ``#`` comments); text placed inside a Rich markup string
goes through :func:`station.console.markup.markup_safe`, which also escapes the markup.
"""

from __future__ import annotations

MAX_CHARS = 120
"""A value shown in a line of text: a serial, a name, a file name."""
PATH_CHARS = 4096
"""A file name, shown whole (Linux's PATH_MAX): cut at ``MAX_CHARS`` it would no longer say which file."""
MAX_MESSAGE = 6000
"""A whole message that holds values (an error, a warning): room for a file name or two and what is
wrong, short enough that a 60,000-character value in it does not flood the terminal."""


def printable(value: object, max_chars: int = MAX_CHARS, escape_backslash: bool = True) -> str:
    """``value`` as one line of visible text: every character that is not printable (control
    characters, format characters such as bidirectional overrides, line separators) and the
    backslash become Python-style escapes (``\\x1b``, ``\\u202e``), so the text shows what was sent.

    Parameters
    ----------
    value : object
        What the unit reported (``str()`` of it when it is not text).
    max_chars : int
        Longer results are cut and end with ``...``.
    escape_backslash : bool
        False for a message the station composed, whose values are already escaped (``repr()``,
        or :func:`printable` itself): its backslashes are left as they are, so an escape is not
        escaped twice; a control character left in it is still escaped.

    Returns
    -------
    str
        Text without a control character, safe on a terminal. Rich markup is not escaped: show it
        as ``rich.text.Text(printable(value))``, never as a markup string.
    """
    text = value if isinstance(value, str) else str(value)
    plain = "" if escape_backslash else "\\"
    if not (text.isprintable() and (plain or "\\" not in text)):
        text = "".join(ch if (ch.isprintable() and ch != "\\") or ch == plain else _escape(ch) for ch in text)
    return text if len(text) <= max_chars else text[: max_chars - 3] + "..."


def printable_message(message: object) -> str:
    """A message the station composed (an error, a warning) with values in it, made safe to print:
    :func:`printable` up to ``MAX_MESSAGE`` characters, its backslashes left as they are.

    Parameters
    ----------
    message : object
        The message, or the exception that carries it.

    Returns
    -------
    str
        One line without a control character.
    """
    return printable(message, MAX_MESSAGE, escape_backslash=False)


def _escape(ch: str) -> str:
    code = ord(ch)
    if ch == "\\":
        return "\\\\"
    if code <= 0xFF:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}"
