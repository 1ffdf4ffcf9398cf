"""How the TUI ends (issue 31): quitting after --port failed to open exits with the port's error code,
not 0; Ctrl-C in the middle of the wizard says it was interrupted and exits 130, keeping the capture."""

from __future__ import annotations

import asyncio

import pytest
from tui_helpers import screen_text, wait_for

from station.acquisition.runner import State
from station.errors import ExitCode
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.screens.wizard import WizardScreen

pytestmark = pytest.mark.timeout(180)


def test_quitting_after_a_missing_port_exits_with_the_device_error_code(tmp_path):
    missing = tmp_path / "ttyUSB-nothing-here"
    app = StationApp(TuiConfig(port=str(missing)))
    seen: dict[str, object] = {}

    async def run() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await wait_for(pilot, lambda: app.connect_error is not None, 30, "the port's error")
            await wait_for(pilot, lambda: "Choose a port" in screen_text(app), 10, "the error on the screen")
            seen["note"] = app.exit_note()
            await pilot.press("q")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.DEVICE
    assert str(seen["note"]).startswith("error: ") and missing.name in str(seen["note"])


def test_a_port_that_opens_after_a_failed_one_clears_the_error(tmp_path):
    from station.tui.screens.connect import ConnectScreen
    from station.tui.session import SIMULATED

    app = StationApp(TuiConfig(port=str(tmp_path / "ttyUSB-nothing-here")))

    async def run() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await wait_for(pilot, lambda: app.connect_error is not None, 30, "the port's error")
            screen = app.screen
            assert isinstance(screen, ConnectScreen)
            screen.connect(SIMULATED)  # the operator picks another port, which opens
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            assert app.connect_error is None
            await pilot.press("q")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.OK and app.exit_note() is None


def test_ctrl_c_mid_wizard_says_interrupted_exits_130_and_keeps_the_capture(tmp_path):
    capture = tmp_path / "run.csv"
    app = StationApp(TuiConfig(simulate=True, seed=1, hold_s=30.0, capture=capture))

    async def run() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.press("enter")  # connect -> live view
            await wait_for(pilot, lambda: type(app.screen).__name__ == "LiveScreen", 10, "the live view")
            await pilot.press("enter")  # live -> wizard
            wizard = await wait_for(pilot, lambda: isinstance(app.screen, WizardScreen) and
                                    app.screen.prompt is not None and app.screen, 30, "the start prompt")
            await pilot.press("enter")  # start
            await wait_for(pilot, lambda: wizard.status is not None and
                           wizard.status.state is State.CAPTURING, 60, "the first step's capture")
            await pilot.pause(0.5)
            await pilot.press("ctrl+c")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.INTERRUPTED
    note = app.exit_note()
    assert note is not None and note.startswith("interrupted") and str(capture) in note
    rows = [line for line in capture.read_text().splitlines() if line and not line.startswith("#")]
    assert len(rows) > 50, "the samples captured before Ctrl-C are kept"


def test_ctrl_c_outside_a_run_quits_as_q_does():
    app = StationApp(TuiConfig(simulate=True, seed=1))

    async def run() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.press("ctrl+c")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert app.return_value == ExitCode.OK and app.exit_note() is None
