"""Serve a simulated device on a pseudo-terminal, as a real unit on a serial port.

A thread owns the master side: every ``block_s`` it produces the samples due by then on an
absolute schedule (sample k at t0 + its device time / speed, so no drift), encodes them in one batch,
applies faults and writes them with one ``os.write``; host commands read from the master are
answered between blocks. The host opens ``port_path`` (the slave) with pyserial or anything.

While no host has the port open (reading the master gives EIO) the device streams into the
void, as a UART with nobody listening: nothing is buffered for a later reader. A
``disconnect`` fault closes the master, so the port vanishes under the host.

``speed`` accelerates the device clock against the wall clock, as ``sim://?speed=X`` does: at
``speed=10`` a 200 Hz unit sends 2000 samples per wall second whose timestamps are still 5 ms
apart, so a sequence of minutes on the device clock runs in seconds. Everything the device does
(rate, motion, noise, the disconnect fault's time) follows its own clock; only the stall fault
and the block period are wall-clock times.
"""

from __future__ import annotations

import contextlib
import errno
import os
import select
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocks.device import SimDevice
from mocks.faults import FaultInjector, FaultSpec
from mocks.raw_pty import PtyService, open_serving_pty

MAX_PENDING_BYTES = 256 * 1024  # beyond this the host is not reading: new output is dropped


@dataclass
class ServerStats:
    """What the pty server did: samples produced, sent, unheard and overrun, bytes, commands, timing."""

    samples: int = 0  # samples produced while streaming
    samples_sent: int = 0  # samples handed to a connected host (before faults)
    samples_unheard: int = 0  # samples produced while no host had the port open
    samples_overrun: int = 0  # samples dropped because the host stopped reading
    bytes_written: int = 0
    answers: int = 0
    host_opens: int = 0
    disconnected: bool = False
    elapsed_s: float = 0.0  # wall clock
    device_time_s: float = 0.0  # device clock: elapsed_s times the speed
    late_blocks: int = 0  # blocks written more than one block period after their due time
    max_lateness_s: float = 0.0
    commands: dict[str, int] = field(default_factory=dict)

    @property
    def rate_hz(self) -> float:
        """Samples per second of device clock (the unit's rate, whatever the speed)."""
        return self.samples / self.device_time_s if self.device_time_s > 0 else 0.0


def read_host(master: int) -> bytes | None:
    """What the host wrote to a non-blocking pty master (``b""`` when nothing), or None while nobody
    has the port open (the master then reads EIO)."""
    try:
        return os.read(master, 4096)
    except BlockingIOError:
        return b""
    except OSError as exc:
        if exc.errno != errno.EIO:
            raise
        return None


class PtyServer(PtyService):
    """A simulated unit on a pty: ``with PtyServer(seed=3) as srv: serial.Serial(srv.port_path)``.

    Parameters
    ----------
    device : the device to serve (default: ``SimDevice(seed=seed, rate_hz=rate_hz, scenario=...)``).
    faults : link faults (:class:`FaultSpec`); None for a clean link.
    block_s : period of the output blocks.
    link : also make a symlink at this path to the port (removed on stop).
    record : keep every intact frame's bytes and every sample sent (for end-to-end tests).
    speed : the device clock runs this many times faster than the wall clock (default 1).
    """

    THREAD_NAME = "pty-server"
    FAILED = "the pty server thread failed"

    def __init__(self, device: SimDevice | None = None, *, seed: int = 0, rate_hz: float = 200.0,
                 scenario: str | Sequence = "still", faults: FaultSpec | None = None, block_s: float = 0.02,
                 link: str | os.PathLike[str] | None = None, record: bool = False, speed: float = 1.0):
        if not speed > 0:
            raise ValueError(f"speed must be positive, not {speed}")
        super().__init__()
        if device is None:
            device = SimDevice(seed=seed, rate_hz=rate_hz, scenario=scenario)
        self.device = device
        self.faults = faults if faults is not None and faults.active else None
        self.injector = FaultInjector(self.faults, record=record) if self.faults else None
        self.block_s = block_s
        self.link = Path(link) if link is not None else None
        self.record = record
        self.speed = float(speed)
        self.stats = ServerStats()
        self.sent_samples: list[np.ndarray] = []
        self._closed = threading.Event()
        self._pending = bytearray()
        self._host = False
        self._hold_until = 0.0
        self._t0 = 0.0

    # --- life cycle ----------------------------------------------------------------------

    def start(self) -> PtyServer:
        """Open the pty (and its symlink ``link``), start serving in a thread; returns self."""
        self._master, self.port_path = open_serving_pty()
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                if self.link.is_symlink():
                    self.link.unlink()
            self.link.symlink_to(self.port_path)
        self._t0 = time.monotonic()
        self._start_thread()
        return self

    @property
    def running(self) -> bool:
        """True while the serving thread runs."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def host_connected(self) -> bool:
        """Whether a host has the port open (as of the last block)."""
        return self._host

    def wait_closed(self, timeout: float | None = None) -> bool:
        """Wait until the port is gone (a disconnect fault ended it, or stop)."""
        return self._closed.wait(timeout)

    def elapsed_s(self) -> float:
        """Wall-clock seconds since start."""
        return time.monotonic() - self._t0

    def device_time_s(self) -> float:
        """Device-clock seconds since power-up (start)."""
        return self._device_at(time.monotonic())

    def _device_at(self, wall: float) -> float:
        """The device clock at wall-clock time ``wall``: ``speed`` times the wall seconds since start (a
        subclass may pace it otherwise, ``mocks.instruments.warp``)."""
        return (wall - self._t0) * self.speed

    def _update_times(self, now: float) -> None:
        self.stats.elapsed_s = now - self._t0
        self.stats.device_time_s = self._device_at(now)

    def _close_master(self) -> None:
        super()._close_master()
        if self.link is not None and self.link.is_symlink():
            self.link.unlink()
        self._closed.set()

    # --- the serving thread ------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._serve()
        except BaseException as exc:  # surfaced by stop(): a test must see a crashed server
            self._error = exc
        finally:
            if self.stats.elapsed_s == 0.0:  # stopped before the first block
                self._update_times(time.monotonic())
            self.stats.commands = dict(self.device.commands)

    def _serve(self) -> None:
        tick = 0
        faults = self.faults
        while not self._stop.is_set():
            tick += 1
            due = self._t0 + tick * self.block_s
            self._wait(due)
            if self._stop.is_set() or self._master < 0:
                return
            now = time.monotonic()
            lateness = now - due
            if lateness > self.block_s:
                self.stats.late_blocks += 1
            self.stats.max_lateness_s = max(self.stats.max_lateness_s, lateness)
            self._probe_host()
            device_time = self._device_at(now)
            self._emit(device_time)
            if faults is not None and faults.disconnect_after_s is not None \
                    and device_time >= faults.disconnect_after_s and self.injector is not None:
                self.injector.end_link()
            self._flush(now)
            if self.injector is not None and self.injector.disconnected and not self._pending:
                self.stats.disconnected = True
                self._update_times(time.monotonic())
                self._close_master()
                return
            self._update_times(now)

    def _wait(self, until: float) -> None:
        """Sleep until ``until`` while answering host commands and draining pending output."""
        while not self._stop.is_set():
            timeout = until - time.monotonic()
            if timeout <= 0:
                return
            if not self._host:
                time.sleep(min(timeout, self.block_s))
                self._probe_host()
                continue
            want_write = [self._master] if self._pending and time.monotonic() >= self._hold_until else []
            readable, writable, _ = select.select([self._master], want_write, [], timeout)
            if readable:
                self._read_host()
            if writable:
                self._flush(time.monotonic())

    def _probe_host(self) -> None:
        if not self._host:
            self._read_host()

    def _read_host(self) -> None:
        data = read_host(self._master)
        if data is None:
            if self._host:
                self._host = False
                self._pending.clear()
            return
        if not self._host:
            self._host = True
            self.stats.host_opens += 1
        if data:
            self._answer(data)

    def _answer(self, data: bytes) -> None:
        # Samples due before the command go out before its answer, as on a real link.
        self._emit(self.device_time_s())
        answer = self.device.feed(data)
        # Answers bypass the per-frame faults (the injector numbers sample frames only) but not
        # the end of the link.
        if answer and not (self.injector is not None and self.injector.disconnected):
            self.stats.answers += 1
            self._pending += answer

    def _emit(self, device_time_s: float) -> None:
        samples = self.device.produce(device_time_s)
        if not len(samples):
            return
        self.stats.samples += len(samples)
        if not self._host:
            self.stats.samples_unheard += len(samples)
            return
        if len(self._pending) > MAX_PENDING_BYTES:
            self.stats.samples_overrun += len(samples)
            return
        self.stats.samples_sent += len(samples)
        if self.record:
            self.sent_samples.append(samples)
        if self.injector is None:
            self._pending += self.device.encode_samples(samples)
        else:
            self._queue(self.injector, self.device.encode_frames(samples))

    def _queue(self, injector: FaultInjector, frames: list[bytes]) -> None:
        out = injector.apply(frames)
        if out.stall_s:
            self._hold_until = max(self._hold_until, time.monotonic()) + out.stall_s
        self._pending += out.data

    def _flush(self, now: float) -> None:
        if not self._pending or not self._host or now < self._hold_until or self._master < 0:
            return
        try:
            written = os.write(self._master, self._pending)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self._host = False
            self._pending.clear()
            return
        self.stats.bytes_written += written
        del self._pending[:written]

    # --- for tests -----------------------------------------------------------------------------

    def sent(self) -> np.ndarray:
        """Every sample handed to the host, in order (``record=True``)."""
        from protocols.base import SAMPLE_DTYPE

        return np.concatenate(self.sent_samples) if self.sent_samples else np.zeros(0, dtype=SAMPLE_DTYPE)
