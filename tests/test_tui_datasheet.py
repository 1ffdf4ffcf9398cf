"""The TUI's datasheet (``d``): the figures of ``--out`` with the scale factor across temperature and the
campaign's turn-ons per soak plotted, with or without a unit connected; through textual's Pilot at
80x24 and 160x48 (snapshots) and in a real terminal (tmux) at 80x24."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest
from across_temperature_params import campaign_file
from serial.tools import list_ports
from test_tui_ports import _ports
from tui_helpers import expect_snapshot, screen_text, wait_for

from station.tui.app import StationApp
from station.tui.config import TuiConfig

pytestmark = pytest.mark.timeout(180)


@pytest.fixture(autouse=True)
def fixed_ports(monkeypatch):
    """The same serial ports on every machine (the connect screen the datasheet returns to)."""
    monkeypatch.setattr(list_ports, "comports", _ports)


def test_datasheet_without_a_unit_plots_both_triads_and_goes_back(tmp_path) -> None:
    out = campaign_file(tmp_path / "unit.yaml")
    app = StationApp(TuiConfig(out=out))

    async def run() -> None:
        async with app.run_test(size=(160, 48)) as pilot:
            await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 10, "connect")
            await pilot.press("d")
            await wait_for(pilot, lambda: "scale-factor temperature coefficient" in screen_text(app), 10,
                           "the datasheet")
            text = screen_text(app)
            assert "gyroscope: scale factor change" in text and "gyroscope: turn-on repeatability" in text
            assert "gyro turn-on bias repeatability at -20 degC" in text
            assert "bias hysteresis (up - down)" in text
            await pilot.press("s")
            await wait_for(pilot, lambda: "accelerometer: turn-on repeatability" in screen_text(app), 5,
                           "the accelerometer's plots")
            # The accelerometer was not calibrated across temperature here: the plot says so.
            assert "accelerometer: no calibration across temperature to plot" in screen_text(app)
            await pilot.press("escape")
            await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 5, "connect again")
            app.exit(0)

    asyncio.run(run())


def test_datasheet_of_a_missing_file_says_what_to_do(tmp_path) -> None:
    app = StationApp(TuiConfig(out=tmp_path / "none.yaml"))

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 10, "connect")
            await pilot.press("d")
            await wait_for(pilot, lambda: "does not exist yet" in screen_text(app), 5, "the advice")
            assert "gyroscope: no calibration across temperature to plot" in screen_text(app)
            app.exit(0)

    asyncio.run(run())


@pytest.mark.parametrize("size", [(80, 24), (160, 48)])
def test_datasheet_snapshots(tmp_path, size, monkeypatch) -> None:
    campaign_file(tmp_path / "unit.yaml")
    monkeypatch.chdir(tmp_path)  # the screen names --out as given: the same on every run and worker
    app = StationApp(TuiConfig(out=Path("unit.yaml")))

    async def run() -> None:
        async with app.run_test(size=size) as pilot:
            await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 10, "connect")
            await pilot.press("d")
            await wait_for(pilot, lambda: "datasheet" in screen_text(app), 10, "the datasheet")
            await expect_snapshot(pilot, app, f"datasheet_{size[0]}x{size[1]}")
            footer = screen_text(app).splitlines()[-1]
            for key in ("back", "gyro/accel", "read again"):
                assert key in footer, footer
            app.exit(0)

    asyncio.run(run())


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (apt-get install tmux)")
def test_datasheet_in_a_real_terminal_at_80x24(tmp_path) -> None:
    out = campaign_file(tmp_path / "unit.yaml")
    status = tmp_path / "exit-code"
    session = f"imu-{uuid.uuid4().hex[:8]}"
    station = Path(sys.executable).with_name("imu-station")
    subprocess.run(["tmux", "new-session", "-d", "-s", session, "-x", "80", "-y", "24",
                    f"{station} tui --out {out}; echo $? > {status}"], check=True)

    def pane() -> str:
        return subprocess.run(["tmux", "capture-pane", "-p", "-t", session], capture_output=True,
                              text=True).stdout

    def until(words: str, what: str) -> str:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            text = pane()
            if words in text:
                return text
            time.sleep(0.2)
        raise AssertionError(f"never saw {what}; the terminal shows:\n{pane()}")

    try:
        until("imu-station · connect", "the connect screen")
        subprocess.run(["tmux", "send-keys", "-t", session, "d"], check=True)
        text = until("imu-station · datasheet", "the datasheet")
        text = until("scale factor change", "the scale plot")
        assert all(len(line) <= 80 for line in text.splitlines())
        subprocess.run(["tmux", "send-keys", "-t", session, "q"], check=True)
        deadline = time.monotonic() + 30
        while not status.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True)
    assert status.read_text().strip() == "0"
