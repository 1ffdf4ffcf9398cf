"""Record a unit at a port into a capture file: open it, prepare it, record until done.

Shared by ``imu-station capture`` and the demo. The caller shows progress: ``status`` makes the
live display once the unit is prepared (so the unit's own lines come before it).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import IO, Any

from drivers import (
    DEFAULT_BAUDRATE,
    CommandTimeout,
    CommandUnsupported,
    Device,
    LinkStats,
    PortLost,
    open_device,
)
from station.acquisition.recorder import CaptureResult, record
from station.common.text import printable

StatusCallback = Callable[[LinkStats, int, float], None]
"""``on_status(link statistics, rows written, device seconds recorded)``, called as the capture goes."""
StatusDisplay = Callable[[float | None], AbstractContextManager[StatusCallback]]
"""Makes the live display for a capture of the given duration; entering it gives the callback."""


def _get_info_quickly(device: Device) -> dict[str, Any]:
    """GET_INFO sent at most twice: a unit that does not answer is recorded anyway."""
    return device.get_info(timeout=0.5, retries=1)


def prepare_device(device: Device, rate_hz: int | None, err: IO[str]) -> None:
    """Ask the unit who it is, set its rate if asked, and start it if it does not stream yet.

    A unit that does not answer GET_INFO or START_STREAM is still recorded (a warning says so):
    a device streams from power-up. A refused or unanswered SET_RATE is an error; after a rate
    change the capture starts with the samples at the new rate.

    Parameters
    ----------
    device : Device
        The open unit.
    rate_hz : int, optional
        The output rate to set first (SET_RATE); None keeps the unit's.
    err : text stream
        Where the unit's identity and the warnings are printed.
    """
    try:
        info = _get_info_quickly(device)
        print(f"unit: {printable(info.get('model', '?'))} serial {printable(info.get('serial', '?'))} "
              f"firmware {printable(info.get('firmware', '?'))} at {printable(info.get('rate_hz', '?'))} Hz",
              file=err)
    except CommandUnsupported:
        return
    except CommandTimeout as exc:
        print(f"warning: {exc}; recording without the unit's info", file=err)
    if rate_hz is not None:
        device.set_rate(rate_hz)
        try:
            _get_info_quickly(device)  # the file records the unit's info at the new rate
        except CommandTimeout:
            pass
        device.read(0)  # samples at the old rate are not part of this capture
    if device.stats.samples == 0:
        try:
            device.start()
        except CommandTimeout as exc:
            print(f"warning: {exc}; recording what it sends", file=err)


def capture_to_file(port: str, output: Path, protocol: str = "native", duration_s: float | None = None,
                    rate_hz: int | None = None, baudrate: int = DEFAULT_BAUDRATE, err: IO[str] | None = None,
                    status: StatusDisplay | None = None) -> CaptureResult:
    """Open the unit at ``port``, prepare it, and record into ``output``.

    Parameters
    ----------
    port : str
        Device path or pyserial URL (a ``sim://`` URL needs ``mocks.register_sim_url()`` first).
    output : Path
        The capture file: ``.csv``, or ``.h5``/``.hdf5``.
    protocol : str
        Decoder name, with its option if any (``ascii:@50``).
    duration_s : float, optional
        Seconds of device clock to record; None records until Ctrl-C or the link breaks.
    rate_hz : int, optional
        Output rate to set first.
    baudrate : int
        Line speed of a real serial port.
    err : text stream, optional
        Where the unit's identity and warnings go (default: stderr).
    status : callable, optional
        Makes the live display (see :data:`StatusDisplay`); None shows nothing.

    Returns
    -------
    CaptureResult
        Rows written, device time, link statistics, and the error that ended it, if any.
    """
    err = err if err is not None else sys.stderr
    with open_device(port, protocol=protocol, baudrate=baudrate) as device:
        try:
            prepare_device(device, rate_hz, err)
        except PortLost:
            pass  # record() saves what arrived before the loss, then reports it
        display = status(duration_s) if status is not None else nullcontext(None)
        with display as on_status:
            result = record(device, output, duration_s=duration_s, on_status=on_status)
        hint = other_instances_hint(device)
        if hint:
            print(hint, file=err)
        return result


def other_instances_hint(device: Device) -> str:
    """What to say when the board streams IMU instances besides the one recorded ("" when it does not).

    Parameters
    ----------
    device : Device
        The unit, after the capture.

    Returns
    -------
    str
    """
    others = [k for k in device.imu_instances if k != device.imu_instance]
    if not others:
        return ""
    return (f"note: the board also streams IMU instance{'s' * (len(others) > 1)} "
            f"{', '.join(map(str, others))}: --instances all records them")
