"""A capture in memory: samples as numpy arrays, with step labels and what is known of the unit."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass
class Capture:
    """Samples of one recording, SI units, raw (uncalibrated) as the sensor reports them.

    ``step`` holds the sequence-step label of each row ("" for rows between steps) or is None
    when the capture carries no labels; ``temp``/``dtemp`` are None when unknown; ``mag`` (n, 3),
    the raw magnetic field in microtesla, is None for a unit without a magnetometer.
    """

    t: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    temp: np.ndarray | None = None
    dtemp: np.ndarray | None = None
    step: np.ndarray | None = None
    device: dict[str, Any] = field(default_factory=dict)
    link: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    mag: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def rate_hz(self) -> float:
        """Sample rate from the median timestamp step (robust to a few gaps)."""
        if len(self.t) < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.t)))

    def segments(self) -> list[tuple[str, slice]]:
        """Contiguous runs of one non-empty step label, in order: [(label, slice), ...]."""
        if self.step is None or len(self.step) == 0:
            return []
        labels = np.asarray(self.step)
        change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
        bounds = np.concatenate([[0], change, [len(labels)]])
        return [(str(labels[a]), slice(int(a), int(b))) for a, b in zip(bounds[:-1], bounds[1:], strict=True)
                if labels[a] != ""]


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
