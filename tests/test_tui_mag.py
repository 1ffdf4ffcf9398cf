"""The TUI's magnetometer step with Pilot: a simulated nine-axis unit turned until the sphere of field
directions is covered (the capture keeps its field), a unit without a magnetometer told apart with
the rest of the TUI still usable, and the screen at 80x24 with nothing clipped."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from pathlib import Path

import numpy as np
import pytest
from serial.tools import list_ports
from test_tui_ports import _ports
from textual.pilot import Pilot
from tui_helpers import screen_text, shown, wait_for

from mocks.mag_sessions import nine_axis_unit
from protocols.base import MAG_SAMPLE_DTYPE
from station.acquisition.capture import read_capture
from station.engines.magnetometer.coverage import CELLS, field_coverage
from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.mag_art import MISSING, NOW, VISITED, disc_directions, hemispheres
from station.tui.screens.live import LiveScreen
from station.tui.screens.mag import MagProgress, MagScreen

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(autouse=True)
def fixed_ports(monkeypatch):
    """The same serial ports on every machine."""
    monkeypatch.setattr(list_ports, "comports", _ports)


def _drive(tmp_path: Path, mag: bool, steps: Callable[[StationApp, Pilot], Awaitable[None]]) -> None:
    """Run the TUI on a simulated unit (a nine-axis one with ``mag``) at 80x24: once its session is
    up, ``steps`` drive it; then the app exits."""
    app = StationApp(TuiConfig(simulate=True, mag=mag, speed=4.0, seed=2, rate_hz=100.0,
                               capture=tmp_path / "run.csv"))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await steps(app, pilot)
            app.exit(0)

    asyncio.run(run())


async def _mag_step(app: StationApp, pilot: Pilot) -> MagScreen:
    """Press m and wait for the magnetometer step's screen."""
    await pilot.press("m")
    await wait_for(pilot, lambda: isinstance(app.screen, MagScreen), 10, "the magnetometer step")
    screen = app.screen
    assert isinstance(screen, MagScreen)
    return screen


def test_a_nine_axis_unit_is_turned_until_the_sphere_is_covered(tmp_path: Path) -> None:
    async def steps(app: StationApp, pilot: Pilot) -> None:
        screen = await _mag_step(app, pilot)
        await wait_for(pilot, lambda: screen.share > 0.2, 30, "some coverage")
        text = screen_text(app)
        for words in ("+z half", "-z half", "covered", "turn next:", "finish"):
            assert words in text, f"{words!r} is not on the 80x24 screen:\n{text}"
        await wait_for(pilot, lambda: screen.finished, 90, "the step to finish by itself")
        await wait_for(pilot, lambda: shown(app, "magnetometer step is done"), 10, "the step's last words")
        await pilot.press("enter")
        await wait_for(pilot, lambda: isinstance(app.screen, LiveScreen), 10, "the live view")

    _drive(tmp_path, True, steps)
    cap = read_capture(tmp_path / "run-mag.csv")
    assert cap.mag is not None and len(cap) > 500
    corrected = nine_axis_unit(2).mag.correct(cap.mag)  # the simulated unit of seed 2
    assert abs(np.linalg.norm(corrected, axis=1).mean() - 50.0) < 0.2
    assert field_coverage(corrected).share >= 0.8


def test_a_unit_without_magnetometer_is_told_and_the_tui_goes_on(tmp_path: Path) -> None:
    async def steps(app: StationApp, pilot: Pilot) -> None:
        await pilot.press("m")
        await wait_for(pilot, lambda: "reports no magnetometer" in screen_text(app), 20, "the message")
        await pilot.press("l")
        await wait_for(pilot, lambda: isinstance(app.screen, LiveScreen), 10, "the live view")
        await wait_for(pilot, lambda: "accel" in screen_text(app), 20, "live values")

    _drive(tmp_path, False, steps)
    assert not (tmp_path / "run-mag.csv").exists()


def test_progress_thins_directions_and_finds_the_hard_iron() -> None:
    progress = MagProgress()
    rng = np.random.default_rng(1)
    n = 4000
    batch = np.zeros(n, MAG_SAMPLE_DTYPE)
    batch["t_us"] = np.arange(n) * 5000  # 200 Hz, 20 s
    direction = rng.normal(size=(n, 3))
    batch["mag"] = 48.0 * direction / np.linalg.norm(direction, axis=1)[:, None] + [12.0, -30.0, 7.0]
    progress.add(batch)
    coverage, now = progress.coverage()
    assert sum(len(r) for r in progress.readings) == pytest.approx(20 * 25, abs=2)
    m = np.concatenate(progress.readings)
    assert np.allclose(progress.centre(m), [12.0, -30.0, 7.0], atol=0.5)
    assert coverage.share > 0.95 and now is not None and abs(np.linalg.norm(now) - 48.0) < 1.0
    assert not progress.no_magnetometer


def test_hemispheres_drawing() -> None:
    up = disc_directions(7, lower=False)
    inside = np.isfinite(up[..., 0])
    assert np.allclose(np.linalg.norm(up[inside], axis=-1), 1.0) and (up[inside][:, 2] >= 0).all()
    assert up.shape == (7, 15, 3)
    hit = np.zeros(CELLS, bool)
    hit[0] = True  # the cap around +z
    text = hemispheres(hit, np.array([0.0, 0.0, -1.0])).plain.splitlines()
    centre = text[1 + 3]
    assert centre[7] == VISITED and centre[15 + 3 + 7] == NOW and MISSING in centre


def test_enter_finishes_early_once_the_calibration_can_use_the_coverage(tmp_path: Path) -> None:
    async def steps(app: StationApp, pilot: Pilot) -> None:
        screen = await _mag_step(app, pilot)
        screen.share = 0.05  # as if the unit had hardly moved: Enter is refused
        screen.action_finish()
        assert not screen.finished
        await wait_for(pilot, lambda: screen.share >= 0.2, 30, "a fifth of the sphere")
        await pilot.press("enter")
        await wait_for(pilot, lambda: screen.finished, 5, "the step to finish")
        # drawn a moment after the step finishes (a loaded machine shows the gap)
        text = await wait_for(pilot, lambda: shown(app, "Finished at"), 10, "the step's last words")
        assert "run-mag.csv" in text.replace("\n", "")  # a long temporary path wraps at 80 columns

    _drive(tmp_path, True, steps)
    assert read_capture(tmp_path / "run-mag.csv").mag is not None


def test_live_view_shows_the_field_of_a_nine_axis_unit(tmp_path: Path) -> None:
    async def steps(app: StationApp, pilot: Pilot) -> None:
        await pilot.press("enter")
        await wait_for(pilot, lambda: isinstance(app.screen, LiveScreen), 10, "the live view")
        await wait_for(pilot, lambda: "uT" in screen_text(app), 20, "the field's row")
        row = next(line for line in screen_text(app).splitlines() if "uT" in line)
        assert "mag" in row and row.count(".") >= 3

    _drive(tmp_path, True, steps)
