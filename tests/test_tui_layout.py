"""Every screen at 80x24 and at 160x48: SVG snapshots (compared by structure) and the words that must not
be clipped: the pose caption, the turn's direction and rate, the footer keys, values with their
uncertainty on one line. The screens are driven by the simulated unit, then given fixed data (the
reader stopped) so that what is drawn is the same on every run; notices end with their step; the
progress bar follows a turn."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from serial.tools import list_ports
from test_tui_ports import _ports
from tui_helpers import expect_snapshot, ideal_run, results_ready, screen_text, stop_reader, wait_for

from station.acquisition.checks import PoseCheck, Stillness
from station.acquisition.runner import LiveStatus, State
from station.acquisition.sequences import builtin
from station.tui.app import StationApp
from station.tui.bridge import RunnerEvent
from station.tui.config import TuiConfig
from station.tui.messages import Snapshot
from station.tui.screens.wizard import WizardScreen

pytestmark = pytest.mark.timeout(180)
SIZES = ((80, 24), (160, 48))


@pytest.fixture(autouse=True)
def fixed_ports(monkeypatch):
    """The same serial ports on every machine."""
    monkeypatch.setattr(list_ports, "comports", _ports)


def _run(config: TuiConfig, show, check, name: str) -> None:
    """Open the simulated unit, ``await show(pilot, app)``, then at each size compare the snapshot
    ``<name>_<W>x<H>`` and ``check(text, width)``."""
    app = StationApp(config)

    async def run() -> None:
        async with app.run_test(size=SIZES[0], notifications=True) as pilot:
            if config.simulate:
                await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await show(pilot, app)
            for width, height in SIZES:
                await pilot.resize_terminal(width, height)
                await expect_snapshot(pilot, app, f"{name}_{width}x{height}")
                check(screen_text(app), width)
            app.exit(0)

    asyncio.run(run())


def _footer(text: str, *keys: str) -> None:
    footer = text.splitlines()[-1]
    for key in keys:
        assert key in footer, f"{key!r} is not in the footer {footer!r}"


async def _stop_reader(pilot, app, name: str):
    """The screen ``name`` with its reader stopped: its worker has ended, so no snapshot of the unit can
    arrive after the one a test posts (a thread worker only sees its cancellation between reads)."""
    screen = await wait_for(pilot, lambda: type(app.screen).__name__ == name and app.screen, 10, name)
    await pilot.pause(0.3)
    await stop_reader(pilot, screen)
    return screen


def test_connect():
    async def show(pilot, app):
        await wait_for(pilot, lambda: "serial" in screen_text(app), 10, "the unit's info")

    def check(text, width):
        assert "/dev/ttyUSB0         CP2102 USB to UART Bridge" in text and "SIM-000001" in text
        assert "200 Hz" in text and "rate_hz" not in text  # labels, not the unit's info keys
        _footer(text, "⏎ continue", "c other port", "? help", "q quit")

    _run(TuiConfig(simulate=True, seed=1), show, check, "connect")


def test_live_traces_have_axes_and_units():
    async def show(pilot, app):
        await pilot.press("enter")
        screen = await _stop_reader(pilot, app, "LiveScreen")
        t = np.arange(400) / 200.0
        tail = np.column_stack([t, 0.1 * np.sin(t), 0.2 * np.cos(t), 9.8 + 0.05 * np.sin(3 * t),
                                0.01 * np.sin(2 * t), -0.01 * np.cos(t), 0.002 * t, np.full_like(t, 25.0)])
        screen.post_message(Snapshot({"tail": tail, "stats": app.session.device.stats}))

    def check(text, width):
        for words in ("accelerometer", "gyroscope", "time (s)", "m/s^2", "rad/s", "accel", "degC"):
            assert words in text, words
        _footer(text, "⏎ sequence wizard", "? help", "q quit")

    _run(TuiConfig(simulate=True, seed=1), show, check, "live")


def _status(step, state: State, angle: float | None = None) -> LiveStatus:
    return LiveStatus(index=1, total=12, step=step, state=state, attempt=1, message="hold still",
                      stillness=Stillness(0.01, 0.001, 0.0, 0.5), rate_hz=200.0,
                      pose=PoseCheck(1.5, (0.0, 0.0, 1.0), step.label, True) if angle is None else None,
                      angle_deg=angle, target_deg=None if angle is None else 360.0)


async def _wizard_at(pilot, app, label: str, sequence: str = "six-position"):
    """The wizard blocked on its start prompt (the runner waits), shown at step ``label``."""
    await pilot.press("w")
    wizard = await wait_for(pilot, lambda: isinstance(app.screen, WizardScreen) and app.screen, 10, "wizard")
    await wait_for(pilot, lambda: wizard.prompt is not None, 10, "the start prompt")
    seq = builtin(sequence)
    index = seq.labels.index(label)
    step = seq.steps[index]
    wizard.post_message(RunnerEvent("place", step, index, len(seq)))
    wizard.post_message(RunnerEvent("answered"))
    await pilot.pause(0.2)
    return wizard, step


def test_wizard_in_a_pose():
    async def show(pilot, app):
        wizard, step = await _wizard_at(pilot, app, "-x")
        wizard.post_message(RunnerEvent("status", _status(step, State.CAPTURING)))

    def check(text, width):
        for words in ("Step 2 of 12: -x", "Place the unit with -X up", "-X face up, lying flat",
                      "(+X towards the table)", "table", "r: redo this step"):
            assert words in text, words
        _footer(text, "⏎ next", "r redo", "s skip", "x abort", "q quit")

    _run(TuiConfig(simulate=True, seed=1, hold_s=30.0), show, check, "wizard_pose")


def test_wizard_in_a_turn_and_the_bar_follows_it():
    seen = {}

    async def show(pilot, app):
        wizard, step = await _wizard_at(pilot, app, "rot+y")
        bar = wizard.query_one("#capture")
        for angle in (45.0, 180.0):
            wizard.post_message(RunnerEvent("status", _status(step, State.ROTATING, angle)))
            await pilot.pause(0.2)
            seen[angle] = bar.progress
        wizard.post_message(RunnerEvent("rotate", step))
        await pilot.pause(0.3)
        seen["notice"] = "Turn now: rot+y" in screen_text(app)
        wizard.post_message(RunnerEvent("finished", _record(step)))  # the turn ends, its notice too
        await pilot.pause(0.3)
        seen["after"] = "Turn now" in screen_text(app)
        wizard.post_message(RunnerEvent("place", step, 8, 12))
        wizard.post_message(RunnerEvent("status", _status(step, State.ROTATING, 94.7)))

    def check(text, width):
        for words in ("Step 9 of 12: rot+y", "turn +360 deg (1 turn) about +Y",
                      "counter-clockwise seen from above", "at about 90 deg/s", "+94.7 of +360 deg"):
            assert words in text, words
        _footer(text, "⏎ next", "x abort", "q quit")

    _run(TuiConfig(simulate=True, seed=1), show, check, "wizard_turn")
    assert seen[45.0] == pytest.approx(0.125) and seen[180.0] == pytest.approx(0.5)
    assert seen["notice"] and not seen["after"]


def _record(step):
    from station.acquisition.runner import StepRecord

    return StepRecord(step.label, "rotation", "accepted", 1)


def test_wizard_draws_a_diagonal_pose_as_diagonal():
    async def show(pilot, app):
        wizard, step = await _wizard_at(pilot, app, "+x+y", "twelve-position")
        wizard.post_message(RunnerEvent("status", _status(step, State.PLACING)))

    def check(text, width):
        assert "+X +Y edge up: tilted 45 deg" in text and "(-X -Y towards the table)" in text
        rows = text.splitlines()
        apex = next(i for i, row in enumerate(rows) if "╱ ╲" in row)
        assert "+X ╱" in rows[apex + 1] and "╲ +Y" in rows[apex + 1] and "IMU" in rows[apex + 2]

    _run(TuiConfig(simulate=True, seed=1, sequence="twelve-position"), show, check, "wizard_edge")


def test_results():
    async def show(pilot, app):
        screen = await results_ready(pilot, app, ideal_run())
        await pilot.press("down")  # the body scrolls with the keys ...
        await pilot.pause(0.2)
        body = screen.query_one("#body")
        assert body.scroll_y > 0
        body.scroll_to(y=14, animate=False)  # ... to the accelerometer's table, below the verdicts

    def check(text, width):
        assert "PASS against the built-in limits" in text
        bias = next(row for row in text.splitlines() if row.startswith("bias "))
        assert bias.count("±") == 3 and "m/s^2" in bias  # a value and its 1-sigma on one line
        _footer(text, "⏎ save and quit", "e exports", "q quit")

    _run(TuiConfig(out=None), show, check, "results")


def test_allan():
    async def show(pilot, app):
        await pilot.press("a")
        screen = await _stop_reader(pilot, app, "AllanScreen")
        tau = np.logspace(-2, 1.5, 20)
        adev = np.column_stack([k * 1e-3 / np.sqrt(tau) for k in (1.0, 1.2, 1.4, 10, 12, 14)])
        screen.post_message(Snapshot({"count": 12000, "stats": app.session.device.stats, "tau": tau,
                                      "adev": adev, "rate_hz": 200.0}))

    def check(text, width):
        for words in ("gyro ADEV", "accel ADEV", "tau (s)", "rad/s", "m/s^2", "Enter: stop and fit"):
            assert words in text, words
        _footer(text, "⏎ stop and fit", "esc back", "q quit")

    _run(TuiConfig(simulate=True, seed=1), show, check, "allan")


def test_thermal():
    async def show(pilot, app):
        await pilot.press("t")
        screen = await _stop_reader(pilot, app, "ThermalScreen")
        t = np.arange(120.0)
        temp = 20 + 0.5 * t
        gyro = np.column_stack([1e-4 * temp, -2e-4 * temp, 5e-5 * temp])
        screen.post_message(Snapshot({"blocks": {"t": t, "temp": temp, "gyro": gyro, "acc": gyro},
                                      "stats": app.session.device.stats}))

    def check(text, width):
        for words in ("temperature (degC)", "time (min)", "gyro bias change", "degC/min",
                      "Enter: stop and fit"):
            assert words in text, words
        _footer(text, "⏎ stop and fit", "esc back", "q quit")

    _run(TuiConfig(simulate=True, seed=1), show, check, "thermal")


def test_help():
    async def show(pilot, app):
        await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 5, "connect")
        await pilot.press("question_mark")

    def check(text, width):
        for words in ("imu-station TUI: keys", "q, ctrl+c  quit (asks first about",
                      "up/down  choose a port          Enter      connect, then the live view",
                      "k        keep a failed step     x          abort (keeps what was"):
            assert words in text, words  # whole lines: nothing wraps at 80 columns

    _run(TuiConfig(), show, check, "help")
