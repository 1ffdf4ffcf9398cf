"""Record a unit still over several power-ups: one capture file per turn-on, for the turn-on bias
repeatability (``imu-station characterise --port``).

Between records the unit is restarted with the native RESTART command (``shared/specs/native-protocol.md``);
a unit that answers ACK status 1 cannot restart itself, and the operator is asked to power-cycle it
(``power_cycle``): the port is closed meanwhile (a USB unit's port vanishes with its power) and opened
again afterwards. With a bench supply (``supply_cycle``, ``station.instruments.power_cycle``) the unit is
power-cycled through it instead of RESTART, then the station waits for its samples to come back.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import IO

from drivers import DEFAULT_BAUDRATE, CommandRejected, CommandUnsupported, Device, open_device
from protocols import native
from station.acquisition.port_capture import StatusDisplay, prepare_device
from station.acquisition.recorder import record
from station.errors import StationError

RESTART_SETTLE_S = 0.2  # wall seconds after the ACK: the samples of the old power-up are flushed
REOPEN_TRIES = 20
SAMPLES_BACK_S = 10.0  # wall seconds a unit may take to boot and stream after its supply comes on

PowerCycle = Callable[[int], None]
"""``power_cycle(turn_on)``: ask the operator to switch the unit off and on; returns when it is back."""


class TurnOnError(StationError):
    """The turn-ons could not be recorded: the unit cannot restart and nobody can power-cycle it,
    or a record ended early."""


def restart_unit(device: Device) -> bool:
    """Restart the unit and let the old power-up's samples flush; False when it answers that it cannot
    (ACK status 1) or its protocol has no RESTART (a text-line, Xsens, MAVLink or frame-described unit:
    power-cycle it). Another rejection is raised (``CommandRejected``)."""
    try:
        device.restart()
    except CommandUnsupported:
        return False
    except CommandRejected as exc:
        if exc.status == native.ACK_UNKNOWN:
            return False
        raise
    time.sleep(RESTART_SETTLE_S)
    return True


def _reopen(port: str, protocol: str, baudrate: int) -> Device:
    """Open the port again after a power cycle, waiting for it to come back."""
    for attempt in range(REOPEN_TRIES):
        try:
            return open_device(port, protocol=protocol, baudrate=baudrate)
        except StationError:
            if attempt == REOPEN_TRIES - 1:
                raise
            time.sleep(0.5)
    raise AssertionError("unreachable")


def _await_samples(device: Device, port: str, timeout_s: float) -> None:
    """Wait for the first samples of the new power-up (discarded: the record starts after them)."""
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        if len(device.read(min(0.2, left))):
            return
    raise TurnOnError(f"{port}: no samples {timeout_s:g} s after the supply switched the unit on; check its "
                      "wiring to the supply, the voltage (--supply-volts) and the current limit "
                      "(--supply-amps)")


def record_turn_ons(port: str, folder: Path, turn_ons: int, still_s: float, *, protocol: str = "native",
                    baudrate: int = DEFAULT_BAUDRATE, power_cycle: PowerCycle | None = None,
                    supply_cycle: PowerCycle | None = None, samples_back_s: float = SAMPLES_BACK_S,
                    err: IO[str], status: StatusDisplay | None = None) -> list[Path]:
    """Record ``turn_ons`` still captures of ``still_s`` seconds, restarting the unit before each but
    the first.

    Parameters
    ----------
    port : str
        The unit's port (device path or pyserial URL).
    folder : Path
        Where the captures go (``turn-on-01.csv``, ...).
    turn_ons : int
    still_s : float
        Seconds of device clock per record.
    protocol, baudrate :
        As for every command that opens a unit.
    power_cycle : callable, optional
        Asks the operator to power-cycle a unit that cannot restart itself; None: such a unit is an error.
    supply_cycle : callable, optional
        Power-cycles the unit through its bench supply; when given, it replaces RESTART and the operator.
    samples_back_s : float
        Wall seconds the unit may take to stream again after ``supply_cycle``.
    err : text stream
        Where progress lines go.
    status : callable, optional
        Makes the live display of one record (see ``port_capture.StatusDisplay``).

    Returns
    -------
    list of Path
        The captures, in turn-on order.

    Raises
    ------
    TurnOnError
        The unit cannot restart and ``power_cycle`` is None, or a record ended early.
    """
    folder.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    device = open_device(port, protocol=protocol, baudrate=baudrate)
    try:
        prepare_device(device, None, err)
        for k in range(turn_ons):
            if k and supply_cycle is not None:
                print(f"turn-on {k + 1}/{turn_ons}: power-cycling the unit through its supply", file=err)
                device.close()
                supply_cycle(k + 1)
                device = _reopen(port, protocol, baudrate)
                _await_samples(device, port, samples_back_s)
            elif k:
                print(f"turn-on {k + 1}/{turn_ons}: restarting the unit", file=err)
                if not restart_unit(device):
                    if power_cycle is None:
                        raise TurnOnError(f"{port}: the unit cannot restart itself (it answered RESTART "
                                          "with status 1, or its protocol has no RESTART); run characterise "
                                          "from a terminal to be asked to power-cycle it, or record each "
                                          "power-up yourself and give the files")
                    device.close()
                    power_cycle(k + 1)
                    device = _reopen(port, protocol, baudrate)
                device.read(0)  # the old power-up's samples
            path = folder / f"turn-on-{k + 1:02d}.csv"
            print(f"turn-on {k + 1}/{turn_ons}: recording {still_s:g} s still into {path}", file=err)
            display = status(still_s) if status is not None else nullcontext(None)
            with display as on_status:
                result = record(device, path, duration_s=still_s, on_status=on_status)
            if result.error is not None or result.device_time_s < 0.9 * still_s:
                reason = result.error or f"only {result.device_time_s:.3g} s recorded"
                raise TurnOnError(f"{path}: turn-on {k + 1} ended early ({reason}); check the unit and rerun")
            paths.append(path)
    finally:
        device.close()
    return paths
