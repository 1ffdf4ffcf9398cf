"""In a real 80x24 terminal (tmux): every step's caption and the footer keys are on the screen, quitting
unsaved results asks first, and closing the terminal (SIGHUP) saves them to a file of their own."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from station.export.params.file import ParamsFile

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (apt-get install tmux)"),
]


def tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], check=True, capture_output=True, text=True).stdout


def _start(tmp_path: Path, out: Path) -> tuple[str, Path]:
    status = tmp_path / "exit-code"
    session = f"imu-{uuid.uuid4().hex[:8]}"
    station = Path(sys.executable).with_name("imu-station")
    command = (f"cd {tmp_path} && {station} tui --simulate --seed 9 --hold 1 --rotation-rate 360 --speed 4 "
               f"--out {out}; echo $? > {status}")
    tmux("new-session", "-d", "-s", session, "-x", "80", "-y", "24", command)
    return session, status


def _to_results(session: str, screens: list[str]) -> None:
    """Enter on every screen until the results show; every screen is kept in ``screens``."""
    deadline = time.monotonic() + 200
    while True:
        time.sleep(1.0)
        screen = tmux("capture-pane", "-p", "-t", session)
        screens.append(screen)
        if "PASS against" in screen or "FAIL against" in screen:
            return
        assert time.monotonic() < deadline, "no results; last screen:\n" + screen
        subprocess.run(["tmux", "send-keys", "-t", session, "Enter"], capture_output=True)


def _wait_file(path: Path, timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists() and time.monotonic() < deadline:
        time.sleep(0.2)


def test_80x24_shows_captions_and_keys_and_q_asks_before_losing_the_results(tmp_path):
    out = tmp_path / "unit.yaml"
    session, status = _start(tmp_path, out)
    screens: list[str] = []
    try:
        _to_results(session, screens)
        subprocess.run(["tmux", "send-keys", "-t", session, "q"], check=True)
        time.sleep(1.5)
        asked = tmux("capture-pane", "-p", "-t", session)
        assert "The calibration is not saved" in asked and "s: save" in asked, asked
        assert status.exists() is False
        subprocess.run(["tmux", "send-keys", "-t", session, "s"], check=True)
        _wait_file(status)
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True)
    assert status.read_text().strip() == "0"
    assert ParamsFile.load(out).device["serial"] == "SIM-000009"
    for screen in screens:
        assert len(screen.splitlines()) <= 24 and max(map(len, screen.splitlines())) <= 80
    pose = next(s for s in screens if "face up, lying flat" in s)
    assert "towards the table)" in pose and "⏎ next" in pose and "q quit" in pose.splitlines()[-1]
    turn = next(s for s in screens if "seen from above" in s)
    assert "at about 360 deg/s" in turn and "x abort" in turn.splitlines()[-1]
    results = screens[-1]
    keys = results.splitlines()[-1]  # Enter saves to --out: it does not quit (issue 31)
    assert "⏎ save " in keys and "save and quit" not in keys and "q quit" in keys


def test_closing_the_terminal_saves_unsaved_results_beside_out(tmp_path):
    out = tmp_path / "unit.yaml"
    session, status = _start(tmp_path, out)
    try:
        _to_results(session, [])
        subprocess.run(["tmux", "kill-session", "-t", session], check=True)  # SIGHUP to the TUI
        deadline = time.monotonic() + 15
        while not list(tmp_path.glob("unit-unsaved-*.yaml")) and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True)
    saved = list(tmp_path.glob("unit-unsaved-*.yaml"))
    assert len(saved) == 1 and not out.exists()
    assert ParamsFile.load(saved[0]).device["serial"] == "SIM-000009"
