"""A capture in memory: samples as numpy arrays, with step labels and what is known of the unit."""

from __future__ import annotations

from pathlib import Path

# Capture is defined below the CSV and HDF5 readers (which build one) so that they do not import
# this module, which dispatches to them; it stays importable from here, its public path.
from station.acquisition.capture_data import Capture as Capture


def read_capture(path: str | Path) -> Capture:
    """Read a capture CSV (``.csv``, ``.csv.gz``) or a station capture file (``.h5``, ``.hdf5``).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Capture

    Raises
    ------
    InputFileError
        A file that cannot be read, naming the line and column.
    """
    from station.acquisition import capture_csv

    name = str(path).lower()
    if name.endswith((".h5", ".hdf5")):
        from station.acquisition import capture_h5

        return capture_h5.read_h5(path)
    return capture_csv.read_csv(path)
