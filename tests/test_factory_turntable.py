"""The turntable driver against the simulated table, both ends on real pseudo-terminals, with the unit's
own samples showing the motion the table was asked for."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator

import numpy as np
import pytest

from drivers import open_device
from drivers.errors import CommandRejected, CommandTimeout, PortLost
from drivers.interface import Device
from drivers.turntable import Turntable
from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from mocks.turntable_sim import TurntableSim
from station.acquisition import checks
from station.acquisition.sequences import pose_vector


@pytest.fixture()
def rig() -> Iterator[tuple[Device, Turntable, TurntableSim]]:
    with PtyServer(SimDevice(seed=11, rate_hz=100)) as server, TurntableSim(server.device) as sim:
        device = open_device(server.port_path)
        table = Turntable(sim.port_path)
        try:
            yield device, table, sim
        finally:
            table.close()
            device.close()


def samples_for(device: Device, seconds: float) -> np.ndarray:
    end = time.monotonic() + seconds
    batches = []
    while time.monotonic() < end:
        batches.append(device.read(0.05))
    return np.concatenate(batches)


def test_identify_and_state(rig: tuple[Device, Turntable, TurntableSim]) -> None:
    _, table, _ = rig
    assert table.identify() == {"model": "imu-sim-table", "serial": "TT-SIM-0001", "firmware": "1.0.0"}
    state = table.state()
    assert (state.state, state.up, state.idle) == ("IDLE", "+z", True)


@pytest.mark.parametrize("pose", ["+x", "-y", "+x+y"])
def test_pose_moves_the_unit(rig: tuple[Device, Turntable, TurntableSim], pose: str) -> None:
    device, table, _ = rig
    table.pose(pose)
    assert table.state().state == "MOVING"
    assert table.wait_idle(10.0).up == pose
    device.read(0)
    s = samples_for(device, 0.4)
    check = checks.pose_check(s["acc"], pose_vector(pose), tolerance_deg=3.0)
    assert check.ok, check  # gravity along the asked axes, within 3 deg (misalignment, bias)
    assert checks.stillness(s["acc"], s["gyro"]).still


def test_rotation_turns_the_unit_by_the_asked_angle(rig: tuple[Device, Turntable, TurntableSim]) -> None:
    device, table, _ = rig
    table.pose("+y")
    table.wait_idle(10.0)
    device.read(0)
    table.rotate("+y", -180.0, 360.0)
    batches = []
    while not table.state().idle:
        batches.append(device.read(0.05))
    batches.append(samples_for(device, 0.2))
    s = np.concatenate(batches)
    angle = checks.integrated_angle_deg(s["t_us"] * 1e-6, s["gyro"].astype(float), 1, 0.0)[-1]
    # raw gyro: scale 1 +- 1 %, bias ~0.5 deg/s over ~1 s: within 4 % of the asked turn
    assert angle == pytest.approx(-180.0, rel=0.04)
    assert table.state().turned_deg == -180.0


def test_refusals(rig: tuple[Device, Turntable, TurntableSim]) -> None:
    _, table, sim = rig
    for line, code in (("FOO", 1), ("POSE +q", 2), ("POSE +x+x", 2), ("ROT +z 0 90", 2),
                       ("ROT +z 90 5000", 2), ("ROT z 90 90", 2), ("HOME now", 2)):
        with pytest.raises(CommandRejected) as info:
            table.command(line)
        assert info.value.status == code, line
        assert table.port in str(info.value)
    table.command("POSE -z")
    with pytest.raises(CommandRejected, match="busy") as info:
        table.command("POSE +z")
    assert info.value.status == 3
    table.pose("+z")  # the driver waits for IDLE itself
    table.wait_idle(10.0)
    assert [c for c in sim.commands if c.startswith("POSE")][-1] == "POSE +z"
    with pytest.raises(ValueError):
        table.pose("up")
    with pytest.raises(ValueError):
        table.rotate("+w", 90, 90)


def test_silent_port_times_out() -> None:
    master, slave = os.openpty()
    try:
        table = Turntable(os.ttyname(slave), reply_timeout_s=0.2)
        with pytest.raises(CommandTimeout, match="did not answer"):
            table.identify()
        table.close()
    finally:
        os.close(master)
        os.close(slave)


def test_table_gone_is_port_lost() -> None:
    with PtyServer(SimDevice(seed=1, rate_hz=50)) as server:
        sim = TurntableSim(server.device).start()
        table = Turntable(sim.port_path)
        assert table.identify()["serial"] == "TT-SIM-0001"
        sim.stop()  # closes the master: the port vanishes under the driver
        with pytest.raises((PortLost, CommandTimeout)) as info:
            table.state()
        table.close()
    assert sim.port_path in str(info.value)
