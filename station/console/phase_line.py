"""A one-line phase display (``reading x.csv ...``, ``calibrating ...``) for a command that works for a
second or two: plain text rewritten in place on a terminal, nothing at all when stderr is not one.

It costs no import and no thread, where rich's progress bar loads rich (20 ms of the calibrate
command's start-up, docs/methods/speed.md); captures, whose lines update live, keep
station.console.status_line.
"""

from __future__ import annotations

from typing import IO

from station.common.text import printable

CLEAR = "\r\x1b[K"  # back to the start of the line, erase to its end


class PhaseLine:
    """The phase of a command on one line of ``err`` while the context is open, erased when it closes.

    Parameters
    ----------
    err : text stream
        Where the line is written; a stream that is not a terminal gets nothing.
    """

    def __init__(self, err: IO[str]):
        self._err = err
        self._shown = err.isatty()

    def __enter__(self) -> PhaseLine:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._shown:
            self._err.write(CLEAR)
            self._err.flush()

    def show(self, phase: str) -> None:
        """Replace the line with ``phase`` (file names from the command line are shown escaped).

        Parameters
        ----------
        phase : str
            What the command does now, e.g. ``reading session.csv``.
        """
        if self._shown:
            self._err.write(f"{CLEAR}{printable(phase)} ...")
            self._err.flush()
