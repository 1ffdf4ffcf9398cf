"""End to end in a real terminal: ``imu-station tui --simulate`` inside tmux, answered with Enter only."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from station.acquisition.capture import read_capture
from station.acquisition.sequences import builtin
from station.export.params.file import ParamsFile

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (apt-get install tmux)"),
]


def tmux(*args: str) -> str:
    return subprocess.run(["tmux", *args], check=True, capture_output=True, text=True).stdout


def test_whole_flow_in_tmux_answered_with_enter_only(tmp_path):
    out = tmp_path / "unit.yaml"
    status = tmp_path / "exit-code"
    session = f"imu-{uuid.uuid4().hex[:8]}"
    station = Path(sys.executable).with_name("imu-station")
    command = (f"{station} tui --simulate --seed 9 --hold 1 --rotation-rate 360 --speed 4 --out {out}; "
               f"echo $? > {status}")
    tmux("new-session", "-d", "-s", session, "-x", "120", "-y", "42", command)
    screens: list[str] = []
    try:
        deadline = time.monotonic() + 240
        while not status.exists():
            last = screens[-1] if screens else ""
            assert time.monotonic() < deadline, "the TUI did not finish; last screen:\n" + last
            time.sleep(1.5)
            try:
                screens.append(tmux("capture-pane", "-p", "-t", session))
            except subprocess.CalledProcessError:
                break  # the pane closed: the command ended
            # The only key anyone presses: Enter, whatever the screen shows.
            subprocess.run(["tmux", "send-keys", "-t", session, "Enter"], capture_output=True)
        deadline = time.monotonic() + 10
        while not status.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        subprocess.run(["tmux", "kill-session", "-t", session], capture_output=True)
    assert status.read_text().strip() == "0"
    seen = "\n".join(screens)
    for landmark in ("imu-station · connect", "imu-station · live", "Place the unit with", "turn +360 deg",
                     "imu-station · results", "PASS"):
        assert landmark in seen, f"never saw {landmark!r} on the terminal"
    params = ParamsFile.load(out)
    assert params.device["serial"] == "SIM-000009"
    assert np.allclose(params.accel.matrix, np.eye(3), atol=0.05)
    assert np.allclose(params.gyro.matrix, np.eye(3), atol=0.05)
    capture = read_capture(tmp_path / "unit-capture.csv")
    assert [label for label, _ in capture.segments()] == builtin("six-position").labels
