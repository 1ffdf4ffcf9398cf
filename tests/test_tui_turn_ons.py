"""The TUI's turn-on repeatability screen on the simulated unit over its pty: restarts through RESTART,
and the power-cycle prompt for a unit that cannot restart itself."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from tui_helpers import shown, svg_rows, wait_for

from protocols import native
from station.export.params.file import ParamsFile
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.screens.ask import AskScreen
from station.tui.screens.turn_ons import TurnOnsScreen

pytestmark = pytest.mark.timeout(180)


def _run(tmp_path, restartable: bool) -> tuple[ParamsFile, dict]:
    out = tmp_path / "unit.yaml"
    app = StationApp(TuiConfig(simulate=True, seed=4, rate_hz=100.0, out=out, speed=20.0))
    seen: dict = {"prompts": 0}

    async def run() -> None:
        async with app.run_test(size=(130, 44)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            unit = app.session.rig
            unit.restartable = restartable
            seen["unit"] = unit
            await pilot.press("o")
            screen = await wait_for(pilot, lambda: next((s for s in app.screen_stack
                                                         if isinstance(s, TurnOnsScreen)), None), 5,
                                    "the turn-on screen")
            while not out.exists():
                # the prompt after turn-on k is answered once (pressing a key can outlast a record at x20)
                if isinstance(app.screen, AskScreen) and seen["prompts"] < len(screen.records):
                    seen["prompts"] += 1
                    seen["question"] = await wait_for(pilot, lambda: shown(app, "cannot restart itself", " "),
                                                      10, "the power-cycle prompt drawn")
                    unit.restartable = True  # the operator switches the unit off and on
                    unit.feed(native.encode_frame(native.RESTART))
                    unit.restartable = False
                    await pilot.press("c")
                await pilot.pause(0.1)
            await pilot.pause(0.3)
            seen["screen"] = " ".join(svg_rows(app.export_screenshot()))
            await pilot.press("q")

    asyncio.run(run())
    return ParamsFile.load(out), seen


def test_turn_ons_restart_the_unit_and_save_the_repeatability(tmp_path):
    params, seen = _run(tmp_path, restartable=True)
    unit = seen["unit"]
    assert unit.restarts == 4 and seen["prompts"] == 0
    section = params.other["characterisation"]
    assert section["turn_ons"] == 5
    drawn = np.array([unit.base_truth.turned_on(k, 4).gyro.bias for k in range(5)]).std(axis=0, ddof=1)
    np.testing.assert_allclose(section["gyro_bias_repeatability"], drawn, rtol=0.25, atol=2e-4)
    assert "characterisation section saved" in seen["screen"]
    assert "gyro turn-on bias repeatability" in seen["screen"]


def test_a_unit_that_cannot_restart_prompts_for_a_power_cycle(tmp_path):
    params, seen = _run(tmp_path, restartable=False)
    assert seen["prompts"] == 4 and seen["unit"].restarts == 4
    assert "cannot restart itself" in seen["question"] and "Switch it off" in seen["question"]
    assert params.other["characterisation"]["turn_ons"] == 5
