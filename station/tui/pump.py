"""Reading the device in a thread worker and handing the UI coalesced updates at most ~20 Hz.

Every batch goes to ``on_batch`` in the worker's thread (cheap work only: appending to arrays);
``on_tick`` runs at most ``ui_rate_hz`` times a second, also in the worker's thread, and
posts one message with whatever the screen shows. So the screen renders at its own pace and
the reader never waits for it: no sample is lost at 1 kHz while the UI renders.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from textual.worker import get_current_worker

from drivers.errors import DriverError
from drivers.interface import Device

UI_RATE_HZ = 20.0


def pump(device: Device, on_batch: Callable[[np.ndarray], None], on_tick: Callable[[], None],
         on_error: Callable[[DriverError], object], ui_rate_hz: float = UI_RATE_HZ) -> None:
    """Read ``device`` until the current worker is cancelled or the link fails (``on_error``)."""
    worker = get_current_worker()
    period = 1.0 / ui_rate_hz
    last = 0.0
    while not worker.is_cancelled:
        try:
            batch = device.read(0.05)
        except DriverError as exc:
            on_error(exc)
            return
        if len(batch):
            on_batch(batch)
        now = time.monotonic()
        if now - last >= period:
            last = now
            on_tick()


class Tail:
    """The last ``size`` samples of a few float columns, kept in a ring for the live traces."""

    def __init__(self, size: int, columns: int):
        self.data = np.full((size, columns), np.nan)
        self.count = 0

    def add(self, rows: np.ndarray) -> None:
        """Append ``rows`` (n, columns), dropping the oldest beyond ``size``."""
        rows = np.asarray(rows, float)[-len(self.data):]
        n = len(rows)
        self.data = np.roll(self.data, -n, axis=0)
        self.data[-n:] = rows
        self.count += n

    def column(self, j: int) -> list[float]:
        """The finite values of column ``j``, oldest first."""
        col = self.data[:, j]
        return col[np.isfinite(col)].tolist()
