"""The TUI judges against a factory plan's limits with --plan (or --limits) and says which limits it uses;
the results show labels, not the engines' column names."""

from __future__ import annotations

import asyncio
import subprocess
import sys

import pytest
from tui_helpers import ideal_run, results_ready, screen_text, wait_for

from station.errors import ExitCode
from station.factory.plan import load_plan
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.screens.ask import AskScreen

pytestmark = pytest.mark.timeout(120)

PLAN = """\
schema: imu-station/plan/1
name: tight-line
sequence: six-position
limits:
  accel.bias: {max_abs: 100, unit: mg}
  accel.scale_error: {max_abs: 1, unit: "%"}
"""


def _drive(app: StationApp, run_result) -> str:
    seen = {}

    async def run() -> None:
        async with app.run_test(size=(160, 48)) as pilot:
            await results_ready(pilot, app, run_result)
            seen["text"] = screen_text(app)
            await pilot.press("q")
            await wait_for(pilot, lambda: isinstance(app.screen, AskScreen), 5, "the question")
            await pilot.press("d")
            await wait_for(pilot, lambda: app.return_value is not None, 10, "the app to exit")

    asyncio.run(run())
    return seen["text"]


def test_a_plans_limits_judge_what_the_built_in_ones_pass(tmp_path):
    plan_path = tmp_path / "line.yaml"
    plan_path.write_text(PLAN)
    biased = ideal_run()
    biased.capture.acc[:] += 1.2  # 122 mg: within the built-in 1.5 m/s^2, beyond the plan's 100 mg

    loose = StationApp(TuiConfig())
    text = _drive(loose, biased)
    assert "limits: built-in" in text.splitlines()[0]  # the header says which
    assert "limits: built-in (loose" in text and "FAIL" not in text
    assert loose.return_value == ExitCode.OK

    tight = StationApp(TuiConfig(plan=load_plan(plan_path)))
    text = _drive(tight, biased)
    assert "limits: plan tight-line" in text.splitlines()[0]
    assert f"limits: plan tight-line ({plan_path})" in text.replace("\n", "")
    bias_row = next(row for row in text.splitlines() if "bias" in row and "mg" in row)
    assert "FAIL" in bias_row and "±100 mg" in bias_row and "122.4 mg" in bias_row
    assert tight.return_value == ExitCode.OUT_OF_LIMITS


def test_results_show_labels_not_column_names():
    app = StationApp(TuiConfig())
    text = _drive(app, ideal_run())
    assert "angle error (deg)" in text and "|g| error (m/s^2)" in text
    assert "angle_error_deg" not in text and "norm_error" not in text


def test_a_bad_plan_is_refused_before_the_screen_opens(tmp_path):
    plan_path = tmp_path / "bad.yaml"
    plan_path.write_text(PLAN.replace("unit: mg", "unit: deg"))
    done = subprocess.run([sys.executable, "-m", "station.cli", "tui", "--limits", str(plan_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == ExitCode.USAGE
    assert str(plan_path) in done.stderr and "line 5" in done.stderr and "Traceback" not in done.stderr
