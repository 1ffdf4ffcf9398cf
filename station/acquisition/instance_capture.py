"""Record a board of several IMUs into one capture file per IMU instance.

A board that streams several IMU instances (MAVLink ``SCALED_IMU``/``SCALED_IMU2``/``SCALED_IMU3`` or
the ``id`` of ``HIGHRES_IMU``/``RAW_IMU``; a frame description whose fields give ``imu: k``) is
opened with ``instances=True`` (``protocols.instances``), and each instance's samples go to a
:class:`~station.acquisition.recorder.Recorder` of its own: ``NAME.csv`` (or ``.h5``) for instance 0,
``NAME.imu<k>.csv`` for instance k >= 1 (:func:`instance_path`). Every file has the same step labels
and the board's own clock (each instance's timestamps as the board sent them), and names its
instance in an ``instance: k`` metadata line (the HDF5 file: in its ``device`` attribute), which is
how the multi-IMU calibration pairs the files up.

A file is opened when its instance's first sample comes, so ``--instances all`` records whatever the
board streams; an instance asked for that never comes leaves no file and is reported. The loop is
:func:`~station.acquisition.recorder.record`'s (``capture_loop``), for several recorders: it ends on the
duration (every file full), Ctrl-C, a stop event or a link error, and in every case each file keeps every
sample of its instance received before the end (the other instances' samples buffered when the
link broke included).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from drivers import DEFAULT_BAUDRATE, Device, DriverError, LinkStats, NoSamples, PortLost, open_device
from protocols.instances import MAX_INSTANCE
from protocols.registry import make_decoder
from station.acquisition.port_capture import StatusCallback, StatusDisplay, prepare_device
from station.acquisition.recorder import (
    NO_SAMPLES_TIMEOUT_S,
    CaptureResult,
    Recorder,
    _with_clock,
    capture_loop,
)
from station.errors import StationError

ALL = "all"


def instance_path(path: str | Path, instance: int) -> Path:
    """The capture file of IMU ``instance``: ``path`` itself for 0, ``NAME.imu<k>.SUFFIX`` for k >= 1.

    Parameters
    ----------
    path : str or Path
        The capture file named on the command line (``NAME.csv``, ``NAME.h5``).
    instance : int
        The IMU instance.

    Returns
    -------
    Path
    """
    path = Path(path)
    if instance == 0:
        return path
    return path.with_name(f"{path.stem}.imu{instance}{path.suffix}")


def parse_instances(text: str) -> tuple[int, ...] | None:
    """``--instances``: ``all`` (None: whatever the board streams) or a comma-separated list ``0,1,2``.

    Parameters
    ----------
    text : str

    Returns
    -------
    tuple of int, or None for ``all``

    Raises
    ------
    ValueError
        Not ``all`` nor a list of distinct instances 0..255, saying what to write.
    """
    text = text.strip()
    if text.lower() == ALL:
        return None
    values: list[int] = []
    parts = text.split(",")
    within = f" (in {text!r})" if len(parts) > 1 else ""
    for part in parts:
        part = part.strip()
        if not part.isdigit() or int(part) > MAX_INSTANCE:
            raise ValueError(f"{part!r}{within} is not an IMU instance: give all, or instances "
                             f"0..{MAX_INSTANCE} separated by commas (0,1,2)")
        if int(part) in values:
            raise ValueError(f"instance {part} is given twice{within}")
        values.append(int(part))
    return tuple(values)


@dataclass
class InstancesResult:
    """What a capture of several IMU instances produced: a :class:`CaptureResult` per file, and why it ended.

    ``captures`` holds the instances that have a file, in instance order; ``missing`` the instances
    asked for that the board never sent (no file); ``seen`` every instance the board streamed.
    """

    captures: dict[int, CaptureResult]
    link: LinkStats
    ended_by: str
    error: DriverError | None = None
    missing: list[int] = field(default_factory=list)
    seen: list[int] = field(default_factory=list)


class _Files:
    """The recorders of the instances, opened as each instance's first samples come."""

    def __init__(self, device: Device, path: Path, wanted: Sequence[int] | None, duration_s: float | None):
        self.device = device
        self.path = path
        self.wanted = None if wanted is None else set(wanted)
        self.duration_s = duration_s
        self.recorders: dict[int, Recorder] = {}

    def write(self, batches: dict[int, np.ndarray], link: dict[str, Any]) -> None:
        for instance, batch in batches.items():
            if not len(batch) or (self.wanted is not None and instance not in self.wanted):
                continue
            recorder = self.recorders.get(instance)
            if recorder is None:
                device = self.device
                recorder = self.recorders[instance] = Recorder(
                    instance_path(self.path, instance), device={**device.info, "instance": instance},
                    port=device.port, protocol=device.protocol, duration_s=self.duration_s)
            recorder.write(batch, link)
        for recorder in self.recorders.values():
            recorder.tick(link)

    @property
    def received(self) -> int:
        return sum(r.received for r in self.recorders.values())

    @property
    def rows(self) -> int:
        return sum(r.rows for r in self.recorders.values())

    @property
    def device_time_s(self) -> float:
        return max((r.device_time_s for r in self.recorders.values()), default=0.0)

    @property
    def full(self) -> bool:
        return bool(self.recorders) and all(r.full for r in self.recorders.values())


def _batches(device: Device, timeout: float) -> dict[int, np.ndarray]:
    """What the device received of every instance: :meth:`~Device.read`'s and the others'."""
    first = device.read(timeout)
    instance = device.imu_instance
    out = device.take_instances()
    if len(first):
        out[0 if instance is None else instance] = first
    return out


def _link(device: Device, files: _Files) -> dict[str, Any]:
    stats = device.stats
    link = stats.as_dict()
    link["clock_outliers"] = sum(r.clock_outliers for r in files.recorders.values())
    link["clock_jumps"] = sum(len(r.clock_jumps) for r in files.recorders.values())
    link["non_increasing_dropped"] = sum(r.non_increasing for r in files.recorders.values())
    return link


def record_instances(device: Device, path: str | Path, instances: Sequence[int] | None = None,
                     duration_s: float | None = None, on_status: StatusCallback | None = None,
                     status_interval_s: float = 0.25, stop: threading.Event | None = None,
                     handle_sigint: bool = True,
                     no_samples_timeout_s: float = NO_SAMPLES_TIMEOUT_S) -> InstancesResult:
    """Capture every IMU instance of ``device`` (opened with ``instances=True``) into its own file.

    Parameters
    ----------
    device : Device
        The board, opened with ``instances=True``.
    path : str or Path
        Instance 0's file; the others' are named by :func:`instance_path`.
    instances : sequence of int, optional
        The instances to record; None: every instance the board streams.
    duration_s : float, optional
        Seconds of device clock each file records; None: until Ctrl-C, ``stop`` or a link error.
    on_status : callable, optional
        ``(link statistics, rows of all files, device seconds)`` as the capture goes.
    status_interval_s : float
        Seconds between status calls.
    stop : threading.Event, optional
        Ends the capture when set.
    handle_sigint : bool
        The first Ctrl-C ends the capture cleanly (from the main thread).
    no_samples_timeout_s : float
        No sample of an instance asked for in this long ends the capture with ``NoSamples``.

    Returns
    -------
    InstancesResult
        One :class:`CaptureResult` per file written, and how the capture ended.
    """
    path = Path(path)
    files = _Files(device, path, instances, duration_s)

    def nothing_came() -> DriverError:
        why = _nothing_asked(device, instances, no_samples_timeout_s)
        return NoSamples(f"{device.port}: {why}", device.port)

    try:
        ended_by, error = capture_loop(
            device, files, lambda timeout: _batches(device, timeout),
            lambda batches: files.write(batches, _link(device, files)), nothing_came, duration_s=duration_s,
            on_status=on_status, status_interval_s=status_interval_s, stop=stop, handle_sigint=handle_sigint,
            no_samples_timeout_s=no_samples_timeout_s)
    finally:
        # what the link delivered before it ended (or before Ctrl-C) still goes into its file
        try:
            files.write(_batches(device, 0.0), _link(device, files))
        except DriverError:
            files.write(device.take_instances(), _link(device, files))
        link = _link(device, files)
        for recorder in files.recorders.values():
            recorder.close(link)
    if on_status is not None:
        on_status(device.stats, files.rows, files.device_time_s)
    return _result(device, files, instances, ended_by, error)


def _nothing_asked(device: Device, instances: Sequence[int] | None, timeout_s: float) -> str:
    seen = sorted(device.imu_instances)
    if instances is not None and seen:
        return (f"the board streams IMU instance(s) {', '.join(map(str, seen))}, none of "
                f"--instances {','.join(map(str, instances))} in {timeout_s:g} s; give some of those, or all")
    return (f"no sample arrived in {timeout_s:g} s ({device.stats.bytes} bytes read); check that the unit "
            f"streams, and the --protocol and baud rate")


def _result(device: Device, files: _Files, instances: Sequence[int] | None, ended_by: str,
            error: DriverError | None) -> InstancesResult:
    captures: dict[int, CaptureResult] = {}
    for instance in sorted(files.recorders):
        recorder = files.recorders[instance]
        if recorder.rows == 0:
            recorder.path.unlink(missing_ok=True)  # its samples were all left out by the clock guard
            continue
        captures[instance] = CaptureResult(
            path=recorder.path, rows=recorder.rows, device_time_s=recorder.device_time_s,
            link=_with_clock(device.stats, recorder), ended_by=ended_by, error=error,
            non_increasing=recorder.non_increasing, clock_jumps=list(recorder.clock_jumps),
            field_dropped=recorder.writer.field_dropped)
    seen = sorted(device.imu_instances)
    missing = [] if instances is None else [k for k in instances if k not in captures]
    if not captures and error is None:
        why = {"interrupted": "interrupted before any sample was kept",
               "duration": "the time ran out before any sample was kept"}.get(ended_by, "the capture ended "
                                                                                 "before any sample was kept")
        error, ended_by = NoSamples(f"{device.port}: {why}; no file was written", device.port), "link error"
    stats = device.stats
    stats.clock_outliers = sum(r.clock_outliers for r in files.recorders.values())
    stats.clock_jumps = sum(len(r.clock_jumps) for r in files.recorders.values())
    return InstancesResult(captures, stats, ended_by, error, missing, seen)


def check_protocol(protocol: str) -> None:
    """Refuse, before any port is opened, a protocol that cannot tell IMU instances apart.

    Parameters
    ----------
    protocol : str
        The decoder name with its option (``mavlink``, ``frame:board.yaml``).

    Raises
    ------
    StationError
        Naming the protocols that can.
    """
    decoder = make_decoder(protocol)
    enable = getattr(decoder, "decode_instances", None)
    if enable is None:
        raise StationError(f"--instances: the {protocol} protocol carries one IMU; several IMU instances "
                           f"come over --protocol mavlink, or a frame description whose fields give imu: k")
    try:
        enable()
    except ValueError as exc:
        raise StationError(f"--instances: {exc}") from None


def capture_instances_to_file(port: str, output: Path, instances: Sequence[int] | None = None,
                              protocol: str = "mavlink", duration_s: float | None = None,
                              rate_hz: int | None = None, baudrate: int = DEFAULT_BAUDRATE,
                              err: IO[str] | None = None,
                              status: StatusDisplay | None = None) -> InstancesResult:
    """Open the board at ``port`` for several IMU instances, prepare it, and record one file per instance.

    Parameters
    ----------
    port : str
        Device path or pyserial URL.
    output : Path
        Instance 0's capture file (``.csv``, ``.h5``/``.hdf5``); the others' by :func:`instance_path`.
    instances : sequence of int, optional
        The instances to record; None: all the board streams.
    protocol : str
        A protocol that tells instances apart: ``mavlink`` or ``frame:FILE`` (its fields with ``imu:``).
    duration_s, rate_hz, baudrate, err, status
        As :func:`~station.acquisition.port_capture.capture_to_file`.

    Returns
    -------
    InstancesResult

    Raises
    ------
    StationError
        The protocol carries one IMU (before any port is opened).
    """
    err = err if err is not None else sys.stderr
    check_protocol(protocol)
    with open_device(port, protocol=protocol, baudrate=baudrate, instances=True) as device:
        try:
            prepare_device(device, rate_hz, err)
        except PortLost:
            pass  # record_instances() keeps what arrived before the loss, then reports it
        display = status(duration_s) if status is not None else nullcontext(None)
        with display as on_status:
            return record_instances(device, output, instances, duration_s=duration_s, on_status=on_status)
