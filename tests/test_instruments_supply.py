"""Bench supplies (issue 26): the SCPI and Korad drivers against their emulators over a real pty or
loopback TCP, the simulated unit powered through them, turn-on repeatability recorded by
power-cycling the unit through a supply, the faults a supply driver must survive, and a contract
test that also runs on a real supply with ``pytest --supply URL``.

Waits are on conditions with timeouts (a read that waits for samples, a poll with a deadline), so the
suite passes on a loaded machine.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pytest
import yaml

from drivers import open_device
from drivers.instruments import Supply
from drivers.instruments.errors import (
    InstrumentError,
    InstrumentGarbled,
    InstrumentLost,
    InstrumentTimeout,
    LimitRefused,
)
from mocks.device import SimDevice
from mocks.instruments.korad import KoradSupply
from mocks.instruments.scpi_supply import ScpiSupply, SupplyOutputs
from mocks.instruments.serving import ByteServer
from mocks.pty_server import PtyServer
from mocks.truth import UnitTruth
from station import cli
from station.instruments.limits import Limits, limited
from station.instruments.open import open_instrument
from station.instruments.power_cycle import open_power_cycle

SEED = 26
EMULATORS = {"scpi": ScpiSupply, "korad": KoradSupply}
SERVED = [("scpi", "tcp"), ("scpi", "pty"), ("korad", "pty")]


@dataclass
class Bench:
    """A supply emulator served on a link, the unit it powers and its URL."""

    scheme: str
    emulator: ScpiSupply | KoradSupply
    outputs: SupplyOutputs
    server: ByteServer
    device: SimDevice | None

    def url(self, query: str = "") -> str:
        return f"{self.scheme}://{self.server.address}{query}"


@pytest.fixture
def bench_factory() -> Iterator[Callable[..., Bench]]:
    servers: list[ByteServer] = []

    def make(scheme: str, transport: str, device: SimDevice | None = None, channels: int = 1) -> Bench:
        outputs = SupplyOutputs(device, channels=channels)
        emulator = EMULATORS[scheme](outputs)
        server = ByteServer(emulator, transport).start()
        servers.append(server)
        return Bench(scheme, emulator, outputs, server, device)

    yield make
    for server in servers:
        server.stop()


def wait_for(condition: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    """Poll ``condition`` until true or ``timeout_s`` passes; its last value."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() >= deadline:
            return condition()
        time.sleep(0.01)
    return True


# ---- each driver against its emulator ---------------------------------------------------------------


@pytest.mark.parametrize(("scheme", "transport"), SERVED)
def test_driver_identifies_sets_switches_and_measures(bench_factory, scheme: str, transport: str) -> None:
    device = SimDevice(seed=SEED)
    bench = bench_factory(scheme, transport, device)
    supply = open_instrument(bench.url(), kind="supply")
    assert isinstance(supply, Supply)
    try:
        assert supply.identify() == bench.emulator.identity
        supply.set_voltage(5.0)
        supply.set_current(0.5)
        assert supply.output() is False and not device.powered
        supply.set_output(True)
        assert supply.output() is True and device.powered
        assert supply.voltage_v() == pytest.approx(5.0, abs=0.01)
        assert supply.current_a() == pytest.approx(0.12, abs=0.001)  # the unit's load at 5 V
        assert bench.outputs.channel(1).amps == pytest.approx(0.5)
        supply.set_output(False)
        assert supply.output() is False and not device.powered
        assert supply.voltage_v() == 0.0 and supply.current_a() == 0.0
    finally:
        supply.close()


def test_a_voltage_below_brown_out_leaves_the_unit_off_and_the_current_limit_sags_it(bench_factory) -> None:
    device = SimDevice(seed=SEED)
    bench = bench_factory("scpi", "tcp", device)
    supply = open_instrument(bench.url(), kind="supply")
    assert isinstance(supply, Supply)
    try:
        supply.set_voltage(2.0)
        supply.set_output(True)
        assert supply.current_a() < 0.01 and not device.powered
        supply.set_voltage(5.0)
        assert supply.output() and device.powered
        supply.set_current(0.06)  # constant current: 0.06 A drives the unit's 41.7 ohm at 2.5 V: browned out
        assert supply.voltage_v() == pytest.approx(2.5, abs=0.01) and not device.powered
    finally:
        supply.close()


def test_scpi_channels_and_error_queue(bench_factory) -> None:
    bench = bench_factory("scpi", "tcp", SimDevice(seed=SEED), channels=2)
    supply = open_instrument(bench.url("?channel=2"), kind="supply")
    assert isinstance(supply, Supply)
    try:
        supply.set_voltage(3.3)
        supply.set_output(True)
        assert supply.output() is True  # answered once the emulator has done what came before
        assert bench.outputs.channel(2).volts == pytest.approx(3.3) and bench.outputs.channel(2).on
        assert not bench.outputs.channel(1).on and not bench.device.powered  # the unit is on channel 1
        assert "INST:NSEL 2" in bench.emulator.commands
    finally:
        supply.close()
    emulator = ScpiSupply(SupplyOutputs())
    answer = emulator.feed(b"SYST:ERR?\nFOO 1\nINST:NSEL 3\nSYST:ERR?\nSYST:ERR?\nsyst:err?\n")
    assert answer.decode().splitlines() == ['0,"No error"', '-113,"Undefined header"',
                                            '-221,"Settings conflict"', '0,"No error"']
    assert emulator.feed(b"VOLTage 4.5;:OUTPut ON;MEASure:VOLTage?\n") == b"4.5000\n"


def test_korad_splits_commands_without_terminator_by_shape_and_gap() -> None:
    now = [0.0]
    korad = KoradSupply(SupplyOutputs(), clock=lambda: now[0])
    # Glued together, split anywhere: the shapes tell them apart.
    assert korad.feed(b"VSET1:05.00ISE") == b""
    assert korad.feed(b"T1:0.250OUT1STAT") == b""
    assert korad.feed(b"US?VOUT1?") == bytes([0x71]) + b"05.00"
    assert korad.commands == ["VSET1:05.00", "ISET1:0.250", "OUT1", "STATUS?", "VOUT1?"]
    # A short number is complete at the next command's first byte, or after the pause.
    korad.feed(b"VSET1:3")
    assert korad.outputs.channel(1).volts == 5.0
    now[0] += 1.0
    assert korad.feed(b"VSET1?") == b"03.00"
    # Line noise is dropped byte by byte until a command starts.
    assert korad.feed(b"\xff\x00zzIOUT1?") == b"0.000" and korad.dropped == 4
    # Half a command then a pause: dropped, as the real one forgets it.
    korad.feed(b"STAT")
    now[0] += 1.0
    assert korad.feed(b"*IDN?") == korad.identity.encode() and korad.dropped == 8
    assert korad.feed(b"OUT0STATUS?") == bytes([0x31])  # CV, beeper, unlocked, output off


# ---- the unit powered through the supply -------------------------------------------------------------


def test_the_unit_goes_silent_with_the_output_off_and_boots_anew_when_on(bench_factory) -> None:
    device = SimDevice(UnitTruth.random(SEED), seed=SEED, rate_hz=100)
    bench = bench_factory("scpi", "pty", device)
    supply = open_instrument(bench.url(), kind="supply")
    assert isinstance(supply, Supply)
    with PtyServer(device, speed=5.0) as server:
        unit = open_device(server.port_path)
        try:
            supply.set_voltage(5.0)
            supply.set_output(True)
            first = _samples(unit, 50)
            assert first["seq"][0] == 0 and len(first) >= 50
            biases = device.truth.gyro.bias.copy()
            supply.set_output(False)
            assert supply.output() is False  # answered after the emulator switched the unit off
            while len(unit.read(0.5)):  # what was already on the wire
                pass
            produced = server.stats.samples
            assert len(unit.read(1.0)) == 0  # silent: a second of waiting brings nothing
            assert server.stats.samples == produced
            supply.set_output(True)
            again = _samples(unit, 50)
            assert again["seq"][0] == 0 and again["t_us"][0] == 0
            assert np.all(np.diff(again["seq"].astype(np.int64)) == 1)
            assert not np.allclose(device.truth.gyro.bias, biases)
            np.testing.assert_array_equal(device.truth.gyro.bias,
                                          device.base_truth.turned_on(device.restarts, SEED).gyro.bias)
        finally:
            unit.close()
            supply.close()


def _samples(unit, n: int, timeout_s: float = 20.0) -> np.ndarray:
    got, count = [], 0
    deadline = time.monotonic() + timeout_s
    while count < n and time.monotonic() < deadline:
        batch = unit.read(0.2)
        if len(batch):
            got.append(batch)
            count += len(batch)
    assert got, f"no samples within {timeout_s} s"
    return np.concatenate(got)


@pytest.mark.parametrize(("scheme", "transport"), [("scpi", "tcp"), ("korad", "pty")])
def test_characterise_records_turn_ons_by_power_cycling_through_the_supply(
        bench_factory, tmp_path, capsys, scheme: str, transport: str) -> None:
    truth = UnitTruth.random(SEED)
    device = SimDevice(truth, seed=SEED, rate_hz=100)
    bench = bench_factory(scheme, transport, device)
    params = tmp_path / "unit.yaml"
    keep = tmp_path / "turn-ons"
    with PtyServer(device, speed=20.0) as server:
        code = cli.main(["characterise", "--port", server.port_path, "--turn-ons", "3", "--still", "2",
                         "--supply", bench.url(), "--supply-volts", "5", "--supply-amps", "0.5",
                         "--supply-off", "0.1", "--keep", str(keep), "-o", str(params)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert device.restarts == 3 and "RESTART" not in device.commands  # one boot, then two power cycles
    assert err.count("power-cycling the unit through its supply") == 2
    assert sorted(p.name for p in keep.iterdir()) == [f"turn-on-0{k}.csv" for k in (1, 2, 3)]
    assert yaml.safe_load(params.read_text())["characterisation"]["turn_ons"] == 3
    assert bench.outputs.channel(1).on and bench.outputs.channel(1).volts == 5.0


def test_characterise_refuses_a_voltage_beyond_the_limit_before_sending_anything(bench_factory,
                                                                                 capsys) -> None:
    bench = bench_factory("scpi", "tcp", SimDevice(seed=SEED))
    code = cli.main(["characterise", "--port", "/dev/null", "--turn-ons", "3", "--still", "1",
                     "--supply", bench.url(), "--supply-volts", "24", "--supply-max-v", "12"])
    err = capsys.readouterr().err
    assert code == LimitRefused.exit_code, err
    assert "--supply-volts 24: give a voltage within --supply-max-v, 0..12 (V)" in err
    assert bench.server.received == 0 and bench.emulator.commands == []


def test_supply_options_without_supply_are_refused(capsys) -> None:
    assert cli.main(["characterise", "--port", "/dev/null", "--turn-ons", "3", "--still", "1",
                     "--supply-volts", "5"]) == 4
    assert "--supply-volts and --supply-amps go with --supply URL" in capsys.readouterr().err


# ---- faults -------------------------------------------------------------------------------------------


def _one_line(exc: BaseException, *parts: str) -> None:
    text = str(exc)
    assert "\n" not in text
    for part in parts:
        assert part in text, text


@pytest.mark.parametrize(("scheme", "transport"), SERVED)
def test_a_silent_supply_times_out_after_the_retries_naming_instrument_and_command(bench_factory, scheme: str,
                                                                                  transport: str) -> None:
    bench = bench_factory(scheme, transport)
    url = bench.url("?timeout=0.2")
    supply = open_instrument(url, kind="supply")
    assert isinstance(supply, Supply)
    try:
        bench.server.silent = True
        with pytest.raises(InstrumentTimeout) as timed_out:
            supply.voltage_v()
        command = "MEAS:VOLT?" if scheme == "scpi" else "VOUT1?"
        _one_line(timed_out.value, url, command, "no reply", "tried 3 times")
        bench.server.silent = False
        assert supply.voltage_v() == 0.0  # the late replies were discarded, the next one is in step
    finally:
        supply.close()


@pytest.mark.parametrize(("scheme", "transport"), SERVED)
def test_garbage_is_an_error_naming_instrument_and_command(bench_factory, scheme: str,
                                                           transport: str) -> None:
    bench = bench_factory(scheme, transport)
    url = bench.url("?timeout=0.2")
    supply = open_instrument(url, kind="supply")
    assert isinstance(supply, Supply)
    try:
        bench.server.garbage = True
        with pytest.raises((InstrumentGarbled, InstrumentTimeout)) as garbled:
            supply.voltage_v()
        _one_line(garbled.value, url, "MEAS:VOLT?" if scheme == "scpi" else "VOUT1?")
    finally:
        supply.close()


@pytest.mark.parametrize(("scheme", "transport"), SERVED)
def test_a_lost_link_is_instrument_lost(bench_factory, scheme: str, transport: str) -> None:
    bench = bench_factory(scheme, transport)
    url = bench.url("?timeout=0.3")
    supply = open_instrument(url, kind="supply")
    assert isinstance(supply, Supply)
    try:
        assert supply.identify()
        bench.server.drop_link()
        with pytest.raises(InstrumentError) as lost:
            for _ in range(3):  # TCP may take one send to notice the peer went away
                supply.voltage_v()
        assert isinstance(lost.value, (InstrumentLost, InstrumentTimeout))
        _one_line(lost.value, url)
    finally:
        supply.close()


def test_nobody_listening_is_instrument_lost() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # free, and nobody listens once it is closed
    with pytest.raises(InstrumentLost) as lost:
        open_instrument(f"scpi://127.0.0.1:{port}", kind="supply")
    _one_line(lost.value, f"127.0.0.1:{port}", "cannot connect")


@pytest.mark.parametrize(("scheme", "transport"), SERVED)
def test_a_voltage_beyond_the_limit_is_refused_before_anything_is_sent(bench_factory, scheme: str,
                                                                      transport: str) -> None:
    bench = bench_factory(scheme, transport, SimDevice(seed=SEED))
    supply = limited(open_instrument(bench.url(), kind="supply"), Limits(max_v=12.0, max_a=1.0))
    assert isinstance(supply, Supply)
    try:
        refused = r"voltage \(V\) 24 is beyond supply.max_v = 12 of the plan; nothing was sent"
        with pytest.raises(LimitRefused, match=refused):
            supply.set_voltage(24.0)
        with pytest.raises(LimitRefused):
            supply.set_current(2.0)
        assert bench.server.received == 0 and bench.emulator.commands == []
    finally:
        supply.close()
    cycle = open_power_cycle(bench.url(), Limits(max_v=12.0), volts=13.0)
    try:
        with pytest.raises(LimitRefused):
            cycle.power_on()
        assert bench.server.received == 0
    finally:
        cycle.close()


# ---- the contract: every supply, emulated or real ----------------------------------------------------


def _contract_targets() -> list[str]:
    return ["scpi-tcp", "scpi-pty", "korad-pty", "real"]


@pytest.fixture(params=_contract_targets())
def contract_supply(request, bench_factory) -> Iterator[Supply]:
    if request.param == "real":
        url = request.config.getoption("--supply")
        if not url:
            pytest.skip("no real supply: give pytest --supply URL")
    else:
        scheme, transport = request.param.split("-")
        url = bench_factory(scheme, transport).url()
    # A real supply's load is unknown: the contract stays at 1 V and 50 mA and leaves the output off.
    limits = Limits(max_v=1.0, max_a=0.05, source="the contract")
    supply = limited(open_instrument(url, kind="supply"), limits)
    assert isinstance(supply, Supply)
    yield supply
    try:
        supply.set_output(False)
    finally:
        supply.close()


def test_supply_contract(contract_supply: Supply) -> None:
    supply = contract_supply
    assert supply.identify()
    supply.set_output(False)
    assert supply.output() in (False, None)
    supply.set_voltage(1.0)
    supply.set_current(0.05)
    supply.set_output(True)
    assert supply.output() in (True, None)
    assert wait_for(lambda: abs(supply.voltage_v() - 1.0) < 0.1, 5.0)
    assert 0.0 <= supply.current_a() <= 0.06
    supply.set_output(False)
    assert supply.output() in (False, None)
    assert wait_for(lambda: supply.voltage_v() < 0.5, 5.0)
    with pytest.raises(LimitRefused):
        supply.set_voltage(1.5)
