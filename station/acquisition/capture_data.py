"""The :class:`Capture` type alone: samples of one recording as numpy arrays, with step labels.

It lives apart from :mod:`station.acquisition.capture`, which reads a file by handing it to the
CSV or HDF5 reader, because those readers build a ``Capture``: with the type here, below all
three, the readers need not import the module that dispatches to them. Import ``Capture`` from
``station.acquisition.capture`` as before; this module is what the file readers and writers use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
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
