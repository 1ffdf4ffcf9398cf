"""Rate tables: the generic table driver against the ACUTROL and Aerosmith emulators over a real pty or
TCP socket, the unit's gyro seeing the table's turns, the turntable sequence on a mounted table, the
faults a driver must survive, and a contract test that also runs on a real table (``--table URL``).

Every wait is on a condition with a timeout, so the suite holds with both cores busy.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from drivers import open_device
from drivers.instruments import Table
from drivers.instruments.errors import (
    InstrumentError,
    InstrumentGarbled,
    InstrumentLost,
    InstrumentTimeout,
    LimitRefused,
)
from mocks.device import SimDevice
from mocks.instruments.acutrol import AcutrolEmulator, TableEmulator
from mocks.instruments.aerosmith import AerosmithEmulator
from mocks.instruments.serving import ByteServer
from mocks.pty_server import PtyServer
from mocks.rig import Static
from station.instruments.limits import Limits, limited
from station.instruments.mounted_table import MountedTable, MountRefused
from station.instruments.open import open_instrument

EMULATORS = {"acutrol": AcutrolEmulator, "aerosmith": AerosmithEmulator}
SERVED = [("acutrol", "tcp"), ("acutrol", "pty"), ("aerosmith", "pty")]


def wait_for(condition: Callable[[], bool], what: str, timeout_s: float = 20.0) -> float:
    """Poll ``condition`` until true; the seconds it took. Fails naming ``what`` after ``timeout_s``."""
    began = time.monotonic()
    while not condition():
        if time.monotonic() - began > timeout_s:
            pytest.fail(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.002)
    return time.monotonic() - began


def url_of(scheme: str, server: ByteServer, options: str = "") -> str:
    return f"{scheme}://{server.address}{options}"


Served = tuple[TableEmulator, ByteServer, Table]


@pytest.fixture(params=SERVED, ids=[f"{s}-{t}" for s, t in SERVED])
def served(request: pytest.FixtureRequest) -> Iterator[Served]:
    scheme, transport = request.param
    emulator = EMULATORS[scheme]()
    server = emulator.serve(transport)
    table = open_instrument(url_of(scheme, server), kind="table")
    assert isinstance(table, Table)
    try:
        yield emulator, server, table
    finally:
        table.close()
        server.stop()


def test_position_and_move_to(served: Served) -> None:
    emulator, _, table = served
    assert table.position_deg() == pytest.approx(0.0)
    table.set_acceleration(400.0)
    table.move_to(45.0)
    wait_for(lambda: abs(table.position_deg() - 45.0) < 1e-3, "the table at 45 deg")
    wait_for(lambda: emulator.rate_dps() == 0.0, "the table at rest")
    table.home()
    wait_for(lambda: abs(table.position_deg()) < 1e-3, "the table home")


def test_turn_at_a_rate_and_read_it_back(served: Served) -> None:
    emulator, _, table = served
    table.set_acceleration(400.0)
    table.turn(-30.0)
    if table.speaker.has("rate"):
        wait_for(lambda: table.rate_dps() == pytest.approx(-30.0), "the rate read back at -30 deg/s")
    else:  # the Aerosmith answers no rate query: its position runs backwards at the rate
        wait_for(lambda: emulator.rate_dps() == pytest.approx(-30.0), "the table at -30 deg/s")
        first = table.position_deg()
        wait_for(lambda: table.position_deg() < first - 0.1, "the position running backwards")
    table.stop()
    wait_for(lambda: emulator.rate_dps() == 0.0, "the table at rest after stop")


def test_acceleration_limit_is_respected(served: Served) -> None:
    emulator, _, table = served
    table.set_acceleration(200.0)
    began = time.monotonic()
    table.turn(100.0)
    peak = 0.0
    while abs(emulator.rate_dps() - 100.0) > 1e-9:
        peak = max(peak, abs(emulator.accel_dps2()))
        assert time.monotonic() - began < 20.0, "the table never reached 100 deg/s"
    # 100 deg/s at 200 deg/s^2 takes 0.5 s on the emulator's clock: never less, however busy the CPU
    assert time.monotonic() - began >= 0.5 * 0.98
    assert peak <= 200.0 + 1e-9
    table.stop()
    wait_for(lambda: emulator.rate_dps() == 0.0, "the table at rest")


def test_stop_brings_a_turning_table_to_rest(served: Served, capsys: pytest.CaptureFixture[str]) -> None:
    emulator, _, table = served
    table.set_acceleration(500.0)
    table.turn(90.0)
    wait_for(lambda: emulator.rate_dps() == pytest.approx(90.0), "the table at 90 deg/s")
    began = time.monotonic()
    table.stop()  # what the runner's Ctrl-C handling calls
    elapsed = wait_for(lambda: emulator.rate_dps() == 0.0, "the table at rest after stop", 5.0)
    stopped = time.monotonic() - began
    with capsys.disabled():
        print(f"\n{table.url}: stop -> rate 0 in {stopped * 1000:.0f} ms (ramp 90/500 = 180 ms)")
    assert elapsed < 0.18 + 1.0


def test_mount_pose_refuses_other_steps_in_one_line(served: Served) -> None:
    emulator, _, table = served
    mounted = MountedTable(table, mount="+z")
    with pytest.raises(MountRefused) as refused:
        mounted.pose("+x")
    message = str(refused.value)
    assert "\n" not in message and "pose +x" in message and "+z" in message
    with pytest.raises(MountRefused, match="rotate \\+y 90"):
        mounted.rotate("+y", 90.0, 30.0)
    assert emulator.lines == []  # refused before anything was sent


# --- the unit on the table ----------------------------------------------------------------------


@pytest.fixture()
def unit() -> Iterator[PtyServer]:
    with PtyServer(SimDevice(seed=5, rate_hz=100, scenario=[Static("+z", 1.0)])) as server:
        yield server


def gyro_mean_dps(device, seconds: float) -> np.ndarray:  # noqa: ANN001 (drivers.interface.Device)
    device.read(0)
    batches = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        batches.append(device.read(0.05))
    samples = np.concatenate(batches)
    assert len(samples) > 5
    return np.degrees(samples["gyro"].astype(float).mean(axis=0))


@pytest.mark.parametrize(("scheme", "mount", "gyro_axis", "sign"),
                         [("acutrol", "+z", 2, 1.0), ("aerosmith", "-x", 0, -1.0)])
def test_a_turn_of_the_table_turns_the_unit(unit: PtyServer, scheme: str, mount: str, gyro_axis: int,
                                            sign: float) -> None:
    emulator = EMULATORS[scheme](device=unit.device, mount=mount)
    with ByteServer(emulator, "pty") as server:
        table = open_instrument(url_of(scheme, server), kind="table")
        assert isinstance(table, Table)
        device = open_device(unit.port_path)
        try:
            wait_for(lambda: abs(gyro_mean_dps(device, 0.2)).max() < 3.0, "the unit still on the table")
            table.set_acceleration(200.0)
            table.turn(60.0)
            wait_for(lambda: emulator.rate_dps() == pytest.approx(60.0), "the table at 60 deg/s")
            gyro = gyro_mean_dps(device, 0.5)
            # raw gyro: scale 1 +- 1 %, bias of a few deg/s at most
            assert gyro[gyro_axis] == pytest.approx(sign * 60.0, abs=3.0)
            assert abs(np.delete(gyro, gyro_axis)).max() < 3.0
            table.stop()
            wait_for(lambda: emulator.rate_dps() == 0.0, "the table at rest")
        finally:
            device.close()
            table.close()


def test_mounted_table_turns_the_unit_by_the_step_angle(unit: PtyServer) -> None:
    emulator = AcutrolEmulator(device=unit.device, mount="+z")
    with ByteServer(emulator, "tcp") as server:
        table = open_instrument(url_of("acutrol", server), kind="table")
        assert isinstance(table, Table)
        device = open_device(unit.port_path)
        try:
            mounted = MountedTable(table, mount="+z", accel_dps2=180.0)
            mounted.pose("+z")
            device.read(0)
            mounted.rotate("+z", -90.0, 45.0)
            batches = []
            worker = mounted._worker
            assert worker is not None
            while worker.is_alive():
                batches.append(device.read(0.05))
            batches.append(device.read(0.2))
            mounted.wait()
            samples = np.concatenate(batches)
            t = samples["t_us"] * 1e-6
            angle = np.degrees(np.sum(samples["gyro"][1:, 2].astype(float) * np.diff(t)))
            assert angle == pytest.approx(-90.0, rel=0.04)
            assert table.position_deg() == pytest.approx(-90.0, abs=0.05)
            peak = max(abs(line_rate) for line_rate in _demanded_rates(emulator))
            assert peak == pytest.approx(45.0)  # the step's rate, not the table's maximum
        finally:
            device.close()
            table.close()


def _demanded_rates(emulator: TableEmulator) -> list[float]:
    return [float(line.split(",")[1]) for line in emulator.lines if line.startswith(":D:R")]


def test_mounted_table_stop_ends_a_turn() -> None:
    emulator = AcutrolEmulator()
    with ByteServer(emulator, "tcp") as server:
        table = open_instrument(url_of("acutrol", server), kind="table")
        assert isinstance(table, Table)
        try:
            mounted = MountedTable(table, mount="+z", accel_dps2=300.0)
            mounted.rotate("+z", 3600.0, 120.0)
            wait_for(lambda: emulator.rate_dps() == pytest.approx(120.0), "the turn at 120 deg/s")
            mounted.stop()
            assert mounted.wait_stopped(5.0) < 5.0
            mounted.wait(5.0)
            assert emulator.rate_dps() == 0.0
        finally:
            table.close()


# --- faults -------------------------------------------------------------------------------------


def test_silent_table_times_out_after_retries_in_one_line(served: Served) -> None:
    _, server, table = served
    scheme = table.description.name
    table.close()  # a pty has one host at a time
    quick = open_instrument(url_of(scheme, server, "?timeout=0.1"), kind="table")
    try:
        server.silent = True
        with pytest.raises(InstrumentTimeout) as timed_out:
            quick.position_deg()
        message = str(timed_out.value)
        assert "\n" not in message and scheme in message and "tried 3 times" in message
        assert (":R:P 1" if scheme == "acutrol" else "PPO?") in message
    finally:
        quick.close()


def test_garbage_is_garbled(served: Served) -> None:
    emulator, server, table = served
    emulator.garble = True  # whole lines of noise
    with pytest.raises(InstrumentGarbled, match=table.description.name) as garbled:
        table.position_deg()
    assert "\n" not in str(garbled.value) and "tried 3 times" in str(garbled.value)
    emulator.garble = False
    server.garbage = True  # every byte scrambled, the line end too: no whole reply comes
    table.close()
    quick = open_instrument(url_of(table.description.name, server, "?timeout=0.1"), kind="table")
    try:
        with pytest.raises((InstrumentGarbled, InstrumentTimeout)):
            quick.position_deg()  # type: ignore[attr-defined]
    finally:
        quick.close()


def test_link_lost_mid_run(served: Served) -> None:
    _, server, table = served
    table.turn(10.0)
    assert isinstance(table.position_deg(), float)
    server.drop_link()
    with pytest.raises(InstrumentLost):
        for _ in range(3):  # a closed pty may take a write before the next read fails
            table.position_deg()


def test_nobody_listening() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(InstrumentError, match="acutrol"):
        open_instrument(f"acutrol://127.0.0.1:{port}", kind="table").position_deg()  # type: ignore[attr-defined]


def test_rate_beyond_the_plan_is_refused_before_anything_is_sent(served: Served) -> None:
    emulator, server, table = served
    capped = limited(table, Limits(max_rate_dps=100.0, max_accel_dps2=50.0))
    assert isinstance(capped, Table)
    received = server.received
    with pytest.raises(LimitRefused, match="max_rate_dps"):
        capped.turn(-150.0)
    with pytest.raises(LimitRefused, match="max_accel_dps2"):
        capped.set_acceleration(80.0)
    assert server.received == received and emulator.rate_dps() == 0.0


# --- the contract, on the emulators and on a real table -----------------------------------------


def _contract_targets(config: pytest.Config) -> list[str]:
    real = config.getoption("--table", default=None)
    return ["acutrol-tcp", "aerosmith-pty"] + ([str(real)] if real else [])


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "contract_target" in metafunc.fixturenames:
        metafunc.parametrize("contract_target", _contract_targets(metafunc.config))


@pytest.fixture()
def contract_table(contract_target: str) -> Iterator[Table]:
    if "://" in contract_target:  # a real table: it moves a few degrees, slowly
        table = open_instrument(contract_target, kind="table")
        assert isinstance(table, Table)
        try:
            yield table
        finally:
            table.stop()
            table.close()
        return
    scheme, transport = contract_target.split("-")
    with ByteServer(EMULATORS[scheme](), transport) as server:
        table = open_instrument(url_of(scheme, server), kind="table")
        assert isinstance(table, Table)
        try:
            yield table
        finally:
            table.close()


def _at_rest(table: Table) -> Callable[[], bool]:
    last = [table.position_deg()]

    def check() -> bool:
        time.sleep(0.05)  # a real table's position settles over its own servo period
        position = table.position_deg()
        steady = abs(position - last[0]) < 1e-3 and abs(table.rate_dps()) < 1e-3
        last[0] = position
        return steady
    return check


def test_contract(contract_table: Table) -> None:
    table = contract_table
    assert table.identify()
    assert table.axes >= 1
    start = table.position_deg()
    assert math.isfinite(start)
    table.set_acceleration(20.0)
    table.move_to(start + 5.0)
    wait_for(lambda: abs(table.position_deg() - (start + 5.0)) < 0.05, "the table 5 deg on", 30.0)
    table.turn(5.0)
    first = table.position_deg()
    wait_for(lambda: table.position_deg() > first + 0.5, "the table turning at 5 deg/s", 30.0)
    table.stop()
    wait_for(_at_rest(table), "the table at rest after stop", 30.0)
    table.move_to(start)
    wait_for(lambda: abs(table.position_deg() - start) < 0.05, "the table back where it started", 30.0)
