"""The chamber drivers (``drivers.instruments`` from the shipped descriptions) against their emulators
(``mocks.instruments``) over real ptys and loopback sockets: simserv (TCP), ESPEC (pty), Watlow F4
(Modbus RTU, pty) and Binder MB1 (Modbus TCP), each coupled to a chamber plant running 600 times
faster than the wall clock.

The contract test runs on the four emulators, and on a real chamber when one is given
(``pytest --chamber votsch://10.0.0.5``), as python-can runs one suite on its virtual bus and on
hardware; on a real chamber it only reads, and sets the setpoint it already has. Every wait is on a
condition with a deadline, so the suite passes on a loaded machine.
"""

from __future__ import annotations

import math
import os
import socket
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from drivers.instruments import Chamber, Transcript
from drivers.instruments.errors import (
    InstrumentError,
    InstrumentGarbled,
    InstrumentLost,
    InstrumentTimeout,
    LimitRefused,
)
from mocks.device import SimDevice
from mocks.instruments.chamber_plant import ChamberPlant
from mocks.instruments.espec import EspecChamber
from mocks.instruments.modbus_chambers import binder_mb1, watlow_f4
from mocks.instruments.serving import ByteServer
from mocks.instruments.simserv import SimservChamber
from station.instruments.limits import Limits, limited
from station.instruments.open import open_instrument

SPEED = 600.0  # device seconds per wall second: the unit's lag of 3 min is 0.3 s
CHAMBERS = ("votsch", "espec", "watlow-f4", "binder")
ASCII_CHAMBERS = ("votsch", "espec")


@dataclass
class Served:
    """One emulated chamber: the URL to open, its plant, the server (faults, bytes received)."""

    scheme: str
    url: str
    plant: ChamberPlant
    server: Any  # ByteServer or ModbusChamber: silent, garbage, drop_link(), received

    def open(self, transcript: Transcript | None = None, timeout: float | None = None) -> Chamber:
        url = self.url + (f"?timeout={timeout}" if timeout is not None else "")
        chamber = open_instrument(url, transcript, kind="chamber")
        assert isinstance(chamber, Chamber)
        return chamber


@contextmanager
def serve(scheme: str) -> Iterator[Served]:
    """The emulator of ``scheme``, started, with a fresh plant; stopped on the way out."""
    plant = ChamberPlant(speed=SPEED)
    server: Any
    if scheme == "votsch":
        server = ByteServer(SimservChamber(plant), "tcp")
    elif scheme == "espec":
        server = ByteServer(EspecChamber(plant), "pty")
    elif scheme == "watlow-f4":
        server = watlow_f4(plant)
    else:
        server = binder_mb1(plant)
    with server:
        yield Served(scheme, f"{scheme}://{server.address}", plant, server)


def wait_for(condition: Callable[[], bool], what: str, timeout_s: float = 20.0) -> None:
    """Poll ``condition`` until it holds, or fail naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s} s")
        time.sleep(0.01)


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "contract_source" in metafunc.fixturenames:
        sources = list(CHAMBERS)
        real = metafunc.config.getoption("--chamber", default=None)
        if real:
            sources.append(real)
        metafunc.parametrize("contract_source", sources)


@pytest.fixture
def contract_chamber(contract_source: str) -> Iterator[tuple[Chamber, Served | None]]:
    if contract_source in CHAMBERS:
        with serve(contract_source) as served:
            chamber = served.open()
            try:
                yield chamber, served
            finally:
                chamber.close()
    else:
        chamber = open_instrument(contract_source, kind="chamber")
        assert isinstance(chamber, Chamber)
        try:
            yield chamber, None
        finally:
            chamber.close()


# --- the contract: what every chamber, emulated or real, must do ------------------------------------

def test_contract(contract_chamber: tuple[Chamber, Served | None]) -> None:
    chamber, served = contract_chamber
    assert chamber.identify()
    temperature = chamber.temperature_c()
    setpoint = chamber.setpoint_c()
    assert -90.0 < temperature < 200.0 and -90.0 < setpoint < 200.0
    # A real chamber is given the setpoint it has: the contract moves nothing.
    target = setpoint if served is None else 35.0
    chamber.set_setpoint(target)
    assert chamber.setpoint_c() == pytest.approx(target, abs=0.05)
    assert isinstance(chamber.alarms(), str)
    state = chamber.state()
    assert state["kind"] == "chamber" and math.isfinite(float(str(state["temperature_c"])))


# --- each driver against its emulator ------------------------------------------------------------

@pytest.mark.parametrize("scheme", CHAMBERS)
def test_set_setpoint_moves_the_plant_and_the_unit(scheme: str) -> None:
    with serve(scheme) as served:
        device = SimDevice(seed=3, rate_hz=50.0, temp_noise_degc=0.0)
        device.follow_temperature(served.plant)
        chamber = served.open()
        try:
            assert chamber.temperature_c() == pytest.approx(23.0, abs=0.5)
            if chamber.speaker.has("start"):
                chamber.start()
            chamber.set_setpoint(40.0)
            assert chamber.setpoint_c() == pytest.approx(40.0, abs=0.05)
            assert served.plant.setpoint_c == pytest.approx(40.0, abs=0.05)
            wait_for(lambda: chamber.temperature_c() > 39.0, f"{scheme}: the air reaching 40 degC")

            def unit_warm() -> bool:
                samples = device.produce(served.plant.clock())
                return len(samples) > 0 and float(samples["temp"][-1]) > 39.0

            wait_for(unit_warm, f"{scheme}: the simulated unit's temperature following the air")
        finally:
            chamber.close()


def test_simserv_gradient_limits_the_ramp() -> None:
    with serve("votsch") as served:
        chamber = served.open()
        try:
            chamber.set_gradient(2.0)
            assert served.plant.gradient_up == pytest.approx(2.0)
            assert served.plant.gradient_down == pytest.approx(2.0)
            assert float(chamber.speaker.do("gradient")["value"]) == pytest.approx(2.0)
            chamber.start()
            t0 = served.plant.clock()
            chamber.set_setpoint(80.0)
            wait_for(lambda: served.plant.clock() > t0 + 300.0, "five device minutes")
            air = served.plant.air_c(np.array([t0 + 10.0, t0 + 250.0]))
            slope_k_per_min = (air[1] - air[0]) / 240.0 * 60.0
            assert slope_k_per_min == pytest.approx(2.0, rel=0.05)
        finally:
            chamber.close()


@pytest.mark.parametrize("scheme", ASCII_CHAMBERS)
def test_start_and_stop(scheme: str) -> None:
    with serve(scheme) as served:
        chamber = served.open()
        try:
            chamber.start()
            assert served.plant.running
            if chamber.speaker.has("running"):
                assert chamber.speaker.do("running")["state"] == "1"
            chamber.stop()
            assert not served.plant.running
        finally:
            chamber.close()


def test_stopped_chamber_drifts_back_to_ambient() -> None:
    now = [0.0]
    plant = ChamberPlant(lambda: now[0])
    plant.set_setpoint(60.0)
    plant.set_running(True)
    now[0] = 3600.0
    plant.set_running(False)
    air = plant.air_c(np.array([3600.0, 3600.0 + 1800.0, 3600.0 + 5 * 1800.0]))
    assert air[0] == pytest.approx(60.0, abs=0.01)
    assert 23.0 < air[1] < 60.0 - 0.5 * (60.0 - 23.0)  # slow: about one time constant
    assert air[2] == pytest.approx(23.0, abs=0.5)
    unit = plant.unit_c(np.array([0.0, 60.0, 3600.0]))
    assert unit[0] == pytest.approx(23.0) and unit[1] < plant.air_c(60.0)
    assert unit[2] == pytest.approx(60.0, abs=0.01)


# --- faults ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("scheme", CHAMBERS)
def test_silent_instrument_times_out_after_retries(scheme: str) -> None:
    with serve(scheme) as served:
        transcript = Transcript()
        chamber = served.open(transcript, timeout=0.2)
        try:
            chamber.temperature_c()
            served.server.silent = True
            with pytest.raises(InstrumentTimeout) as caught:
                chamber.temperature_c()
            message = str(caught.value)
            assert "\n" not in message and served.url in message
            assert ("11004" in message or "TEMP?" in message or "read temperature" in message)
            if scheme in ASCII_CHAMBERS:
                assert "tried 3 times" in message
                assert [e.error for e in transcript.entries()[1:]] == ["InstrumentTimeout"] * 3
        finally:
            chamber.close()


class Garbling:
    """An emulator whose replies keep their terminator but not their sense (a wrong controller)."""

    def __init__(self, inner: Any, line: bytes):
        self.inner = inner
        self.line = line

    def feed(self, data: bytes) -> bytes:
        return self.line * self.inner.feed(data).count(b"\r\n")


@pytest.mark.parametrize(("scheme", "line"), [("votsch", b"1\xb6#?!\r\n"), ("espec", b"@@##\r\n")])
def test_garbage_is_garbled(scheme: str, line: bytes) -> None:
    with serve(scheme) as served:
        chamber = served.open(timeout=0.2)
        try:
            served.server.emulator = Garbling(served.server.emulator, line)
            with pytest.raises(InstrumentGarbled) as caught:
                chamber.temperature_c()
            message = str(caught.value)
            assert served.url in message and "\n" not in message and "tried 3 times" in message
        finally:
            chamber.close()


@pytest.mark.parametrize("scheme", ASCII_CHAMBERS)
def test_scrambled_bytes_are_an_error(scheme: str) -> None:
    # Every byte scrambled, the terminator too: no reply ever completes.
    with serve(scheme) as served:
        chamber = served.open(timeout=0.2)
        try:
            served.server.garbage = True
            with pytest.raises((InstrumentTimeout, InstrumentGarbled)) as caught:
                chamber.temperature_c()
            assert served.url in str(caught.value)
        finally:
            chamber.close()


@pytest.mark.parametrize("scheme", ("watlow-f4", "binder"))
def test_modbus_garbage_is_an_error(scheme: str) -> None:
    # pymodbus discards a frame whose CRC or header is wrong and waits for another: a scrambled
    # answer is, to the station, no answer.
    with serve(scheme) as served:
        chamber = served.open(timeout=0.2)
        try:
            served.server.garbage = True
            with pytest.raises(InstrumentError) as caught:
                chamber.temperature_c()
            assert served.url in str(caught.value)
        finally:
            chamber.close()


@pytest.mark.parametrize("scheme", CHAMBERS)
def test_link_lost_mid_run(scheme: str) -> None:
    with serve(scheme) as served:
        chamber = served.open(timeout=0.5)
        try:
            assert chamber.temperature_c() == pytest.approx(23.0, abs=0.5)
            served.server.drop_link()
            with pytest.raises(InstrumentLost) as caught:
                chamber.temperature_c()
            assert served.url in str(caught.value)
        finally:
            chamber.close()


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.mark.parametrize("scheme", CHAMBERS)
def test_nobody_listening_is_a_clear_error(scheme: str) -> None:
    # The free port is taken when the test runs: in the test's id it would differ between xdist workers.
    network = scheme in ("votsch", "binder")
    url = f"{scheme}://127.0.0.1:{_free_port()}" if network else f"{scheme}:///dev/pts/no-such-port"
    with pytest.raises(InstrumentLost) as caught:
        open_instrument(url)
    message = str(caught.value)
    assert url.split("://")[0] in message and "\n" not in message
    assert "check" in message


@pytest.mark.parametrize("scheme", CHAMBERS)
def test_setpoint_beyond_the_limits_is_refused_before_sending(scheme: str) -> None:
    with serve(scheme) as served:
        chamber = limited(served.open(), Limits(min_c=-40.0, max_c=85.0, source="plan.yaml"))
        assert isinstance(chamber, Chamber)
        try:
            before = served.server.received
            for celsius in (120.0, -60.0, float("nan")):
                with pytest.raises(LimitRefused) as caught:
                    chamber.set_setpoint(celsius)
                assert "nothing was sent" in str(caught.value) and "plan.yaml" in str(caught.value)
            assert served.server.received == before
            chamber.set_setpoint(50.0)
            wait_for(lambda: served.server.received > before, "the allowed setpoint reaching the emulator")
            assert served.plant.setpoint_c == pytest.approx(50.0)
        finally:
            chamber.close()


@pytest.mark.parametrize("scheme", CHAMBERS)
def test_transcript_records_every_exchange(scheme: str) -> None:
    with serve(scheme) as served:
        transcript = Transcript()
        chamber = served.open(transcript)
        started = time.time()
        try:
            chamber.temperature_c()
            chamber.set_setpoint(30.0)
            chamber.setpoint_c()
        finally:
            chamber.close()
        entries = transcript.entries()
        assert len(entries) == 3
        assert all(e.instrument == served.url and not e.error and e.reply for e in entries)
        assert all(started - 1.0 <= e.t <= time.time() and 0.0 <= e.duration_s < 5.0 for e in entries)
        assert [e.t for e in entries] == sorted(e.t for e in entries)
        assert any(("30.0" in e.command) or ("write" in e.command) for e in entries)


def test_emulators_refuse_what_their_controllers_refuse() -> None:
    plant = ChamberPlant(speed=SPEED)
    espec = EspecChamber(plant)
    assert espec.feed(b"TEMP,S200.0\r\n") == b"NA:DATA OUT OF RANGE\r\n"
    assert espec.feed(b"FROB\r\n") == b"NA:COMMAND ERR\r\n"
    assert espec.feed(b"TEMP,S25.0\r") == b""  # half a line: no answer yet
    assert espec.feed(b"\n") == b"OK:TEMP,S25.0\r\n"
    simserv = SimservChamber(plant)
    assert simserv.feed(b"11001\xb61\xb61\xb635.0\r") == b"1\r\n"
    assert simserv.feed(b"11004\xb61\xb61\r").startswith(b"1\xb6")
    assert simserv.feed(b"99999\xb61\r").startswith(b"-1\xb6")
    assert plant.setpoint_c == 35.0


@pytest.mark.skipif(not os.path.exists("/dev/ptmx"), reason="no pseudo-terminals")
def test_espec_refusal_is_instrument_refused() -> None:
    from drivers.instruments.errors import InstrumentRefused

    with serve("espec") as served:
        chamber = served.open()
        try:
            with pytest.raises(InstrumentRefused) as caught:
                chamber.set_setpoint(150.0)  # the controller's own alarm limit is 85
            assert "DATA OUT OF RANGE" in str(caught.value)
        finally:
            chamber.close()
