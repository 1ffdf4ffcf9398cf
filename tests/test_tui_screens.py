"""TUI screens headless: SVG snapshots of key screens, keys (skip, abort, help), Allan and thermal screens,
and the text drawings and plots they are made of."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
from tui_helpers import expect_snapshot, svg_rows, wait_for

from drivers import open_device
from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from mocks.rig import ramp, sequence_segments, simulate
from mocks.truth import UnitTruth
from station.acquisition.capture import read_capture
from station.acquisition.runner import RunResult
from station.acquisition.sequences import RotationStep, builtin
from station.export.params.file import ParamsFile
from station.tui.app import StationApp
from station.tui.art import bar, pose_art, rotation_art
from station.tui.config import TuiConfig
from station.tui.limits import ACCEL_LIMITS, evaluate
from station.tui.plot import Series, draw
from station.tui.screens.allan import AllanScreen
from station.tui.screens.results import ResultsScreen
from station.tui.screens.thermal import ThermalScreen, block_means, temperature_rate
from station.tui.screens.wizard import WizardScreen
from station.tui.session import Session

pytestmark = pytest.mark.timeout(180)
SIZE = (110, 40)


# ---- drawings and plots ----------------------------------------------------------------------------

def test_pose_and_rotation_drawings_name_the_faces_and_the_turn():
    art = pose_art("-z")
    assert "-Z" in art.splitlines()[2] and "+Z towards the table" in art
    assert "edge up" in pose_art("+x+y") and "corner up" in pose_art("+x+y+z")
    ccw = rotation_art(RotationStep("rot+z", rate_dps=45))
    cw = rotation_art(RotationStep("rot-x:180"))
    assert "+360 deg (1 turn) about +Z, counter-clockwise" in ccw and "45 deg/s" in ccw
    assert "-180 deg about +X, clockwise" in cw
    # Counter-clockwise seen from above: the far side moves left, the near side right.
    assert "◀" in ccw.splitlines()[2] and "▶" in ccw.splitlines()[6]
    assert "▶" in cw.splitlines()[2] and "◀" in cw.splitlines()[6]
    assert bar(0.5, 10) == "█████░░░░░" and bar(1.7, 4) == "████" and bar(float("nan"), 3) == "░░░"
    assert bar(0.55, 10) == "█████▌░░░░"


def test_log_log_plot_draws_a_falling_line_with_its_axes_labels_and_legend():
    from rich.text import Text
    from textual.app import App
    from textual_plotext import PlotextPlot

    class One(App[None]):
        def compose(self):
            yield PlotextPlot()

    tau = np.logspace(-2, 2, 200)
    app = One()
    drawn = {}

    async def run() -> None:
        async with app.run_test(size=(60, 20)) as pilot:
            widget = app.query_one(PlotextPlot)
            drawn["count"] = draw(widget, [Series("white", tau, 0.01 / np.sqrt(tau), "red"),
                                           Series("none", tau[:1], tau[:1])],  # one point: left out
                                  title="ADEV", xlabel="tau (s)", ylabel="rad/s", logx=True, logy=True)
            await pilot.pause(0.3)
            drawn["rows"] = Text.from_ansi(widget.plt.build()).plain.splitlines()  # as rendered, 60x20
            await pilot.resize_terminal(70, 22)  # rendered again: plotext's log scale took log(log) here
            await pilot.pause(0.2)
            empty = app.query_one(PlotextPlot)
            draw(empty, [], title="ADEV", xlabel="tau (s)", ylabel="rad/s")
            await pilot.pause(0.2)
            drawn["empty"] = svg_rows(app.export_screenshot())

    asyncio.run(run())
    rows = drawn["rows"]
    assert drawn["count"] == 1
    text = "\n".join(rows)
    assert "ADEV" in rows[0] and "tau (s)" in text and "rad/s" in text and "white" in text
    braille = [(i, next(j for j, ch in enumerate(row) if 0x2800 < ord(ch) <= 0x28FF and ch != "⢕"))
               for i, row in enumerate(rows) if any(0x2800 < ord(ch) <= 0x28FF and ch != "⢕" for ch in row)]
    columns = [j for _, j in braille]
    assert len(braille) >= 8 and columns == sorted(columns), "the line does not fall left to right"
    assert "0.1" in text and "0.001" in text  # the log axis' ticks, in values, not exponents
    assert "waiting for data" in "\n".join(drawn["empty"])


def test_limits_flag_what_is_outside():
    from station.engines.shared.sensor_model import SensorCalibration

    good = SensorCalibration.from_parts([1.01, 0.99, 1.0], np.zeros((3, 3)), [0.1, 0, 0], residual_rms=0.01)
    assert all(v.passed for v in evaluate("accel", good, ACCEL_LIMITS, "m/s^2"))
    bad = SensorCalibration.from_parts([1.3, 1, 1], np.zeros((3, 3)), [2.0, 0, 0], residual_rms=0.01)
    failed = {v.name for v in evaluate("accel", bad, ACCEL_LIMITS, "m/s^2") if not v.passed}
    assert failed == {"max |bias|", "max |scale - 1|"}


# ---- snapshots and keys on the simulated unit ------------------------------------------------------

def test_wizard_snapshot_help_skip_and_abort(tmp_path):
    # Holds long enough that no step can finish before the keys arrive on a loaded machine.
    config = TuiConfig(simulate=True, seed=1, hold_s=30.0, out=tmp_path / "p.yaml")
    app = StationApp(config)

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.press("w")
            wizard = await wait_for(pilot, lambda: isinstance(app.screen, WizardScreen) and app.screen, 5,
                                    "the wizard")
            await wait_for(pilot, lambda: wizard.prompt is not None, 10, "the start prompt")
            await expect_snapshot(pilot, app, "wizard_start")
            await pilot.press("question_mark")
            await expect_snapshot(pilot, app, "help")
            await pilot.press("escape")
            await pilot.press("enter")  # start
            await wait_for(pilot, lambda: wizard.current == 0, 10, "the first step")
            await pilot.press("s")  # skip +x
            await wait_for(pilot, lambda: wizard.current == 1, 10, "the second step")
            rows = "\n".join(svg_rows(app.export_screenshot()))
            assert "Step 2 of 12: -x" in rows and "Place the unit with -X up" in rows
            await pilot.press("x")  # abort
            await wait_for(pilot, lambda: wizard.result is not None, 10, "the end of the run")
            assert wizard.result.outcome == "aborted"
            assert [r.status for r in wizard.result.steps] == ["skipped", "aborted"]
            await pilot.press("enter")  # results: nothing was captured, so the calibration says so
            results = await wait_for(pilot, lambda: isinstance(app.screen, ResultsScreen) and app.screen, 5,
                                     "results")
            await pilot.pause(0.5)
            assert results.report is None
            assert "no step was captured" in "\n".join(svg_rows(app.export_screenshot()))
            await pilot.press("q")

    asyncio.run(run())
    assert app.return_value == 2  # an aborted run: ExitCode.ABORTED, as `tui --help` says
    assert not (tmp_path / "p.yaml").exists()


def test_results_snapshot_of_an_ideal_unit(tmp_path, monkeypatch):
    # A relative output path: the screen shows it, and the snapshot must not depend on where tmp is.
    monkeypatch.chdir(tmp_path)
    truth = UnitTruth.ideal()
    segments = sequence_segments("six-position", hold_s=1.0, rotation_rate_dps=180.0)
    rec = simulate(truth, segments, rate_hz=100.0)
    capture = rec.to_capture()
    capture.device = {"serial": "SIM-IDEAL", "model": "imu-sim", "firmware": "1.0.0", "rate_hz": 100}
    run = RunResult("completed", capture, [], builtin("six-position"))
    out = Path("ideal.yaml")
    app = StationApp(TuiConfig(out=out))

    async def drive() -> None:
        async with app.run_test(size=(110, 60)) as pilot:
            await _connect_screen_ready(pilot, app)
            app.show_results(run)
            screen = await wait_for(pilot, lambda: isinstance(app.screen, ResultsScreen) and app.screen, 5,
                                    "results")
            await wait_for(pilot, lambda: screen.report is not None, 30, "the calibration")
            await expect_snapshot(pilot, app, "results_ideal")
            await pilot.press("enter")
            await wait_for(pilot, lambda: screen.saved, 5, "save")
            await pilot.press("enter")

    asyncio.run(drive())
    params = ParamsFile.load(out)
    assert np.allclose(params.accel.matrix, np.eye(3), atol=1e-9)
    assert np.allclose(params.gyro.matrix, np.eye(3), atol=1e-6)
    assert params.device["serial"] == "SIM-IDEAL"
    assert app.return_value == 0


def test_allan_screen_plots_and_fits_the_white_noise(tmp_path):
    out = tmp_path / "noise.yaml"
    config = TuiConfig(simulate=True, seed=6, rate_hz=1000.0, out=out, speed=2.0)
    app = StationApp(config)
    holder = {}

    async def run() -> None:
        async with app.run_test(size=(130, 44)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            holder["truth"] = app.session.rig.truth
            await pilot.press("a")
            screen = await wait_for(pilot, lambda: isinstance(app.screen, AllanScreen) and app.screen, 5,
                                    "Allan")
            await wait_for(pilot, lambda: recorded(screen) >= 8000, 60, "8 s of samples")
            await pilot.pause(1.2)
            rows = svg_rows(app.export_screenshot())
            assert any("gyro ADEV" in r for r in rows) and any("rad/s" in r for r in rows)
            assert sum(any(0x2800 < ord(c) <= 0x28FF for c in r) for r in rows) >= 6  # braille dots drawn
            await pilot.press("enter")
            await wait_for(pilot, lambda: out.exists(), 60, "the noise section")
            await pilot.pause(0.3)
            assert any("noise section saved" in r for r in svg_rows(app.export_screenshot()))
            await pilot.press("q")

    asyncio.run(run())
    noise = ParamsFile.load(out).noise
    truth_n = holder["truth"].gyro.noise.N
    fitted = np.asarray(noise["gyro"]["N"], float)
    assert np.allclose(fitted, truth_n, rtol=0.25), (fitted, truth_n)
    recording = read_capture(tmp_path / "noise-allan.h5")
    assert len(recording) >= 8000 and recording.rate_hz == pytest.approx(1000.0, rel=1e-3)


def test_thermal_screen_follows_a_ramp_and_fits(tmp_path):
    out = tmp_path / "thermal.yaml"
    profile = ramp([(0.0, 20.0), (30.0, 50.0), (60.0, 20.0)])
    unit = SimDevice(seed=8, rate_hz=100.0, scenario="still", temperature=profile)
    server = PtyServer(unit, speed=4.0).start()
    device = open_device(server.port_path)
    app = StationApp(TuiConfig(out=out))

    async def run() -> None:
        async with app.run_test(size=(130, 44)) as pilot:
            await _connect_screen_ready(pilot, app)
            app.session = Session(device, "simulated chamber", info=device.get_info())
            app.show("thermal")
            screen = await wait_for(pilot, lambda: isinstance(app.screen, ThermalScreen) and app.screen, 5,
                                    "thermal")
            await wait_for(pilot, lambda: recorded(screen) >= 2500, 60, "25 s of the sweep")
            await pilot.pause(0.6)
            rows = "\n".join(svg_rows(app.export_screenshot()))
            assert "temperature (degC)" in rows and "degC/min" in rows
            await pilot.press("enter")
            await wait_for(pilot, lambda: out.exists(), 60, "the thermal section")
            await pilot.press("q")

    try:
        asyncio.run(run())
    finally:
        device.close()
        server.stop()
    params = ParamsFile.load(out)
    assert params.thermal is not None
    recording = read_capture(tmp_path / "thermal-thermal.h5")
    blocks = block_means(_samples(recording))
    # The ramp climbs 1 degC/s: the monitor's rate estimate over the first 20 s says so.
    first = blocks["t"] <= 20
    assert temperature_rate(blocks["t"][first], blocks["temp"][first], 15.0) == pytest.approx(1.0, rel=0.05)


def recorded(screen) -> int:
    """Samples the screen's recording holds (0 until the screen has mounted)."""
    recording = getattr(screen, "recording", None)
    return recording.count if recording is not None else 0


async def _connect_screen_ready(pilot, app) -> None:
    await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 5, "the connect screen")
    await pilot.pause(0.2)


def _samples(capture):
    from protocols.base import SAMPLE_DTYPE

    out = np.zeros(len(capture), SAMPLE_DTYPE)
    out["t_us"] = np.round(capture.t * 1e6).astype(np.uint64)
    out["acc"], out["gyro"], out["temp"] = capture.acc, capture.gyro, capture.temp
    return out


def test_a_capture_file_that_cannot_be_written_is_reported_on_the_screen(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where a folder should be")
    app = StationApp(TuiConfig(simulate=True, seed=2, capture=blocker / "run.csv"))

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.press("w")
            def stopped() -> bool:
                return any("The run stopped" in r for r in svg_rows(app.export_screenshot()))

            await wait_for(pilot, stopped, 10, "the error on the screen", step_s=0.3)
            rows = "\n".join(svg_rows(app.export_screenshot()))
            assert "not-a-dir" in rows
            await pilot.press("q")

    asyncio.run(run())


def test_thermal_screen_on_the_simulated_chamber_fits_and_saves(tmp_path):
    from mocks import register_sim_url

    register_sim_url()
    out = tmp_path / "chamber.yaml"
    app = StationApp(TuiConfig(port="sim://?scenario=chamber&speed=400", out=out))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated chamber")
            await pilot.press("t")
            screen = await wait_for(pilot, lambda: isinstance(app.screen, ThermalScreen) and app.screen, 5,
                                    "thermal")
            await wait_for(pilot, lambda: recorded(screen) >= 200 * 60 * 40, 120, "40 min of the sweep")
            await pilot.pause(0.6)
            rows = "\n".join(svg_rows(app.export_screenshot()))
            assert "degC/min" in rows and "temperature (degC)" in rows
            await pilot.press("enter")
            await wait_for(pilot, lambda: out.exists(), 120, "the thermal section")
            await pilot.pause(0.3)
            assert "thermal section saved" in "\n".join(svg_rows(app.export_screenshot()))
            await pilot.press("q")

    asyncio.run(run())
    params = ParamsFile.load(out)
    assert params.thermal is not None and params.device["serial"].startswith("SIM-")
