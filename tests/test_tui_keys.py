"""What the TUI says about its keys (issue 31): Enter on the results screen is labelled with what it does
(save, then quit; save and quit without --out), and a notice at 80x24 leaves the wizard's keys readable."""

from __future__ import annotations

import asyncio

import pytest
from test_tui_layout import _status, _wizard_at
from tui_helpers import ideal_run, results_ready, screen_text, wait_for

from station.acquisition.runner import State
from station.tui.app import StationApp
from station.tui.bridge import RunnerEvent
from station.tui.config import TuiConfig

pytestmark = pytest.mark.timeout(180)
KEY_LINE = "r: redo this step · s: skip it · x: abort (what was captured is kept)"


def _footer(app) -> str:
    return screen_text(app).splitlines()[-1]


def test_enter_on_the_results_is_labelled_save_then_quit(tmp_path):
    out = tmp_path / "unit.yaml"
    app = StationApp(TuiConfig(out=out))
    seen: dict[str, str] = {}

    async def run() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await results_ready(pilot, app, ideal_run())
            seen["before"] = await wait_for(pilot, lambda: "⏎ save" in _footer(app) and _footer(app), 10,
                                            "Enter's label")
            await pilot.press("enter")
            await wait_for(pilot, out.exists, 30, "the parameter file")
            seen["after"] = await wait_for(pilot, lambda: "⏎ quit" in _footer(app) and _footer(app), 10,
                                           "Enter's label once saved")
            assert app.return_value is None, "the first Enter only saves"
            await pilot.press("enter")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    assert "save and quit" not in seen["before"] and "⏎ save " in seen["before"]
    assert "⏎ save" not in seen["after"]


def test_without_out_enter_is_labelled_save_and_quit():
    app = StationApp(TuiConfig(out=None))

    async def run() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await results_ready(pilot, app, ideal_run())
            await wait_for(pilot, lambda: "⏎ save and quit" in _footer(app), 10, "Enter's label")
            app.exit(0)

    asyncio.run(run())


@pytest.mark.parametrize("notice", ["rotate", "redo"])
def test_a_notice_at_80x24_leaves_the_wizards_keys_readable(notice):
    app = StationApp(TuiConfig(simulate=True, seed=1))
    seen: dict[str, str] = {}

    async def run() -> None:
        async with app.run_test(size=(80, 24), notifications=True) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            wizard, step = await _wizard_at(pilot, app, "rot+y")
            wizard.post_message(RunnerEvent("status", _status(step, State.ROTATING, 45.0)))
            if notice == "rotate":
                wizard.post_message(RunnerEvent("rotate", step))
                words = "Turn now: rot+y"
            else:
                await pilot.pause(0.2)
                wizard.action_answer("redo")
                words = "redo requested"
            seen["text"] = await wait_for(pilot, lambda: words in screen_text(app) and screen_text(app), 10,
                                          "the notice")
            app.exit(0)

    asyncio.run(run())
    assert KEY_LINE in seen["text"], seen["text"]
