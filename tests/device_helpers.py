"""Live devices in tests: collect a device's sample batches up to a count or a deadline; feed a raw
pty from a thread as a unit would."""

from __future__ import annotations

import os
import threading
import time

import numpy as np

from mocks.raw_pty import open_raw_pty
from protocols.base import SAMPLE_DTYPE


def read_samples(dev, n: int, timeout: float) -> np.ndarray:
    """Samples read from ``dev`` until at least ``n`` came or ``timeout`` seconds passed."""
    got, count = [], 0
    deadline = time.monotonic() + timeout
    while count < n and time.monotonic() < deadline:
        batch = dev.read(0.1)
        got.append(batch)
        count += len(batch)
    return np.concatenate(got) if got else np.zeros(0, SAMPLE_DTYPE)


class BytePty:
    """A raw pty the test writes ``pieces`` into from a thread, one every ``period_s``, starting after
    ``delay_s`` (time for the reader to open the port); :meth:`chunked` and :meth:`lines` cut them."""

    def __init__(self, pieces: list[bytes], period_s: float, delay_s: float = 0.0) -> None:
        self.master, self.slave, self.path = open_raw_pty()
        self._pieces, self._period, self._delay = pieces, period_s, delay_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @classmethod
    def chunked(cls, data: bytes, chunk: int, period_s: float, delay_s: float = 0.0) -> BytePty:
        """The pty fed ``data`` ``chunk`` bytes at a time."""
        return cls([data[i : i + chunk] for i in range(0, len(data), chunk)], period_s, delay_s)

    @classmethod
    def lines(cls, data: bytes, lines_per_write: int = 5, period_s: float = 0.01) -> BytePty:
        """The pty fed ``lines_per_write`` whole lines of ``data`` at a time."""
        lines = data.splitlines(keepends=True)
        return cls([b"".join(lines[i : i + lines_per_write]) for i in range(0, len(lines), lines_per_write)],
                   period_s)

    def _run(self) -> None:
        if self._stop.wait(self._delay):
            return
        for piece in self._pieces:
            if self._stop.is_set():
                return
            try:
                os.write(self.master, piece)
            except OSError:
                return
            time.sleep(self._period)

    def __enter__(self) -> BytePty:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        for fd in (self.master, self.slave):
            os.close(fd)
