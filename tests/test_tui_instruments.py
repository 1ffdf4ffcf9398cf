"""The TUI with lab instruments by URL (issue 26): ``tui --supply URL`` power-cycles the unit through a
bench supply on the turn-on screen, no prompt; ``tui --table URL`` has a three-axis rate table place and
turn the unit for every wizard step, no key beyond starting.

The simulated unit is served on a pty here (as ``imu-station simulate --instruments`` serves it) and
given to the TUI as ``--port``; the SCPI supply and ACUTROL emulators, over loopback TCP, are wired to
that unit: the supply's output powers it, the table's axes carry it. Every wait is on a condition with
a timeout (tests/tui_helpers.py), so the suite holds with both cores busy.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
from tui_helpers import shown, wait_for

from mocks.device import SimDevice
from mocks.instruments.acutrol import AcutrolEmulator
from mocks.instruments.scpi_supply import ScpiSupply, SupplyOutputs
from mocks.instruments.serving import ByteServer
from mocks.pty_server import PtyServer
from mocks.rig import Static
from station.acquisition.sequences import builtin
from station.export.params.file import ParamsFile
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.screens.ask import AskScreen
from station.tui.screens.results import ResultsScreen
from station.tui.screens.turn_ons import TurnOnsScreen
from station.tui.screens.wizard import WizardScreen

pytestmark = pytest.mark.timeout(240)
SEED = 4


@contextmanager
def unit_on_supply(speed: float) -> Iterator[tuple[SimDevice, ByteServer]]:
    """The simulated unit on a pty, powered from a SCPI supply served over TCP (its output starts off)."""
    unit = SimDevice(seed=SEED, rate_hz=100.0, scenario="still")
    with PtyServer(unit, block_s=0.05, speed=speed) as served:
        supply = ScpiSupply(SupplyOutputs(device=served.device))
        with ByteServer(supply, "tcp") as server:
            yield served, server  # type: ignore[misc]


def _turn_ons(tmp_path, monkeypatch, drop_supply: bool = False) -> dict[str, Any]:
    out = tmp_path / "unit.yaml"
    seen: dict[str, Any] = {"progress": [], "asked": 0}
    original = TurnOnsScreen.show_progress

    def recorded(self: TurnOnsScreen, d: dict[str, Any]) -> None:
        seen["progress"].append(dict(d))
        original(self, d)

    monkeypatch.setattr(TurnOnsScreen, "show_progress", recorded)
    with unit_on_supply(speed=20.0) as (served, server):
        unit = served.device
        assert not unit.powered  # the supply starts with its output off: the TUI switches it on
        config = TuiConfig(port=served.port_path, out=out, supply=f"scpi://{server.address}",
                           supply_volts=5.0, supply_amps=0.5, supply_off_s=0.3)
        app = StationApp(config)

        async def run() -> None:
            async with app.run_test(size=(130, 44)) as pilot:
                await wait_for(pilot, lambda: app.session is not None, 30, "the unit powered and connected")
                seen["powered"] = unit.powered
                if drop_supply:
                    server.stop()  # the supply's link goes away before the first power cycle
                await pilot.press("o")
                screen = await wait_for(pilot, lambda: next((s for s in app.screen_stack
                                                             if isinstance(s, TurnOnsScreen)), None), 5,
                                        "the turn-on screen")
                if drop_supply:
                    seen["text"] = await wait_for(pilot, lambda: shown(app, "the supply failed", " "), 60,
                                                  "the supply's failure on the screen")
                    seen["records"] = len(screen.records)
                    seen["asked"] += isinstance(app.screen, AskScreen)
                    await pilot.press("q")
                    return
                while not out.exists():
                    seen["asked"] += isinstance(app.screen, AskScreen)
                    await pilot.pause(0.1)
                seen["text"] = await wait_for(pilot, lambda: shown(app, "section saved", " "), 10,
                                              "the section saved")
                seen["cycles"] = app.session.power.cycles
                await pilot.press("q")

        asyncio.run(run())
        seen["unit"] = unit
        seen["out"] = out
    return seen


def test_turn_ons_power_cycle_the_unit_through_the_supply_without_a_prompt(tmp_path, monkeypatch):
    seen = _turn_ons(tmp_path, monkeypatch)
    unit = seen["unit"]
    assert seen["powered"] and seen["asked"] == 0
    # switched on when connecting (its first boot), then four power cycles through the supply
    assert seen["cycles"] == 4 and unit.restarts == 5
    doing = [d["doing"] for d in seen["progress"] if "supply" in d]
    assert sum("output off" in line for line in doing) == 4
    assert sum("output on (5.00 V" in line for line in doing) == 4
    section = ParamsFile.load(seen["out"]).other["characterisation"]
    assert section["turn_ons"] == 5
    drawn = np.array([unit.base_truth.turned_on(k, SEED).gyro.bias for k in range(1, 6)]).std(axis=0, ddof=1)
    np.testing.assert_allclose(section["gyro_bias_repeatability"], drawn, rtol=0.25, atol=2e-4)
    assert "gyro turn-on bias repeatability" in seen["text"]


def test_a_supply_that_fails_is_shown_on_the_turn_on_screen(tmp_path, monkeypatch):
    seen = _turn_ons(tmp_path, monkeypatch, drop_supply=True)
    assert seen["asked"] == 0 and seen["records"] == 1
    assert "the supply failed at turn-on 2" in seen["text"] and "Traceback" not in seen["text"]
    assert "Enter: compute from them" in seen["text"]


@pytest.mark.parametrize("url", ["nope://10.0.0.1", "scpi://127.0.0.1:1?timeout=0.2"])
def test_a_supply_that_cannot_be_opened_is_the_connect_screens_error(tmp_path, url):
    with unit_on_supply(speed=1.0) as (served, _server):
        app = StationApp(TuiConfig(port=served.port_path, supply=url))

        async def run() -> str:
            async with app.run_test(size=(130, 44)) as pilot:
                text = await wait_for(pilot, lambda: shown(app, "Choose a port and press Enter", " "), 30,
                                      "the connect screen's error")
                assert app.session is None
                await pilot.press("q")
                return text

        text = asyncio.run(run())
    assert url.split("?")[0] in text and "Traceback" not in text


@contextmanager
def unit_on_table(speed: float) -> Iterator[tuple[Any, AcutrolEmulator, ByteServer]]:
    """The simulated unit on a pty, carried by a three-axis ACUTROL emulator served over TCP."""
    unit = SimDevice(seed=SEED, rate_hz=100.0, scenario=[Static("+z", 1.0)])
    with PtyServer(unit, block_s=0.05, speed=speed) as served:
        emulator = AcutrolEmulator(axes=3, device=served.device, mount="+z")
        with ByteServer(emulator, "tcp") as server:
            yield served, emulator, server


def _table_config(served: Any, server: ByteServer, **kw: Any) -> TuiConfig:
    return TuiConfig(port=served.port_path, table=f"acutrol://{server.address}?axes=3", table_mount="+z",
                     table_accel_dps2=200.0, rotation_rate_dps=90.0, **kw)


async def _start_wizard(pilot, app: StationApp) -> WizardScreen:
    await wait_for(pilot, lambda: app.session is not None, 30, "the unit and the table to connect")
    app.show("wizard")
    wizard = await wait_for(pilot, lambda: isinstance(app.screen, WizardScreen) and app.screen, 5, "wizard")
    await wait_for(pilot, lambda: wizard.prompt is not None, 10, "the start prompt")
    await pilot.press("enter")  # start: the only key of the run
    return wizard


def test_the_table_places_and_turns_the_unit_for_every_wizard_step(tmp_path):
    out = tmp_path / "unit.yaml"
    with unit_on_table(speed=4.0) as (served, emulator, server):
        truth = served.device.truth
        app = StationApp(_table_config(served, server, out=out, hold_s=1.0))
        seen: dict[str, Any] = {"prompts": 0}

        async def run() -> None:
            async with app.run_test(size=(120, 44)) as pilot:
                wizard = await _start_wizard(pilot, app)
                moving = "the table is moving the unit"
                seen["moving"] = await wait_for(pilot, lambda: shown(app, moving, " "), 30,
                                                "the screen saying the table moves")
                while wizard.result is None:
                    seen["prompts"] += wizard.prompt is not None
                    await pilot.pause(0.2)
                await pilot.press("enter")  # -> results (the run is over: reading them is not a step)
                results = await wait_for(pilot, lambda: isinstance(app.screen, ResultsScreen) and app.screen,
                                         5, "results")
                await wait_for(pilot, lambda: results.report is not None, 60, "the calibration")
                await pilot.press("enter")  # save
                await wait_for(pilot, lambda: results.saved, 10, "the parameter file to be saved")
                await pilot.press("q")

        asyncio.run(run())
    run_result = app.last_run
    assert run_result is not None and run_result.outcome == "completed", run_result and run_result.reason
    assert seen["prompts"] == 0, "a prompt during the run: the table should have placed the unit"
    sequence = builtin("six-position")
    assert [(s.label, s.status) for s in run_result.steps] == [(lab, "accepted") for lab in sequence.labels]
    # the table did it: tilts on the middle and inner axes, every turn on the outer one at the step's rate
    assert any(line.startswith(":D:P 2,") for line in emulator.lines)
    outer_rates = [float(line.split(",")[1]) for line in emulator.lines if line.startswith(":D:R 1,")]
    assert sorted({abs(r) for r in outer_rates if r}) == [90.0]

    params = ParamsFile.load(out)
    # Raw = M true + b (+ the thermal constant at 25 degC); the tolerances of tests/test_tui_flow.py.
    acc_bias = truth.accel.bias + truth.accel.thermal.coeffs[:, 6]
    gyro_bias = truth.gyro.bias + truth.gyro.thermal.coeffs[:, 6]
    assert np.abs(params.accel.matrix - truth.accel.matrix).max() < 3e-3
    assert np.abs(params.accel.bias - acc_bias).max() < 2e-2
    assert np.abs(params.gyro.matrix - truth.gyro.matrix).max() < 5e-3
    assert np.abs(params.gyro.bias - gyro_bias).max() < 2e-3


def test_escape_stops_the_table_and_aborts_the_run(tmp_path):
    with unit_on_table(speed=4.0) as (served, emulator, server):
        app = StationApp(_table_config(served, server, hold_s=30.0))

        async def run() -> str:
            async with app.run_test(size=(120, 44)) as pilot:
                wizard = await _start_wizard(pilot, app)
                # the first rotation's turn is far off (30 s holds); stop during the second step's tilt
                await wait_for(pilot, lambda: wizard.current >= 1, 60, "the second step")
                await pilot.press("escape")
                await wait_for(pilot, lambda: wizard.result is not None, 60, "the run to end")
                text = await wait_for(pilot, lambda: shown(app, "aborted", " "), 10,
                                      "the abort on the screen")
                await wait_for(pilot, lambda: all(abs(emulator.rate_dps(a)) < 1e-6 for a in (1, 2, 3)), 30,
                               "every axis of the table at rest")
                await pilot.press("q")
                return text

        text = asyncio.run(run())
        # the stop of every axis (a pose stops the outer axis only; nothing else stops the middle one)
        assert ":D:R 2,0" in emulator.lines and ":D:R 3,0" in emulator.lines
    assert app.last_run is not None and app.last_run.outcome == "aborted"
    assert "Traceback" not in text
