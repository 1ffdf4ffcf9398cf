"""A three-axis rate table: the station's whole turntable sequence (twelve positions and the turns about
x, y and z) through the runner's table operator over :class:`MountedTable` on the ACUTROL emulator over a
real TCP socket (``acutrol://127.0.0.1:PORT?axes=3``), the simulated unit on a pty, then calibrated and
checked against the unit's truth; and the mount's kinematics on their own.

Every wait is on a condition with a timeout, so the suite holds with both cores busy.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from drivers.instruments import Table
from drivers.instruments.errors import InstrumentError
from drivers.paced_port import open_paced
from mocks.device import SimDevice
from mocks.instruments.acutrol import AcutrolEmulator, gimbal_attitude
from mocks.instruments.serving import ByteServer
from mocks.pty_server import PtyServer
from mocks.rig import Static
from mocks.truth import UnitTruth
from station.acquisition.runner import RunOptions, SequenceRunner
from station.acquisition.sequences import SIX_POSITION, TWELVE_EXTRA, builtin, pose_vector
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.factory.run import TableOperator
from station.instruments.limits import Limits, limited
from station.instruments.mounted_table import (
    MountedTable,
    axis_vector,
    mount_matrix,
    tilt_angles,
    up_direction,
)
from station.instruments.open import open_instrument

SEED = 27
RATE_HZ = 100
SPEED = 4.0  # the unit's clock (and so the table's motion) runs 4x the wall clock
POSES = SIX_POSITION + TWELVE_EXTRA


def wait_for(condition: Callable[[], bool], what: str, timeout_s: float = 20.0) -> float:
    """Poll ``condition`` until true; the seconds it took. Fails naming ``what`` after ``timeout_s``."""
    began = time.monotonic()
    while not condition():
        if time.monotonic() - began > timeout_s:
            pytest.fail(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.002)
    return time.monotonic() - began


@pytest.mark.parametrize(("mount", "middle"), [("+z", "+x"), ("-x", "+y"), ("+y", "-z")])
def test_every_station_pose_has_middle_and_inner_angles(mount: str, middle: str) -> None:
    m = mount_matrix(mount, middle)
    for pose in POSES:
        middle_deg, inner_deg = tilt_angles(m, axis_vector(pose))
        up = up_direction(m, middle_deg, inner_deg, axis_vector(pose))
        assert up == pytest.approx((0, 0, 1), abs=1e-12)
        # from zero, multiples of 45 deg, within one turn
        for angle in (middle_deg, inner_deg):
            assert -180.0 < angle <= 180.0 and angle / 45.0 == pytest.approx(round(angle / 45.0), abs=1e-9)
        # the emulator's kinematics agree: the pose's direction up, whatever the outer axis
        attitude = gimbal_attitude(np.array(m), [123.0, middle_deg, inner_deg])
        assert attitude @ pose_vector(pose) == pytest.approx([0, 0, 1], abs=1e-12)
        # of the two solutions, the one with the least travel (off the inner axis, where there are two)
        if abs(np.dot(pose_vector(pose), axis_vector(mount))) < 0.5:
            nearest = tilt_angles(m, axis_vector(pose), middle_deg - 10.0, inner_deg + 10.0)
            assert nearest == pytest.approx((middle_deg, inner_deg))
    # along the inner axis, the inner axis stays where it is
    assert tilt_angles(m, axis_vector(mount), 30.0, -20.0) == pytest.approx((0.0, -20.0))
    assert tilt_angles(m, axis_vector("-" + mount[1] if mount[0] == "+" else "+" + mount[1]), 0.0, 70.0) \
        == pytest.approx((180.0, 70.0))


@pytest.fixture()
def table3() -> Iterator[tuple[AcutrolEmulator, Table]]:
    emulator = AcutrolEmulator(axes=3)
    with ByteServer(emulator, "tcp") as server:
        table = open_instrument(f"acutrol://{server.address}?axes=3", kind="table")
        assert isinstance(table, Table) and table.axes == 3
        try:
            yield emulator, table
        finally:
            table.close()


def test_pose_starts_the_tilt_and_returns(table3: tuple[AcutrolEmulator, Table]) -> None:
    emulator, table = table3
    mounted = MountedTable(table, mount="+z", accel_dps2=400.0)
    mounted.pose("+x+y")
    assert emulator.position_deg(2) < 89.0  # returned once started (the tilt takes about a second)
    wait_for(lambda: (emulator.position_deg(2), emulator.position_deg(3)) == pytest.approx((90.0, 45.0)),
             "the middle and inner axes at 90 and 45 deg")
    assert mounted.tilt_targets("+x+y") == pytest.approx((90.0, 45.0))
    sent = len(emulator.lines)
    mounted.pose("+x+y")  # already there: the middle and inner axes are only read
    demands = [line for line in emulator.lines[sent:] if line.startswith((":M", ":D"))]
    assert demands and all(line[5] == "1" for line in demands)
    assert {line[:6] for line in emulator.lines[sent:] if line.startswith(":R")} == {":R:P 2", ":R:P 3"}


def test_turn_about_an_axis_not_up_tilts_first_then_turns_the_outer_axis(
        table3: tuple[AcutrolEmulator, Table]) -> None:
    emulator, table = table3
    mounted = MountedTable(table, mount="+z", accel_dps2=400.0)
    mounted.rotate("-y", 90.0, 45.0)  # -y up: the middle axis at -90 deg, then the outer turns +90
    assert emulator.position_deg(2) == pytest.approx(-90.0, abs=0.05)
    mounted.wait(20.0)
    assert emulator.position_deg(1) == pytest.approx(90.0, abs=0.05)
    assert [float(line.split(",")[1]) for line in emulator.lines if line.startswith(":D:R 1,")][0] == 45.0
    assert mounted.wait_stopped(5.0) < 5.0


def test_a_stop_during_the_tilt_before_a_turn_ends_the_turn(table3: tuple[AcutrolEmulator, Table]) -> None:
    # Abort while the unit is being tilted for a turn: rotate() ends at once, the turn never starts.
    emulator, table = table3
    capped = limited(table, Limits(max_rate_dps=20.0))  # a slow tilt: 90 deg at 20 deg/s
    assert isinstance(capped, Table)
    mounted = MountedTable(capped, mount="+z", accel_dps2=100.0)
    failed: list[BaseException] = []

    def turn() -> None:
        try:
            mounted.rotate("+x", 360.0, 90.0, timeout_s=60.0)
        except InstrumentError as exc:
            failed.append(exc)

    worker = threading.Thread(target=turn)
    worker.start()
    wait_for(lambda: abs(emulator.rate_dps(2)) > 5.0, "the tilt under way")
    started = time.monotonic()
    mounted.stop()
    worker.join(timeout=10.0)
    assert not worker.is_alive() and time.monotonic() - started < 5.0
    assert failed and "stopped while tilting" in str(failed[0])
    assert not any(line.startswith(":D:R 1,") and not line.endswith(",0") for line in emulator.lines)
    wait_for(lambda: all(emulator.rate_dps(a) == 0.0 for a in (1, 2, 3)), "every axis at rest")


def test_a_tilt_stays_within_the_plans_rate(table3: tuple[AcutrolEmulator, Table]) -> None:
    emulator, table = table3
    capped = limited(table, Limits(max_rate_dps=60.0, max_accel_dps2=400.0))
    assert isinstance(capped, Table)
    mounted = MountedTable(capped, mount="+z", accel_dps2=400.0)
    assert mounted.max_rate_dps == 60.0  # from the plan's limits
    mounted.pose("-z")  # half a turn of the middle axis: sqrt(400 x 180) = 268 deg/s unless capped
    peak = [0.0]

    def arrived() -> bool:
        peak[0] = max(peak[0], abs(emulator.rate_dps(2)))
        return emulator.position_deg(2) == pytest.approx(180.0) and emulator.rate_dps(2) == 0.0
    wait_for(arrived, "the middle axis at 180 deg")
    assert 30.0 < peak[0] <= 60.0 + 1e-9


def test_twelve_positions_and_turns_on_a_three_axis_table(capsys: pytest.CaptureFixture[str]) -> None:
    """The whole sequence, then the turntable calibration against the unit's truth with the tolerances of
    the simulated factory line (tests/test_factory_run.py): accelerometer M 2e-3, b 6e-3 m/s^2; gyroscope
    M 4e-3, b 2e-3 rad/s."""
    truth = UnitTruth.random(SEED)
    sequence = builtin("twelve-position", rotations=True, hold_s=2.0, rotation_rate_dps=90.0, settle_s=1.0)
    began = time.monotonic()
    unit = SimDevice(truth, seed=SEED, rate_hz=RATE_HZ, scenario=[Static("+z", 1.0)])
    with PtyServer(unit, block_s=0.05, speed=SPEED) as served:
        emulator = AcutrolEmulator(axes=3, device=served.device, mount="+z")
        with ByteServer(emulator, "tcp") as server:
            table = open_instrument(f"acutrol://{server.address}?axes=3", kind="table")
            assert isinstance(table, Table)
            capped = limited(table, Limits(max_rate_dps=120.0, max_accel_dps2=200.0))  # a plan's table limits
            assert isinstance(capped, Table)
            mounted = MountedTable(capped, mount="+z", accel_dps2=200.0)
            device = open_paced(served.port_path)
            try:
                operator = TableOperator(mounted, timeout_s=60.0)
                options = RunOptions(step_timeout_s=60.0, max_attempts=2)
                result = SequenceRunner(device, sequence, operator, options).run()
            finally:
                mounted.stop()
                device.close()
                table.close()
    wall = time.monotonic() - began
    assert operator.error is None, operator.error
    assert result.outcome == "completed", result.reason
    assert [(s.label, s.status) for s in result.steps] == [(label, "accepted") for label in sequence.labels]
    capture = result.capture
    assert [label for label, _ in capture.segments()] == sequence.labels
    # the table did it: tilts on the middle and inner axes, every turn on the outer one at the step's rate
    assert any(line.startswith(":D:P 2,") for line in emulator.lines)
    assert any(line.startswith(":D:P 3,") for line in emulator.lines)
    outer_rates = [float(line.split(",")[1]) for line in emulator.lines if line.startswith(":D:R 1,")]
    assert sorted({abs(r) for r in outer_rates if r}) == [90.0]

    data = TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step, rate_hz=float(RATE_HZ))
    report = calibrate_turntable(data, TurntableSettings(gravity=truth.gravity))
    errors = {}
    for sensor, tol_m in (("accel", 2e-3), ("gyro", 4e-3)):
        true, cal = getattr(truth, sensor), getattr(report, sensor)
        errors[sensor] = (float(np.abs(cal.matrix - true.matrix).max()),
                          float(np.abs(cal.bias - true.bias).max()))
        assert np.abs(true.matrix - np.eye(3)).max() > 2 * tol_m  # the unit is far from ideal
    with capsys.disabled():
        print(f"\nthree-axis table, {len(sequence)} steps, {len(capture)} samples at x{SPEED:g}: "
              f"{wall:.1f} s wall; |M - M_true|, |b - b_true| max: accel {errors['accel'][0]:.2e}, "
              f"{errors['accel'][1]:.2e} m/s^2; gyro {errors['gyro'][0]:.2e}, {errors['gyro'][1]:.2e} rad/s")
    assert errors["accel"][0] < 2e-3 and errors["accel"][1] < 6e-3
    assert errors["gyro"][0] < 4e-3 and errors["gyro"][1] < 2e-3
