"""A capture in memory: samples as numpy arrays, with step labels and what is known of the unit."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

# Capture is defined below the CSV and HDF5 readers (which build one) so that they do not import
# this module, which dispatches to them; it stays importable from here, its public path.
from station.acquisition.capture_data import Capture as Capture
from station.errors import InputFileError

# The file's columns of each of a capture's arrays (a triad's three, in axis order).
_COLUMNS = {"t": ("t",), "acc": ("ax", "ay", "az"), "gyro": ("gx", "gy", "gz"), "temp": ("temp",),
            "dtemp": ("dtemp",), "mag": ("mx", "my", "mz")}


def read_capture(path: str | Path, instance: int | None = None) -> Capture:
    """Read a capture CSV (``.csv``, ``.csv.gz``), a station capture file (``.h5``, ``.hdf5``), or one IMU
    of a PX4 ULog (``.ulg``) or ArduPilot DataFlash log (``.bin``).

    A log's IMU is converted by :mod:`station.acquisition.autopilot_log` (SI units, the board's axes, the
    autopilot's own correction taken out); what was done is in the capture's notes
    (:func:`station.acquisition.autopilot_log.log_notes`), which the commands print.

    Parameters
    ----------
    path : str or Path
    instance : int, optional
        The log's IMU (PX4 multi_id, ArduPilot IMU.I; ``--instance``); needed when it has several.

    Returns
    -------
    Capture

    Raises
    ------
    InputFileError
        A file that cannot be read, naming the line and column; a log with several IMUs and no
        ``instance`` (naming them: instance, device id, rate, samples); ``instance`` for a file that is
        not a log.
    """
    from station.acquisition import autopilot_log, capture_csv

    if autopilot_log.is_autopilot_log(path):
        return autopilot_log.read_log_capture(path, instance)
    if instance is not None:
        raise InputFileError(path, f"--instance {instance} picks an IMU of a PX4 (.ulg) or ArduPilot (.bin) "
                             "log, and this is not one; leave --instance out")
    name = str(path).lower()
    if name.endswith((".h5", ".hdf5")):
        from station.acquisition import capture_h5

        return capture_h5.read_h5(path)
    return capture_csv.read_csv(path)


def require_finite(capture: Capture, path: str | Path, arrays: Sequence[str], why: str) -> None:
    """Refuse the first sample whose value in one of ``arrays`` is not a finite number (NaN, inf).

    The capture CSV's reader refuses them in the required columns alone (an optional column may
    hold ``nan`` for a sample without that value); a command that computes with an optional one
    calls this, so that a NaN is refused where it is instead of spreading silently.

    Parameters
    ----------
    capture : Capture
        As :func:`read_capture` returned it.
    path : str or Path
        The file, as the user named it.
    arrays : sequence of str
        Capture arrays to check: ``t``, ``acc``, ``gyro``, ``temp``, ``dtemp``, ``mag`` (absent ones skipped).
    why : str
        Why the command needs the values, said after the problem.

    Raises
    ------
    InputFileError
        Naming the file, the line (a CSV's: row *i* is line *i* + 2, after the header) or the row
        (an HDF5 capture file's), and the column.
    """
    csv = not str(path).lower().endswith((".h5", ".hdf5", ".ulg", ".bin"))  # a file without lines: rows
    for name in arrays:
        values = getattr(capture, name)
        if values is None:
            continue
        table = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
        bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
        if len(bad):
            row = int(bad[0])
            axis = int(np.flatnonzero(~np.isfinite(table[row]))[0])
            column = _COLUMNS[name][axis]
            value = float(table[row, axis])
            problem = f"value {value!r} is not a finite number{'' if csv else f' (row {row})'}: {why}"
            raise InputFileError(path, problem, line=row + 2 if csv else None, column=column)
