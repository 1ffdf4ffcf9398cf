"""One unit read without a reader thread, for a consumer that reads it in a loop of its own.

:class:`PacedPort` is a :class:`~drivers.polled_port.PolledPort` for one consumer at a time that
calls ``read(timeout)`` in a loop (the TUI's screens, a factory run's sequence runner): its reads
are spaced ``READ_PERIOD_S`` apart, each taking every byte the port gathered meanwhile and
decoding it in one batch. A reader thread instead wakes for every few bytes the port delivers
(a unit on a USB link sends each frame as it is made: 1000 wake-ups a second at 1 kHz, each a
decoder call, a lock and a notify, and its consumer wakes as often); here the consumer's own
thread does the reading, fifty times a second whatever the rate. A port's buffers hold far more
than a period (a pty ~20 KB: 0.4 s of a 1 kHz unit), so nothing is lost for the wait.

Its calls take a lock, so a screen's worker and the UI thread (asking for the link statistics,
a command) may share it. While nobody reads (the TUI's connect screen), asking for the link
statistics reads what the port has, so they stay live and the port's buffers do not overflow;
the samples wait, bounded as a reader thread's are (beyond ``max_buffered_samples`` they are
dropped and counted). It needs a port with a file descriptor; :func:`open_paced` falls back to the
threaded :class:`~drivers.serial_device.SerialDevice` for a pyserial URL (``sim://``).
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from drivers.interface import Device
from drivers.link_stats import LinkStats
from drivers.polled_port import PolledPort
from drivers.serial_device import DEFAULT_BAUDRATE, DEFAULT_MAX_BUFFERED, SerialDevice
from protocols.base import Message

READ_PERIOD_S = 0.02  # as the many-unit capture's loop: 50 decoder calls a second whatever the rate


class PacedPort(PolledPort):
    """A :class:`PolledPort` whose blocking reads are spaced ``period_s`` apart, safe to share
    between threads, with the commands of :class:`~drivers.serial_device.SerialDevice`.

    Parameters
    ----------
    port : str
        Device path or pty.
    protocol : str
        Decoder name from ``protocols.registry``.
    baudrate : int
        Line speed; ignored by pseudo-terminals.
    exclusive : bool
        Take an exclusive lock on the port.
    period_s : float
        Least time between two reads that wait (``read(timeout)`` with a timeout above 0).
    max_buffered_samples : int
        Samples kept between two reads; beyond it batches are dropped and counted in
        ``stats.overflow_drops``.
    """

    def __init__(self, port: str, protocol: str = "native", baudrate: int = DEFAULT_BAUDRATE,
                 exclusive: bool = True, period_s: float = READ_PERIOD_S,
                 max_buffered_samples: int = DEFAULT_MAX_BUFFERED):
        super().__init__(port, protocol, baudrate, exclusive)
        self.period_s = period_s
        self._max_buffered = max_buffered_samples
        self._buffered = 0
        self._lock = threading.RLock()
        self._last_read = 0.0

    def _ingest(self, data: bytes) -> None:
        """Decode ``data``; a batch beyond ``max_buffered_samples`` waiting is dropped and counted."""
        waiting = len(self._pending)
        super()._ingest(data)
        if len(self._pending) > waiting:
            batch = self._pending[-1]
            if self._buffered + len(batch) > self._max_buffered:
                self._pending.pop()
                self._monitor.add_overflow(len(batch))
            else:
                self._buffered += len(batch)

    def read_now(self) -> np.ndarray:
        """Every sample received since the last read, reading what the port has without waiting."""
        with self._lock:
            batch = super().read_now()
            self._buffered = 0  # every waiting sample is in the batch
            return batch

    def read(self, timeout: float | None = None) -> np.ndarray:
        """Every sample received since the last read; waits first until ``period_s`` has passed since
        the last read (at most ``timeout``), then up to the rest of ``timeout`` for the first bytes."""
        start = time.monotonic()
        wait = self._last_read + self.period_s - start
        if timeout is not None:
            wait = min(wait, timeout)
        if wait > 0:
            time.sleep(wait)  # the bytes gather in the port meanwhile: one batch, not one per arrival
        with self._lock:
            self._last_read = time.monotonic()
            batch = self.read_now()
        if len(batch) or self.closed or self.failed is not None:
            return batch
        left = None if timeout is None else timeout - (time.monotonic() - start)
        if left is not None and left <= 0:
            return batch
        self._wait_readable(left)
        with self._lock:
            self._last_read = time.monotonic()
            return self.read_now()

    def command(self, command_id: int, payload: bytes = b"", timeout: float = 1.0,
                retries: int = 2) -> Message:
        """Send a native command and wait for its answer (:meth:`PolledPort.command`), the port's
        reads held meanwhile (the samples that arrive wait for the next read)."""
        with self._lock:
            return super().command(command_id, payload, timeout, retries)

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link statistics, once what the port has is read (its samples wait for
        the next read)."""
        with self._lock:
            self._receive()
            return super().stats

    @property
    def info(self) -> dict[str, Any]:
        """The last DEVICE_INFO the unit sent (empty until it sent one)."""
        with self._lock:
            return super().info

    def close(self) -> None:
        """Release the port; safe to call twice."""
        with self._lock:
            super().close()


def open_paced(port: str, protocol: str = "native", baudrate: int = DEFAULT_BAUDRATE) -> Device:
    """Open the unit at ``port`` as a :class:`PacedPort`, or, for a pyserial URL (no file descriptor
    to read), as a :class:`~drivers.serial_device.SerialDevice` with its reader thread.

    Parameters
    ----------
    port : str
        Device path, pty or pyserial URL.
    protocol : str
        Decoder name from ``protocols.registry``.
    baudrate : int
        Line speed of a real serial port.

    Returns
    -------
    Device
        The open unit.

    Raises
    ------
    DriverError
        The port cannot be opened (``PortNotFound``, ``PortBusy``, ...).
    """
    if "://" in port:
        return SerialDevice(port, protocol=protocol, baudrate=baudrate)
    return PacedPort(port, protocol=protocol, baudrate=baudrate)
