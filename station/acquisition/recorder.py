"""Streaming capture: samples from a device into a capture file, in bounded memory.

:class:`Recorder` writes batches as they arrive (CSV, or the HDF5 capture file by suffix),
keeps ``t`` strictly increasing as the capture format requires, labels rows with the current
sequence step and flushes at least once a second. :func:`record` is the capture loop of
``imu-station capture``: it ends on ``duration_s`` of device clock, on Ctrl-C, on a stop event
or when the link breaks, and in every case leaves every sample received so far in the file.
"""

from __future__ import annotations

import shutil
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from drivers.errors import DriverError, NoSamples
from drivers.interface import Device
from drivers.link_stats import LinkStats
from station.acquisition.capture_csv import CsvCaptureWriter
from station.acquisition.capture_h5 import H5CaptureWriter
from station.errors import OutputFileError

FLUSH_INTERVAL_S = 1.0
READ_TIMEOUT_S = 0.1
NO_SAMPLES_TIMEOUT_S = 5.0
H5_SUFFIXES = (".h5", ".hdf5")
# Below this much free space the recorder stops and closes the file while it still can: an HDF5
# file that meets a full disk mid-write may be left damaged, a closed one is complete.
MIN_FREE_BYTES = 4 * 1024 * 1024


class CaptureWriter(Protocol):
    path: Path

    @property
    def rows(self) -> int: ...

    def write(self, samples: np.ndarray, step: np.ndarray | list[str] | None = None) -> None: ...

    def flush(self, link: dict[str, Any] | None = None) -> None: ...

    def close(self, link: dict[str, Any] | None = None) -> None: ...


def is_h5_path(path: str | Path) -> bool:
    return str(path).lower().endswith(H5_SUFFIXES)


def open_capture_writer(path: str | Path, device: dict[str, Any] | None = None, with_step: bool = False,
                        port: str = "", protocol: str = "") -> CaptureWriter:
    """A streaming writer for ``path``: the HDF5 capture file for .h5/.hdf5, else capture CSV."""
    if is_h5_path(path):
        return H5CaptureWriter(path, device=device, with_step=with_step, port=port, protocol=protocol)
    return _CsvWriterAdapter(CsvCaptureWriter(path, with_step=with_step))


class _CsvWriterAdapter:
    """The CSV writer behind the common writer interface (a CSV has no room for link statistics)."""

    def __init__(self, writer: CsvCaptureWriter):
        self._writer = writer
        self.path = writer.path

    @property
    def rows(self) -> int:
        return self._writer.rows

    def write(self, samples: np.ndarray, step: np.ndarray | list[str] | None = None) -> None:
        self._writer.write(samples, step)

    def flush(self, link: dict[str, Any] | None = None) -> None:
        self._writer.flush()

    def close(self, link: dict[str, Any] | None = None) -> None:
        self._writer.close()


class Recorder:
    """Writes sample batches to a capture file as they come.

    Samples whose device time does not increase past the last written one (a replayed frame, a
    device restart) are left out and counted in ``non_increasing``: the capture formats require
    strictly increasing ``t``. Rows get the label in :attr:`step` at the time they are written.
    """

    def __init__(self, path: str | Path, device: dict[str, Any] | None = None, with_step: bool = False,
                 port: str = "", protocol: str = "", flush_interval_s: float = FLUSH_INTERVAL_S):
        self.writer = open_capture_writer(path, device=device, with_step=with_step, port=port,
                                          protocol=protocol)
        self.path = Path(path)
        self.step = ""
        self.non_increasing = 0
        self.first_t_us: int | None = None
        self.last_t_us: int | None = None
        self._with_step = with_step
        self._flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._unflushed_bytes = 0

    @property
    def rows(self) -> int:
        return self.writer.rows

    @property
    def device_time_s(self) -> float:
        if self.first_t_us is None or self.last_t_us is None:
            return 0.0
        return (self.last_t_us - self.first_t_us) * 1e-6

    def write(self, samples: np.ndarray, link: dict[str, Any] | None = None) -> int:
        """Append a batch; returns the number of rows written."""
        if len(samples) == 0:
            self.tick(link)
            return 0
        t_us = samples["t_us"]
        last = -1 if self.last_t_us is None else self.last_t_us
        running_max = np.maximum.accumulate(np.concatenate([[last], t_us.astype(np.int64)]))
        keep = t_us.astype(np.int64) > running_max[:-1]
        if not keep.all():
            self.non_increasing += int((~keep).sum())
            samples = samples[keep]
            if len(samples) == 0:
                self.tick(link)
                return 0
        self._check_space(samples.nbytes, link)
        step = [self.step] * len(samples) if self._with_step else None
        self.writer.write(samples, step)
        self._unflushed_bytes += samples.nbytes
        if self.first_t_us is None:
            self.first_t_us = int(samples["t_us"][0])
        self.last_t_us = int(samples["t_us"][-1])
        self.tick(link)
        return len(samples)

    def _check_space(self, batch_bytes: int, link: dict[str, Any] | None) -> None:
        # What the writer still holds in memory (HDF5 caches chunks until a flush) needs room too.
        free = shutil.disk_usage(self.path.parent).free - self._unflushed_bytes - batch_bytes
        if free < MIN_FREE_BYTES:
            self.writer.close(link)
            raise OutputFileError(self.path, f"the disk is almost full ({free // 1024} KiB left): the "
                                  f"capture stopped at {self.rows} samples and the file is complete; free "
                                  f"space and capture again")

    def tick(self, link: dict[str, Any] | None = None) -> None:
        """Flush if the last flush is a second old (call it when idle, too)."""
        now = time.monotonic()
        if now - self._last_flush >= self._flush_interval_s:
            self.writer.flush(link)
            self._last_flush = now
            self._unflushed_bytes = 0

    def close(self, link: dict[str, Any] | None = None) -> None:
        self.writer.close(link)


@dataclass
class CaptureResult:
    path: Path
    rows: int
    device_time_s: float
    link: LinkStats
    ended_by: str  # "duration", "interrupted", "stopped" or "link error"
    error: DriverError | None = None
    non_increasing: int = 0


StatusCallback = Callable[[LinkStats, int, float], None]


def record(device: Device, path: str | Path, duration_s: float | None = None,
           on_status: StatusCallback | None = None, status_interval_s: float = 0.25,
           stop: threading.Event | None = None, handle_sigint: bool = True,
           no_samples_timeout_s: float = NO_SAMPLES_TIMEOUT_S) -> CaptureResult:
    """Capture from ``device`` into ``path`` until ``duration_s`` of device clock, Ctrl-C, ``stop`` or
    a link error. Every sample received before the end is in the file when this returns.

    No sample in the first ``no_samples_timeout_s`` ends it with ``NoSamples``.
    A link error (``PortLost``, ...) does not raise: it ends the capture and is returned in
    ``error``. A write error (disk full) raises ``OutputFileError`` after keeping what was written.
    """
    recorder = Recorder(path, device=device.info, port=device.port, protocol=device.protocol)
    interrupted = threading.Event()
    restore = _install_sigint(interrupted) if handle_sigint else None
    limit_us = None if duration_s is None else int(round(duration_s * 1e6))
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
                batch = device.read(READ_TIMEOUT_S)
            except DriverError as exc:
                error, ended_by = exc, "link error"
                break
            now = time.monotonic()
            if recorder.first_t_us is None and not len(batch) and now - started > no_samples_timeout_s:
                error, ended_by = NoSamples(
                    f"{device.port}: no sample arrived in {no_samples_timeout_s:g} s "
                    f"({device.stats.bytes} bytes read); check that the unit streams, and the --protocol "
                    f"and baud rate", device.port
                ), "link error"
                break
            done = False
            if limit_us is not None and len(batch):
                start = recorder.first_t_us if recorder.first_t_us is not None else int(batch["t_us"][0])
                inside = batch["t_us"].astype(np.int64) - start < limit_us
                done = not inside.all()
                batch = batch[inside]
            recorder.write(batch, _link(device))
            if on_status is not None and now - last_status >= status_interval_s:
                on_status(device.stats, recorder.rows, recorder.device_time_s)
                last_status = now
            if done or (wall_deadline is not None and now > wall_deadline):
                ended_by = "duration"
                break
    except KeyboardInterrupt:
        ended_by = "interrupted"
    finally:
        if restore is not None:
            restore()
        recorder.close(_link(device, recorder))
    if on_status is not None:
        on_status(device.stats, recorder.rows, recorder.device_time_s)
    return CaptureResult(path=recorder.path, rows=recorder.rows, device_time_s=recorder.device_time_s,
                         link=device.stats, ended_by=ended_by, error=error,
                         non_increasing=recorder.non_increasing)


def _link(device: Device, recorder: Recorder | None = None) -> dict[str, Any]:
    link = device.stats.as_dict()
    if recorder is not None:
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
