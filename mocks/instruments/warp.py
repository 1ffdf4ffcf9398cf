"""A served simulated unit whose clock can change pace while it runs: a chamber campaign's waits.

A campaign spends most of its device time waiting for the chamber (hours of ramps and settles)
and a small part recording sequences. :class:`WarpPtyServer` is the ``PtyServer`` of
``mocks.pty_server`` with a piecewise-linear device clock::

    D(w) = D_k + (w - w_k) * s_k          for w_k <= w < w_{k+1}                     (1)

(w wall seconds, s_k the pace set at w_k by :meth:`WarpPtyServer.set_speed`), continuous at every
change, so the unit's samples, the chamber plant and the rate table (all on this clock) never see
a jump. The serving loop's blocks stay paced in wall time: the base server's loop, which reads its
device clock through ``_device_at``.
"""

from __future__ import annotations

import threading
import time

from mocks.pty_server import PtyServer


class WarpPtyServer(PtyServer):
    """``PtyServer`` with a device clock whose pace can change (eq. (1)); ``speed`` is its pace now."""

    _clock_lock: threading.Lock
    _w0: float
    _d0: float

    def start(self) -> WarpPtyServer:
        """Open the pty and serve, the clock from 0 at the current pace; returns self."""
        self._clock_lock = threading.Lock()
        super().start()
        self._w0, self._d0 = self._t0, 0.0
        return self

    def _device_at(self, wall: float) -> float:
        with self._clock_lock:
            return self._d0 + (wall - self._w0) * self.speed

    def set_speed(self, speed: float) -> None:
        """From now on the device clock runs ``speed`` times the wall clock (continuous, eq. (1))."""
        if not speed > 0:
            raise ValueError(f"speed must be positive, not {speed}")
        now = time.monotonic()
        with self._clock_lock:
            self._d0 += (now - self._w0) * self.speed
            self._w0 = now
            self.speed = float(speed)
