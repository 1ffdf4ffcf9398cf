"""Streaming capture: samples from a device into a capture file, in bounded memory.

:class:`Recorder` writes batches as they arrive (CSV, or the HDF5 capture file by suffix),
keeps ``t`` strictly increasing as the capture format requires (a wild timestamp is left out
and counted, a confirmed jump of the unit's clock bridged), labels rows with the current
sequence step and flushes at least once a second. :func:`record` is the capture loop of
``imu-station capture``: it ends on ``duration_s`` of continuous device clock, on Ctrl-C, on a
stop event or when the link breaks, and in every case leaves every sample received so far in
the file (but wild ones); a capture without a single row leaves no file and says so.
"""

from __future__ import annotations

import shutil
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from drivers.errors import DriverError, FramesRefused, NoSamples
from drivers.interface import Device
from drivers.link_stats import LinkStats
from station.acquisition.capture_csv import CsvCaptureWriter
from station.acquisition.capture_h5 import H5CaptureWriter
from station.acquisition.clock_guard import ClockGuard, ClockJump, Released
from station.errors import OutputFileError

FLUSH_INTERVAL_S = 1.0
READ_TIMEOUT_S = 0.1
NO_SAMPLES_TIMEOUT_S = 5.0
H5_SUFFIXES = (".h5", ".hdf5")
# Below this much free space the recorder stops and closes the file while it still can: an HDF5
# file that meets a full disk mid-write may be left damaged, a closed one is complete.
MIN_FREE_BYTES = 4 * 1024 * 1024


class CaptureWriter(Protocol):
    """A streaming capture writer (CSV or HDF5): rows in, the file kept valid as it grows."""

    path: Path

    @property
    def rows(self) -> int:
        """Rows written so far."""

    @property
    def field_dropped(self) -> int:
        """Samples whose magnetic field the file had no room for (a CSV that could not be widened)."""

    def write(self, samples: np.ndarray, step: np.ndarray | list[str] | None = None) -> None:
        """Append a batch of ``SAMPLE_DTYPE`` samples, and their step labels if the file has them."""

    def flush(self, link: dict[str, Any] | None = None) -> None:
        """Make what was written durable, with the link statistics ``link`` so far."""

    def close(self, link: dict[str, Any] | None = None) -> None:
        """Flush with the final link statistics and close the file."""


def is_h5_path(path: str | Path) -> bool:
    """True when ``path`` names a station capture file (.h5, .hdf5), else it is a capture CSV."""
    return str(path).lower().endswith(H5_SUFFIXES)


def open_capture_writer(path: str | Path, device: dict[str, Any] | None = None, with_step: bool = False,
                        port: str = "", protocol: str = "") -> CaptureWriter:
    """A streaming writer for ``path``: the HDF5 capture file for .h5/.hdf5, else capture CSV."""
    if is_h5_path(path):
        return H5CaptureWriter(path, device=device, with_step=with_step, port=port, protocol=protocol)
    return _CsvWriterAdapter(CsvCaptureWriter(path, with_step=with_step, device=device, protocol=protocol))


class _CsvWriterAdapter:
    """The CSV writer behind the common writer interface (a CSV has no room for link statistics)."""

    def __init__(self, writer: CsvCaptureWriter):
        self._writer = writer
        self.path = writer.path

    @property
    def rows(self) -> int:
        return self._writer.rows

    @property
    def field_dropped(self) -> int:
        return self._writer.field_dropped

    def write(self, samples: np.ndarray, step: np.ndarray | list[str] | None = None) -> None:
        self._writer.write(samples, step)

    def flush(self, link: dict[str, Any] | None = None) -> None:
        self._writer.flush()

    def close(self, link: dict[str, Any] | None = None) -> None:
        self._writer.close()


class Recorder:
    """Writes sample batches to a capture file as they come.

    Timestamps pass a :class:`~station.acquisition.clock_guard.ClockGuard` first: a sample whose
    device time departs alone from the others is left out and counted (``clock_outliers``), a
    jump the following samples confirm is kept (``clock_jumps``; a clock that went back is
    re-based to follow on), and samples whose time does not increase (a replayed frame) are left
    out and counted in ``non_increasing``: the capture formats require strictly increasing
    ``t``. A few samples may wait in the guard for the ones after them; :meth:`close` writes
    what can be. Rows get the label in :attr:`step` at the time they are given to :meth:`write`.
    With ``duration_s``, rows stop once that much continuous device time (jumps left out) is
    recorded, and :attr:`full` becomes true.
    """

    def __init__(self, path: str | Path, device: dict[str, Any] | None = None, with_step: bool = False,
                 port: str = "", protocol: str = "", flush_interval_s: float = FLUSH_INTERVAL_S,
                 duration_s: float | None = None):
        self.writer = open_capture_writer(path, device=device, with_step=with_step, port=port,
                                          protocol=protocol)
        self.path = Path(path)
        self.step = ""
        self.clock = ClockGuard()
        self.received = 0  # samples given to write()
        self.full = False
        self._limit_us = None if duration_s is None else int(round(duration_s * 1e6))
        self._first_c: int | None = None  # continuous device time of the first and last rows
        self._last_c: int | None = None
        self._stopped = False  # the writer was closed early (the disk filled)
        self._with_step = with_step
        self._flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._unflushed_bytes = 0

    @property
    def rows(self) -> int:
        """Rows written to the capture so far."""
        return self.writer.rows

    @property
    def non_increasing(self) -> int:
        """Samples on the clock's line whose time did not increase (a replayed frame), left out."""
        return self.clock.non_increasing

    @property
    def clock_outliers(self) -> int:
        """Samples whose timestamp was off the clock's line and not confirmed by the next ones, left out."""
        return self.clock.outliers

    @property
    def clock_jumps(self) -> list[ClockJump]:
        """Jumps of the device clock that later samples confirmed (the capture runs on across them)."""
        return self.clock.jumps

    @property
    def device_time_s(self) -> float:
        """Device time recorded: from the first row to the last, jumps of the clock left out."""
        if self._first_c is None or self._last_c is None:
            return 0.0
        return (self._last_c - self._first_c) * 1e-6

    def write(self, samples: np.ndarray, link: dict[str, Any] | None = None) -> int:
        """Append a batch; returns the number of rows written (samples held by the clock guard
        are written by a later call)."""
        self.received += len(samples)
        labels = [self.step] * len(samples) if self._with_step else None
        return self._write(self.clock.push(samples, labels), link)

    def _write(self, released: Released, link: dict[str, Any] | None) -> int:
        samples, labels, continuous = released.samples, released.labels, released.continuous_us
        if self.full or self._stopped:
            samples = samples[:0]
        if self._limit_us is not None and len(samples):
            start = self._first_c if self._first_c is not None else int(continuous[0])
            inside = continuous - start < self._limit_us
            if not inside.all():
                self.full = True
                samples, continuous = samples[inside], continuous[inside]
                if labels is not None:
                    labels = [label for label, ok in zip(labels, inside, strict=True) if ok]
        if len(samples) == 0:
            self.tick(link)
            return 0
        self._check_space(samples.nbytes, link)
        self.writer.write(samples, labels)
        self._unflushed_bytes += samples.nbytes
        if self._first_c is None:
            self._first_c = int(continuous[0])
        self._last_c = int(continuous[-1])
        self.tick(link)
        return len(samples)

    def _check_space(self, batch_bytes: int, link: dict[str, Any] | None) -> None:
        # What the writer still holds in memory (HDF5 caches chunks until a flush) needs room too.
        free = shutil.disk_usage(self.path.parent).free - self._unflushed_bytes - batch_bytes
        if free < MIN_FREE_BYTES:
            self._stopped = True
            self.writer.close(link)
            if self.rows == 0:
                self.path.unlink(missing_ok=True)
                raise OutputFileError(self.path, f"the disk is almost full ({free // 1024} KiB left): no "
                                      f"sample could be written and the file was removed; free space and "
                                      f"capture again")
            raise OutputFileError(self.path, f"the disk is almost full ({free // 1024} KiB left): the "
                                  f"capture stopped at {self.rows} samples and the file is complete; free "
                                  f"space and capture again")

    def tick(self, link: dict[str, Any] | None = None) -> None:
        """Flush if the last flush is a second old (call it when idle, too)."""
        if self._stopped:
            return
        now = time.monotonic()
        if now - self._last_flush >= self._flush_interval_s:
            self.writer.flush(link)
            self._last_flush = now
            self._unflushed_bytes = 0

    def drain(self) -> int:
        """Write the samples the clock guard still holds (those it can place); returns the rows."""
        if self._stopped:
            return 0
        return self._write(self.clock.finish(self._with_step), None)

    def close(self, link: dict[str, Any] | None = None) -> None:
        """Write what the clock guard holds (:meth:`drain`), then close the file."""
        self.drain()
        self.writer.close(link)


@dataclass
class CaptureResult:
    """What a capture produced: its file, rows, device time, link statistics and why it ended."""

    path: Path
    rows: int
    device_time_s: float
    link: LinkStats
    ended_by: str  # "duration", "interrupted", "stopped" or "link error"
    error: DriverError | None = None
    non_increasing: int = 0
    clock_jumps: list[ClockJump] = field(default_factory=list)
    field_dropped: int = 0  # samples whose magnetic field the file had no room for


StatusCallback = Callable[[LinkStats, int, float], None]


class CaptureSink(Protocol):
    """What :func:`capture_loop` writes to and watches: a :class:`Recorder`, or one per IMU instance."""

    @property
    def received(self) -> int:
        """Samples given to it so far."""

    @property
    def full(self) -> bool:
        """Its capture has the duration asked for."""

    @property
    def rows(self) -> int:
        """Rows written so far."""

    @property
    def device_time_s(self) -> float:
        """Device seconds recorded so far."""


def capture_loop(device: Device, sink: CaptureSink, read: Callable[[float], Any],
                 write: Callable[[Any], object], nothing_came: Callable[[], DriverError], *,
                 duration_s: float | None, on_status: StatusCallback | None, status_interval_s: float,
                 stop: threading.Event | None, handle_sigint: bool,
                 no_samples_timeout_s: float) -> tuple[str, DriverError | None]:
    """Read ``device`` and ``write`` what comes to ``sink`` until ``duration_s`` of device clock
    (``sink.full``), Ctrl-C, ``stop`` or a link error: the loop of :func:`record` and of a board's
    several IMUs (``station.acquisition.instance_capture``). The caller writes what is left and closes
    its files after it, also when ``write`` raises.

    Returns
    -------
    tuple
        How it ended (``duration``, ``interrupted``, ``stopped``, ``link error``) and the link's error:
        a ``DriverError`` of ``read``, ``nothing_came()`` after ``no_samples_timeout_s`` without a
        sample, or ``FramesRefused`` when most frames fail a frame description's checksum.
    """
    interrupted = threading.Event()
    restore = _install_sigint(interrupted) if handle_sigint else None
    # The device clock decides the duration; the wall clock only guards against a unit that stalls.
    wall_deadline = None if duration_s is None else time.monotonic() + duration_s * 1.5 + 5.0
    ended_by = "stopped"
    error: DriverError | None = None
    last_status = 0.0
    started = time.monotonic()
    try:
        while True:
            if interrupted.is_set():
                ended_by = "interrupted"
                break
            if stop is not None and stop.is_set():
                break
            try:
                batch = read(READ_TIMEOUT_S)
            except DriverError as exc:
                error, ended_by = exc, "link error"
                break
            write(batch)
            now = time.monotonic()
            if sink.received == 0 and now - started > no_samples_timeout_s:
                error, ended_by = nothing_came(), "link error"
                break
            # a frame description most frames fail: what is kept is a few frames that matched by chance
            problem = getattr(device, "decoder_problem", None)
            if problem:
                error = FramesRefused(f"{device.port}: {problem}; the capture stopped", device.port)
                ended_by = "link error"
                break
            if on_status is not None and now - last_status >= status_interval_s:
                on_status(device.stats, sink.rows, sink.device_time_s)
                last_status = now
            if sink.full or (wall_deadline is not None and now > wall_deadline):
                ended_by = "duration"
                break
    except KeyboardInterrupt:
        ended_by = "interrupted"
    finally:
        if restore is not None:
            restore()
    return ended_by, error


def record(device: Device, path: str | Path, duration_s: float | None = None,
           on_status: StatusCallback | None = None, status_interval_s: float = 0.25,
           stop: threading.Event | None = None, handle_sigint: bool = True,
           no_samples_timeout_s: float = NO_SAMPLES_TIMEOUT_S) -> CaptureResult:
    """Capture from ``device`` into ``path`` until ``duration_s`` of device clock, Ctrl-C, ``stop`` or
    a link error. Every sample received before the end is in the file when this returns, but
    those the clock guard left out (see :class:`Recorder`); the duration counts continuous device
    time, so a jump of the unit's clock neither ends the capture nor counts.

    No sample in the first ``no_samples_timeout_s`` ends it with ``NoSamples``; most frames failing the
    checksum a frame description names ends it with ``FramesRefused`` (returned in ``error``). A capture that
    ends without a single row, however it ends, leaves no file and returns ``NoSamples`` in
    ``error``, which says so. A link error (``PortLost``, ...) does not raise: it ends the
    capture and is returned in ``error``. A write error (disk full) raises ``OutputFileError``
    after keeping what was written.
    """
    recorder = Recorder(path, device=device.info, port=device.port, protocol=device.protocol,
                        duration_s=duration_s)

    def nothing_came() -> DriverError:
        return NoSamples(f"{device.port}: no sample arrived in {no_samples_timeout_s:g} s "
                         f"({device.stats.bytes} bytes read); check that the unit streams, and the "
                         f"--protocol and baud rate", device.port)

    try:
        ended_by, error = capture_loop(
            device, recorder, device.read, lambda batch: recorder.write(batch, _link(device, recorder)),
            nothing_came, duration_s=duration_s, on_status=on_status, status_interval_s=status_interval_s,
            stop=stop, handle_sigint=handle_sigint, no_samples_timeout_s=no_samples_timeout_s)
    finally:
        recorder.drain()
        recorder.close(_link(device, recorder))
    if on_status is not None:
        on_status(device.stats, recorder.rows, recorder.device_time_s)
    if recorder.rows == 0:
        error, ended_by = _no_rows(device, recorder, error, ended_by), "link error"
    return CaptureResult(path=recorder.path, rows=recorder.rows, device_time_s=recorder.device_time_s,
                         link=_with_clock(device.stats, recorder), ended_by=ended_by, error=error,
                         non_increasing=recorder.non_increasing, clock_jumps=list(recorder.clock_jumps),
                         field_dropped=recorder.writer.field_dropped)


def _no_rows(device: Device, recorder: Recorder, error: DriverError | None, ended_by: str) -> DriverError:
    """The error of a capture that wrote no row: its file (a header only) is removed, and said so."""
    recorder.path.unlink(missing_ok=True)
    removed = f"no sample was captured, so no file was written ({recorder.path} removed)"
    if error is not None:
        return type(error)(f"{error}; {removed}", error.port)
    why = {"interrupted": "interrupted before any sample was kept",
           "duration": "the time ran out before any sample was kept"}.get(ended_by, "the capture ended "
                                                                             "before any sample was kept")
    left_out = recorder.received
    detail = f" ({left_out} received, all left out by the clock guard)" if left_out else ""
    return NoSamples(f"{device.port}: {why}{detail}; {removed}", device.port)


def _with_clock(stats: LinkStats, recorder: Recorder) -> LinkStats:
    """The link statistics with the clock guard's counts, which only the recorder knows."""
    stats.clock_outliers = recorder.clock_outliers
    stats.clock_jumps = len(recorder.clock_jumps)
    return stats


def _link(device: Device, recorder: Recorder) -> dict[str, Any]:
    link = _with_clock(device.stats, recorder).as_dict()
    link["non_increasing_dropped"] = recorder.non_increasing
    return link


def _install_sigint(flag: threading.Event) -> Callable[[], None] | None:
    """First Ctrl-C sets ``flag`` (the loop ends cleanly); a second one interrupts at once."""
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: object) -> None:
        flag.set()
        signal.signal(signal.SIGINT, previous)

    def restore() -> None:
        signal.signal(signal.SIGINT, previous)

    signal.signal(signal.SIGINT, handler)
    return restore
