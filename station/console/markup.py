"""Data shown inside Rich markup: printable, and its markup escaped."""

from __future__ import annotations

from rich.markup import escape

from station.common.text import MAX_CHARS, printable


def markup_safe(value: object, max_chars: int = MAX_CHARS) -> str:
    """:func:`~station.common.text.printable` with Rich markup escaped too, for data (a unit's
    serial, a plan or station name, a record's reason, a file name) placed inside a markup string:
    ``[link=...]`` or ``[/]`` in the data shows as typed instead of styling the terminal or failing
    to parse.

    Parameters
    ----------
    value : object
        What a unit, a plan, a record or the operator supplied.
    max_chars : int
        Longer results are cut and end with ``...`` (before the markup escapes are added).

    Returns
    -------
    str
        Text safe to interpolate into Rich markup.
    """
    return escape(printable(value, max_chars))
