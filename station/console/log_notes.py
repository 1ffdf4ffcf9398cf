"""The notes of a capture read from a PX4 or ArduPilot log, one line each on stderr.

Every command that reads a capture prints them before its results: the IMU read with its true rate
and gaps, and what was converted or taken out of the autopilot's samples
(:mod:`station.acquisition.autopilot_log`).
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from pathlib import Path
from typing import IO


def print_log_notes(path: str | Path, notes: Iterable[str], file: IO[str] | None = None) -> None:
    """Print ``notes`` as ``PATH: note`` lines (nothing for a capture that is not from a log).

    Parameters
    ----------
    path : str or Path
        The log, as the user named it.
    notes : iterable of str
        :func:`station.acquisition.autopilot_log.log_notes` of the capture.
    file : text stream, optional
        Default ``sys.stderr``.
    """
    from station.common.text import PATH_CHARS, printable

    out = file if file is not None else sys.stderr
    # a phase line ("reading LOG ...") may stand on a terminal's last line: start the notes on a clean one
    clear = "\r\x1b[K" if out.isatty() else ""
    for note in notes:
        print(f"{clear}{printable(path, PATH_CHARS)}: {printable(note, 400)}", file=out, flush=True)
        clear = ""
