"""The TUI never loses a result: quitting (q, Ctrl-C) or leaving unsaved results asks to save, discard
or go back; a hang-up saves them to a file of their own; the exit code says how the run ended."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import sys

import numpy as np
import pytest
from tui_helpers import ideal_run, results_ready, screen_text, wait_for

from drivers import open_device
from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from station.errors import ExitCode
from station.export.params.file import ParamsFile
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.screens.ask import AskScreen
from station.tui.session import Session

pytestmark = pytest.mark.timeout(120)


def test_q_on_unsaved_results_asks_and_back_keeps_them(tmp_path):
    out = tmp_path / "unit.yaml"
    app = StationApp(TuiConfig(out=out))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            results = await results_ready(pilot, app, ideal_run())
            await pilot.press("q")
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            text = screen_text(app)
            assert "The calibration is not saved" in text and "s: save" in text and "d: discard" in text
            await pilot.press("escape")  # back
            await wait_for(pilot, lambda: app.screen is results, 5, "the results again")
            assert app.return_value is None and not out.exists()
            await pilot.press("ctrl+c")  # Ctrl-C asks too
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question on Ctrl-C")
            await pilot.press("s")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.OK
    assert np.allclose(ParamsFile.load(out).accel.matrix, np.eye(3), atol=1e-9)
    assert app.saved == [str(out)]


def test_without_out_the_question_offers_a_file_and_discard_exits_without_writing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    app = StationApp(TuiConfig())

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await results_ready(pilot, app, ideal_run())
            await pilot.press("enter")  # "Enter: choose a file to save to ..."
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            assert "no --out was given" in screen_text(app)
            await pilot.press("d")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.OK and app.saved == []
    assert list(tmp_path.iterdir()) == []


def test_a_file_that_cannot_be_written_asks_again_and_another_name_saves(tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where a folder should be")
    app = StationApp(TuiConfig(out=blocker / "unit.yaml"))
    other = tmp_path / "other.yaml"

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await results_ready(pilot, app, ideal_run())
            await pilot.press("q")
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            await pilot.press("s")
            await wait_for(pilot, lambda: "Could not save" in screen_text(app), 5, "the refusal")
            assert isinstance(app.screen, AskScreen) and app.return_value is None
            await pilot.press("e")
            field = app.screen.query_one("#path")
            field.value = str(other)
            await pilot.press("enter")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert ParamsFile.load(other).device["serial"] == "SIM-IDEAL"


def test_leaving_unsaved_results_for_another_screen_asks_first(tmp_path):
    server = PtyServer(SimDevice(seed=3, rate_hz=100.0, scenario="still")).start()
    device = open_device(server.port_path)
    app = StationApp(TuiConfig(out=tmp_path / "unit.yaml"))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            results = await results_ready(pilot, app, ideal_run())
            # The live view needs a session (the app reads its port meanwhile); the question comes first.
            app.session = Session(device, "simulated unit", info=device.get_info())
            app.show("live")
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            await pilot.press("escape")
            await wait_for(pilot, lambda: app.screen is results, 5, "the results again")
            app.session = None
            app.exit(0)

    try:
        asyncio.run(run())
    finally:
        device.close()
        server.stop()


def test_a_hangup_saves_unsaved_results_beside_out_and_exits(tmp_path):
    out = tmp_path / "unit.yaml"
    app = StationApp(TuiConfig(out=out))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await results_ready(pilot, app, ideal_run())
            os.kill(os.getpid(), signal.SIGHUP)
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert not out.exists()  # nobody said yes to --out
    assert app.recovered is not None and app.recovered.parent == tmp_path
    assert app.recovered.name.startswith("unit-unsaved-")
    assert ParamsFile.load(app.recovered).device["serial"] == "SIM-IDEAL"
    assert app.return_value == ExitCode.OK


def test_results_outside_the_limits_exit_1():
    run_result = ideal_run()
    run_result.capture.acc[:] += 2.0  # a 2 m/s^2 bias on every axis: beyond the 1.5 built in
    app = StationApp(TuiConfig())

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await results_ready(pilot, app, run_result)
            assert "FAIL" in screen_text(app)
            await pilot.press("q")
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            await pilot.press("d")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.OUT_OF_LIMITS


def test_replacing_a_noise_section_from_the_allan_screen_asks_first(tmp_path):
    out = tmp_path / "unit.yaml"
    old_noise = {"gyro": {"N": [1.0, 1.0, 1.0]}, "note": "the noise of last week"}
    ParamsFile(device={"serial": "SIM-000006"}, noise=old_noise).save(out)
    app = StationApp(TuiConfig(simulate=True, seed=6, rate_hz=1000.0, out=out, speed=4.0))

    async def record_and_fit(pilot) -> None:
        await pilot.press("a")
        screen = await wait_for(pilot, lambda: type(app.screen).__name__ == "AllanScreen" and app.screen, 5,
                                "Allan")
        await wait_for(pilot, lambda: getattr(getattr(screen, "recording", None), "count", 0) >= 6000, 60,
                       "6 s of samples")
        await pilot.press("enter")
        await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 60, "the question")
        assert "already holds a noise section" in screen_text(app)

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await record_and_fit(pilot)
            await pilot.press("k")  # keep the file's
            await wait_for(pilot, lambda: "keeps the one it had" in screen_text(app), 5, "the answer")
            assert ParamsFile.load(out).noise == old_noise
            await pilot.press("escape")
            await wait_for(pilot, lambda: type(app.screen).__name__ == "LiveScreen", 5, "the live view")
            await record_and_fit(pilot)
            await pilot.press("r")  # replace it
            await wait_for(pilot, lambda: "noise section saved" in screen_text(app), 10, "the save")
            await pilot.press("q")

    asyncio.run(run())
    noise = ParamsFile.load(out).noise
    assert noise != old_noise and len(noise["gyro"]["N"]) == 3


def _other_units_file(path):
    ParamsFile(device={"serial": "OTHER-7", "model": "imu-sim"}, noise={"note": "unit 7's noise"}).save(path)
    return path.read_text()


@pytest.mark.parametrize("answer", ["another file", "replace"])
def test_a_file_of_another_unit_is_refused_on_the_screen_then_replaced_or_left(tmp_path, answer):
    out = tmp_path / "unit.yaml"
    before = _other_units_file(out)
    other = tmp_path / "ideal.yaml"
    app = StationApp(TuiConfig(out=out))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            results = await results_ready(pilot, app, ideal_run())
            await pilot.press("enter")  # save to --out: refused, asked
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            text = screen_text(app).replace("\n", " ")
            assert "OTHER-7" in text and "SIM-IDEAL" in text and "r: replace that file" in text
            if answer == "replace":
                await pilot.press("r")
            else:
                await pilot.press("e")
                app.screen.query_one("#path").value = str(other)
                await pilot.press("enter")
            await wait_for(pilot, lambda: results.saved, 5, "the save")
            await pilot.press("enter")  # quit
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    if answer == "replace":
        params = ParamsFile.load(out)
        assert params.device["serial"] == "SIM-IDEAL" and params.noise is None  # started afresh
    else:
        assert out.read_text() == before  # untouched
        assert ParamsFile.load(other).device["serial"] == "SIM-IDEAL"


def test_tui_help_states_the_exit_codes_the_app_returns():
    done = subprocess.run([sys.executable, "-m", "station.cli", "tui", "--help"], capture_output=True,
                          text=True, timeout=60)
    text = " ".join(done.stdout.split()).split("exit codes:")[1].split("examples:")[0]
    codes = {int(n): what for n, what in re.findall(r"(\d) ([a-z][^;.]*)", text)}
    assert "outside its limits" in codes[ExitCode.OUT_OF_LIMITS]
    assert "aborted" in codes[ExitCode.ABORTED] and codes[ExitCode.OK].startswith("done")
    assert "usage" in codes[ExitCode.USAGE]
