"""Saving the TUI's results: sections merged into a parameter file, and the file a hang-up leaves."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from station.export.params.file import ParamsFile, merge_sections

REPLACE_KEY = "r"
"""The key that starts a parameter file of another unit afresh, in the TUI's question."""


def save_sections(path: Path, device: dict[str, Any], sections: dict[str, Any], *,
                  capture: Path | None = None, replace: bool = False) -> None:
    """Merge ``sections`` (``accel``, ``gyro``, ``noise``, ``thermal``) into the file at ``path``, as
    the commands do (:func:`~station.export.params.file.merge_sections`): the file's other sections
    are kept, a section given as None is left as it is, each written section records its source.

    Parameters
    ----------
    path : Path
        The parameter file (created when missing).
    device : dict
        What is known of the unit (serial, model, firmware).
    sections : dict
        The sections to write, by name.
    capture : Path, optional
        The capture file the sections were computed from.
    replace : bool
        Start the file afresh (the operator answered :data:`REPLACE_KEY`).

    Raises
    ------
    UnitMismatchError
        The file holds another unit's results; it is left untouched.
    StationError
        The existing file cannot be read, or the new one cannot be written.
    """
    merge_sections(path, device, sections, capture=capture, replace=replace,
                   option=f"{REPLACE_KEY} (replace) in the question")


def existing_section(path: Path | None, name: str) -> bool:
    """True when the parameter file at ``path`` exists and already holds section ``name``.

    Parameters
    ----------
    path : Path or None
        The parameter file, None when there is none.
    name : str
        The section (``noise``, ``thermal``, ...).

    Returns
    -------
    bool
    """
    if path is None or not Path(path).exists():
        return False
    return getattr(ParamsFile.load(path), name) is not None


def recovery_path(out: Path | None, now: float | None = None) -> Path:
    """Where results go when the terminal closes before the operator chose: beside ``--out`` (never
    onto it: nobody said yes), else in the working folder; stamped with the UTC time.

    Parameters
    ----------
    out : Path or None
        The ``--out`` parameter file.
    now : float, optional
        The time to stamp (default: now).

    Returns
    -------
    Path
    """
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(now))
    if out is None:
        return Path(f"imu-station-unsaved-{stamp}.yaml")
    return out.with_name(f"{out.stem}-unsaved-{stamp}.yaml")
