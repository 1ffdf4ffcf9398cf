"""``imu-station simulate`` as a user runs it: a real process, a real pty, pyserial, Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import serial

from protocols import native
from protocols.native import NativeDecoder, encode_frame
from station.cli import main


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "station.cli", "simulate", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def wait_for_link(link: str, proc: subprocess.Popen, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while not os.path.lexists(link):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < end, "the simulator did not publish its port"
        time.sleep(0.05)


def test_simulate_serves_until_ctrl_c_then_prints_a_summary(tmp_path) -> None:
    link = str(tmp_path / "imu")
    proc = start("--seed", "7", "--rate", "250", "--link", link)
    try:
        wait_for_link(link, proc)
        with serial.Serial(link, timeout=0.05) as port:
            port.write(encode_frame(native.GET_INFO))
            decoder = NativeDecoder()
            info, samples = None, 0
            end = time.monotonic() + 5.0
            while time.monotonic() < end and (info is None or samples < 100):
                d = decoder.feed(port.read(4096))
                samples += len(d.samples)
                infos = [json.loads(m.payload) for m in d.messages if m.msg_id == native.DEVICE_INFO]
                info = infos[0] if infos else info
        assert info == {"serial": "SIM-000007", "model": "imu-sim-mems", "firmware": "1.0.0", "rate_hz": 250}
        assert samples >= 100
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("simulated unit SIM-000007 (imu-sim-mems), 250 Hz, scenario still")
    port_path = lines[1].removeprefix("port: ")
    assert port_path.startswith("/dev/pts/")
    assert f"link: {link} -> {port_path}" in lines
    assert "host opened the port 1 time(s); commands: GET_INFO x1" in out
    assert not os.path.lexists(link)  # removed at exit


def test_simulate_runs_for_a_duration_with_faults(capsys) -> None:
    args = ["simulate", "--duration", "1", "--faults", "drop=0.1,seed=3", "--scenario", "six-position"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "scenario six-position, faults drop=0.1,seed=3" in out
    assert "faults: 0 frames" in out  # no host opened the port: nothing reached the injector
    assert "host opened the port 0 time(s)" in out


def test_simulate_refuses_bad_options(tmp_path, capsys) -> None:
    assert main(["simulate", "--faults", "drop=2"]) == 4
    err = capsys.readouterr().err
    assert "--faults 'drop=2'" in err and "[0, 1]" in err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["simulate", "--link", str(blocker)]) == 4
    assert "not a symlink" in capsys.readouterr().err
    assert main(["simulate", "--rate", "0"]) == 4
    assert "--rate 0" in capsys.readouterr().err
