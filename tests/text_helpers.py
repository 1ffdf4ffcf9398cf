"""Hostile text for the tests that show nothing from a unit, a plan, a record or a file name reaches a
terminal raw (``tests/test_device_text.py``, ``tests/test_hostile_text.py``), and the checks they share."""

from __future__ import annotations

import re

CLEAR = "\x1b[2J\x1b[H"  # clears the screen
TITLE = "\x1b]0;pwned\x07"  # retitles the terminal (OSC 0)
RLO = "\u202e"  # shows what follows reversed
C1 = "\x9b31m"  # CSI as one C1 byte: red text on terminals that take 8-bit controls
CLOSE = "[/]"  # closes a Rich tag that is not open: MarkupError
LINK = "[link=file:///etc/passwd]x[/link]"  # a terminal hyperlink to a local file (OSC 8)
SPOOF = "[reverse]PASS[/]"  # a styled outcome that was not the station's
MARKUP = (CLOSE, LINK, SPOOF)
CONTROLS = (CLEAR, TITLE, RLO, C1)
HOSTILE = f"h{CLEAR}{TITLE}{RLO}{C1}{CLOSE}{LINK}{SPOOF}"
"""Every attack of the audit in one string (it holds ``/``, so it cannot be one file name)."""

# Control characters a terminal acts on: C0 but tab and newline, DEL, C1, and the bidirectional overrides.
CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]")
# What a terminal does with Rich's own output: styles (SGR), line erasing and cursor moves of live displays.
_RICH_CSI = re.compile(r"\x1b\[[0-9;?]*[mKAGhlD]|\r")
# Sequences no station output holds of its own: clear screen, titles, hyperlinks, reverse video.
FOREIGN = ("\x1b[2J", "\x1b]", "\x1b[7m", "\x9b", "\u202e", "\x07")


def raw_attacks(text: str) -> list[str]:
    """The hostile sequences ``text`` holds as a terminal would take them (empty when none)."""
    return [seq for seq in FOREIGN if seq in text]


def without_styles(text: str) -> str:
    """``text`` without the control sequences Rich writes to a terminal (styles, live-display moves)."""
    return _RICH_CSI.sub("", text)
