"""The simulated bench (``mocks.instruments.bench``) as an operator and the factory meet it:
``imu-station simulate --instruments`` in a subprocess prints the instruments' URLs, and
``imu-station instrument URL`` (in this process, through the real drivers over loopback TCP) reads and
sets them: a chamber setpoint warms the unit (on its device clock, so at --speed), a table's turn is
the unit's, the supply's output off silences the unit and on boots it anew. ``simulated_rig(...,
instruments=...)`` serves the same bench and registers ``sim://KIND`` for its block.

Every wait is on a condition with a deadline (a read that waits for samples, a line from the
subprocess), so the suite passes on a loaded machine.
"""

from __future__ import annotations

import json
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drivers import Device, open_device
from drivers.instruments.errors import InstrumentError
from mocks.device import SimDevice
from mocks.instruments.bench import KINDS, parse_kinds, simulated_bench
from mocks.pty_server import PtyServer
from station import cli
from station.errors import StationError
from station.factory.simrig import SimulatedUnit, simulated_rig
from station.instruments.open import open_instrument

ROOT = Path(__file__).resolve().parent.parent
SPEED = 100.0  # device seconds per wall second: the chamber's minutes pass in seconds
RATE_HZ = 20  # 2000 samples per wall second at SPEED
START_S = 60.0  # wall seconds for a Python with numpy to start on a busy machine


@dataclass
class Served:
    """``imu-station simulate --instruments`` running in a subprocess: its port, URLs and output."""

    proc: subprocess.Popen[str]
    lines: queue.Queue[str | None]
    port: str
    urls: dict[str, str]
    shown: list[str]

    def rest(self, timeout_s: float = 30.0) -> list[str]:
        """Every line it prints until it exits."""
        out = []
        deadline = time.monotonic() + timeout_s
        while True:
            line = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            if line is None:
                return out
            out.append(line)


def _pump(stream: Any, lines: queue.Queue[str | None]) -> None:
    for line in stream:
        lines.put(line.rstrip("\n"))
    lines.put(None)


@pytest.fixture
def simulate() -> Iterator[Callable[..., Served]]:
    started: list[subprocess.Popen[str]] = []

    def start(*extra: str, duration: float = 300.0) -> Served:
        proc = subprocess.Popen([sys.executable, "-m", "station", "simulate", "--seed", "5",
                                 "--rate", str(RATE_HZ), "--speed", f"{SPEED:g}",
                                 "--duration", f"{duration:g}", *extra],
                                cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        started.append(proc)
        lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True).start()
        shown: list[str] = []
        deadline = time.monotonic() + START_S
        while not shown or not shown[-1].startswith("press Ctrl-C"):
            try:
                line = lines.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"no 'press Ctrl-C' within {START_S} s: {shown}") from None
            assert line is not None, f"simulate ended: {shown} {proc.stderr.read() if proc.stderr else ''}"
            shown.append(line)
        fields = dict(line.split(": ", 1) for line in shown if ": " in line)
        urls = {kind: fields[kind] for kind in KINDS if kind in fields}
        return Served(proc, lines, fields["port"], urls, shown)

    yield start
    for proc in started:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=30)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def _stop(served: Served) -> list[str]:
    """SIGTERM, as Ctrl-C from a service manager: a clean exit 0 and the summary."""
    served.proc.send_signal(signal.SIGTERM)
    rest = served.rest()
    assert served.proc.wait(timeout=30) == 0
    return rest


def _instrument(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    """``imu-station instrument ARGV --json`` in this process: its state."""
    capsys.readouterr()
    code = cli.main(["instrument", *argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def _samples(unit: Device, n: int = 1, timeout_s: float = 30.0) -> np.ndarray:
    """At least ``n`` samples from the unit, waiting at most ``timeout_s``."""
    got, count = [], 0
    deadline = time.monotonic() + timeout_s
    while count < n and time.monotonic() < deadline:
        batch = unit.read(0.2)
        if len(batch):
            got.append(batch)
            count += len(batch)
    assert count >= n, f"{count} samples within {timeout_s} s, not {n}"
    return np.concatenate(got)


def _until(unit: Device, condition: Callable[[np.ndarray], bool], what: str,
           timeout_s: float = 60.0) -> np.ndarray:
    """Read the unit until a batch satisfies ``condition``; that batch."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        batch = unit.read(0.2)
        if len(batch) and condition(batch):
            return batch
    raise AssertionError(f"{what}: not within {timeout_s} s")


# --- imu-station simulate --instruments, another process -------------------------------------------

def test_simulate_prints_the_urls_and_each_instrument_answers(simulate, capsys) -> None:
    served = simulate("--instruments")
    assert list(served.urls) == list(KINDS)
    assert served.urls["chamber"].startswith("votsch://127.0.0.1:")
    assert served.urls["table"].startswith("acutrol://127.0.0.1:")
    assert served.urls["supply"].startswith("scpi://127.0.0.1:")
    assert any("sim://KIND names them only inside one process" in line for line in served.shown)
    chamber = _instrument(capsys, served.urls["chamber"])
    assert chamber["kind"] == "chamber" and chamber["temperature_c"] == pytest.approx(23.0, abs=0.5)
    table = _instrument(capsys, served.urls["table"])
    assert table["kind"] == "table" and table["rate_dps"] == 0.0
    supply = _instrument(capsys, served.urls["supply"])
    assert supply["kind"] == "supply" and supply["output"] is True
    assert supply["voltage_v"] == pytest.approx(5.0) and supply["current_a"] == pytest.approx(0.12, abs=0.001)
    rest = _stop(served)
    assert any(line.startswith("ran ") for line in rest)
    assert re.fullmatch(r"instruments: chamber [1-9]\d* request\(s\), table [1-9]\d* command\(s\), "
                        r"supply [1-9]\d* command\(s\)", rest[-1]), rest[-1]


def test_duration_ends_it_with_the_instruments_asked_for(simulate) -> None:
    served = simulate("--instruments", "supply,chamber", duration=1.0)
    assert list(served.urls) == ["chamber", "supply"]
    rest = served.rest()
    assert served.proc.wait(timeout=30) == 0
    assert rest[-1] == "instruments: chamber 0 request(s), supply 0 command(s)"


def test_a_chamber_setpoint_warms_the_unit_on_its_device_clock(simulate, capsys) -> None:
    served = simulate("--instruments", "chamber")
    unit = open_device(served.port)
    try:
        before = _samples(unit, 10)
        assert float(np.median(before["temp"][-10:])) < 24.0
        set_at = _samples(unit)[-1]["t_us"]
        state = _instrument(capsys, served.urls["chamber"], "--setpoint", "40", "--gradient", "20", "--start")
        assert state["setpoint_c"] == pytest.approx(40.0)
        warm = _until(unit, lambda b: float(b["temp"][-1]) > 30.0, "the unit warming past 30 degC")
        # The unit lags the air by minutes of device clock; at x100 they pass in seconds of wall clock.
        assert (int(warm["t_us"][-1]) - int(set_at)) / 1e6 > 60.0
        assert _instrument(capsys, served.urls["chamber"])["temperature_c"] > 30.0
    finally:
        unit.close()
    _stop(served)


def test_the_supply_silences_the_unit_and_boots_it_anew(simulate, capsys) -> None:
    served = simulate("--instruments", "supply")
    unit = open_device(served.port)
    try:
        first = _samples(unit, 10)
        assert int(first["seq"][-1]) > 0
        assert _instrument(capsys, served.urls["supply"], "--output", "off")["output"] is False
        while len(unit.read(0.5)):  # what was already on the wire
            pass
        assert len(unit.read(1.0)) == 0  # silent: a second of waiting brings nothing
        assert _instrument(capsys, served.urls["supply"], "--output", "on")["output"] is True
        again = _samples(unit, 10)
        assert again["seq"][0] == 0 and again["t_us"][0] == 0
        assert np.all(np.diff(again["seq"].astype(np.int64)) == 1)
    finally:
        unit.close()
    _stop(served)


def test_a_table_turn_is_the_units(simulate, capsys) -> None:
    served = simulate("--instruments", "table")
    unit = open_device(served.port)
    try:
        still = float(np.degrees(np.median(_samples(unit, 20)["gyro"][:, 2])))
        _instrument(capsys, served.urls["table"], "--rate", "30")
        turning = _until(unit, lambda b: abs(np.degrees(np.median(b["gyro"][:, 2])) - still - 30.0) < 2.0,
                         "the unit's z gyro seeing the table's 30 deg/s")
        assert len(turning)
        assert _instrument(capsys, served.urls["table"])["rate_dps"] == pytest.approx(30.0)
    finally:
        unit.close()
    _stop(served)


@pytest.mark.parametrize(("argv", "words"), [
    (["--instruments", "oven"], "--instruments 'oven': unknown instrument 'oven'"),
    (["--instruments", "--scenario", "chamber"], "--scenario chamber has its own programme"),
])
def test_what_cannot_be_served_is_refused(capsys, argv: list[str], words: str) -> None:
    assert cli.main(["simulate", "--duration", "1", *argv]) == 4
    assert words in capsys.readouterr().err


# --- the bench in this process ------------------------------------------------------------------

def test_the_bench_keeps_the_unit_running_and_its_chamber_on_the_device_clock() -> None:
    device = SimDevice(seed=2, rate_hz=RATE_HZ)
    with PtyServer(device, speed=SPEED) as server, simulated_bench(device, server.device_time_s) as bench:
        assert set(bench.urls) == set(KINDS) and set(bench.servers) == set(KINDS)
        # The supply's output is on and the unit was not booted by it: its scenario and seq go on.
        assert bench.outputs is not None and bench.outputs.channel(1).on
        assert bench.outputs.channel(1).volts == 5.0 and device.powered and device.restarts == 0
        assert bench.plant is not None
        assert abs(bench.plant.clock() - server.device_time_s()) < SPEED * 0.5
    for server in bench.servers.values():
        assert server.address and server._listener is None  # noqa: SLF001 - stopped, nothing listens


def test_the_unit_stays_in_the_chamber_air_through_power_cycles() -> None:
    # A clock the test moves: the unit produces up to it, the plant runs on it.
    now = [0.0]
    device = SimDevice(seed=2, rate_hz=10, temp_noise_degc=0.0)
    with simulated_bench(device, lambda: now[0], ["chamber", "supply"]) as bench:
        assert bench.plant is not None and bench.outputs is not None
        bench.plant.set_gradient(20.0)
        bench.plant.set_setpoint(40.0)
        bench.plant.set_running(True)
        for cycle in range(1, 4):
            now[0] = 300.0 * cycle
            device.produce(now[0])
            bench.outputs.set(1, on=False)
            bench.outputs.set(1, on=True)  # a boot: the unit's clock from 0
            assert device.restarts == cycle
            now[0] += 60.0
            samples = device.produce(now[0])
            assert samples["t_us"][0] == 0
            # The unit reads the plant at the right time after every boot, not ahead of it.
            assert float(samples["temp"][-1]) == pytest.approx(float(bench.plant.unit_c(now[0])), abs=0.05)


def test_kinds_are_named_once_in_bench_order() -> None:
    assert parse_kinds("supply,chamber,supply") == ("chamber", "supply")
    assert parse_kinds("all") == KINDS
    assert parse_kinds(["table"]) == ("table",)
    with pytest.raises(ValueError, match="unknown instrument 'oven'"):
        parse_kinds("oven")
    with pytest.raises(ValueError, match="name at least one"):
        parse_kinds(" , ")


# --- run --simulate: simulated_rig -----------------------------------------------------------------

def test_simulated_rig_registers_sim_urls_for_its_block() -> None:
    unit = SimulatedUnit(seed=4, speed=10.0)
    with simulated_rig(unit, "SIM-000004", 50.0, instruments=["supply", "chamber", "table"]) as ports:
        assert list(ports.instruments) == list(KINDS)
        for kind in KINDS:
            instrument = open_instrument(f"sim://{kind}", kind=kind)
            try:
                state = instrument.state()
                assert state["kind"] == kind and instrument.url == f"sim://{kind}"
            finally:
                instrument.close()
    for kind in KINDS:
        with pytest.raises(InstrumentError, match="no simulated"):
            open_instrument(f"sim://{kind}")


def test_simulated_rig_without_instruments_serves_none() -> None:
    with simulated_rig(SimulatedUnit(seed=4), "SIM-000004", 50.0) as ports:
        assert ports.instruments == {}
        with pytest.raises(InstrumentError):
            open_instrument("sim://chamber")
    with pytest.raises(StationError, match="unknown instrument 'oven'"):
        with simulated_rig(SimulatedUnit(seed=4), "SIM-000004", 50.0, instruments=["oven"]):
            pass
