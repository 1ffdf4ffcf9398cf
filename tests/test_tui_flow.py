"""The whole TUI flow, headless (Pilot), against the simulated unit served on a pseudo-terminal.

Enter alone drives it: connect (automatic with --simulate), live view, wizard (start prompt, then
six poses and six rotations placed by the simulated operator), results, save. The parameter
file is read back and compared with the simulated unit's truth.
"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from tui_helpers import answer_every_prompt, wait_for

from station.acquisition.capture import read_capture
from station.acquisition.sequences import builtin
from station.export.params.file import ParamsFile
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.screens.results import ResultsScreen
from station.tui.screens.wizard import WizardScreen

pytestmark = pytest.mark.timeout(240)


async def _drive_with_enter(app: StationApp) -> None:
    async with app.run_test(size=(120, 44)) as pilot:
        await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit to connect")
        await pilot.press("enter")  # connect -> live view
        await wait_for(pilot, lambda: type(app.screen).__name__ == "LiveScreen", 5, "the live view")
        await pilot.pause(0.5)
        await pilot.press("enter")  # live view -> wizard
        wizard = await wait_for(pilot, lambda: isinstance(app.screen, WizardScreen) and app.screen, 5,
                                "wizard")
        await answer_every_prompt(pilot, wizard)
        await pilot.press("enter")  # -> results
        results = await wait_for(pilot, lambda: isinstance(app.screen, ResultsScreen) and app.screen, 5,
                                 "results")
        await wait_for(pilot, lambda: results.report is not None, 60, "the calibration")
        await pilot.press("enter")  # save
        await wait_for(pilot, lambda: results.saved, 10, "the parameter file to be saved")
        await pilot.press("enter")  # quit
        await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")


def test_enter_only_six_position_and_rotations_writes_the_units_parameters(tmp_path):
    out = tmp_path / "unit.yaml"
    config = TuiConfig(simulate=True, seed=4, out=out, hold_s=1.0, rotation_rate_dps=360.0, export=["json"],
                       speed=4.0)
    app = StationApp(config)
    truth_holder = {}

    async def run() -> None:
        task = asyncio.create_task(_drive_with_enter(app))
        while app.session is None and not task.done():
            await asyncio.sleep(0.05)
        if app.session is not None:
            truth_holder["truth"] = app.session.rig.truth
            truth_holder["info"] = dict(app.session.info)
        await task

    asyncio.run(run())
    assert app.return_value == 0
    assert app.last_run.outcome == "completed"
    truth = truth_holder["truth"]

    params = ParamsFile.load(out)
    assert params.device["serial"] == truth_holder["info"]["serial"]
    # Raw = M true + b (+ the thermal constant at 25 degC, a bias like any other here).
    acc_bias = truth.accel.bias + truth.accel.thermal.coeffs[:, 6]
    gyro_bias = truth.gyro.bias + truth.gyro.thermal.coeffs[:, 6]
    # Short holds (1 s at 200 Hz) of a noisy MEMS unit: a few 1e-3 on the matrix, ~1e-2 m/s^2 bias.
    assert np.abs(params.accel.matrix - truth.accel.matrix).max() < 3e-3
    assert np.abs(params.accel.bias - acc_bias).max() < 2e-2
    assert np.abs(params.gyro.matrix - truth.gyro.matrix).max() < 5e-3
    assert np.abs(params.gyro.bias - gyro_bias).max() < 2e-3
    # Within the engine's own stated uncertainty (5 sigma: short holds, bias instability).
    acc_sd = np.asarray(params.accel.stddev["bias"], float)
    assert np.all(np.abs(params.accel.bias - acc_bias) < 5 * acc_sd + 1e-3)

    capture = read_capture(tmp_path / "unit-capture.csv")
    assert [label for label, _ in capture.segments()] == builtin("six-position").labels
    assert (tmp_path / "imu_calib.json").exists()
    assert app.saved[0] == str(out)


def test_capture_loses_no_sample_at_1khz_while_the_ui_renders(tmp_path):
    seq = tmp_path / "two.yaml"
    seq.write_text("name: two\nhold_s: 1.5\nsteps: [+z, -z]\n")
    capture_path = tmp_path / "run.csv"
    config = TuiConfig(simulate=True, seed=2, rate_hz=1000.0, sequence=str(seq), capture=capture_path)
    app = StationApp(config)

    async def run() -> None:
        async with app.run_test(size=(120, 44)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.press("enter")
            await pilot.pause(1.0)  # the live view renders sparklines of 1 kHz data
            await pilot.press("enter")
            wizard = await wait_for(pilot, lambda: isinstance(app.screen, WizardScreen) and app.screen, 5,
                                    "wizard")
            await wait_for(pilot, lambda: wizard.prompt is not None, 10, "the start prompt")
            await pilot.press("enter")
            await wait_for(pilot, lambda: wizard.result is not None, 60, "the end of the run")
            stats = app.session.device.stats
            assert stats.lost == 0 and stats.overflow_drops == 0 and stats.errors == 0
            await pilot.press("q")

    asyncio.run(run())
    capture = read_capture(capture_path)
    assert [label for label, _ in capture.segments()] == ["+z", "-z"]
    steps = np.diff(capture.t)
    assert capture.rate_hz == pytest.approx(1000.0, rel=1e-3)
    assert steps.max() < 1.5e-3, "a gap in the capture: samples were lost"
    for _, sl in capture.segments():
        assert sl.stop - sl.start >= 1500
