"""End to end over real pseudo-terminals: wire -> pyserial -> driver -> capture file, with faults.

Every sample in the file is compared with the frames that really left the far end intact: the
simulator's fault injector lists them, and the independent encoder below (written from the spec
with struct, not with ``protocols/``) knows which frames it sent whole.
"""

from __future__ import annotations

import os
import re
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from test_drivers_serial import RawPty

from drivers import open_device
from mocks.faults import FaultSpec
from mocks.pty_server import PtyServer
from protocols.base import SAMPLE_DTYPE
from station.acquisition.capture import read_capture
from station.acquisition.capture_h5 import read_samples
from station.acquisition.recorder import record

CLI = [str(Path(sys.executable).with_name("imu-station"))]


def intact_samples(server: PtyServer) -> np.ndarray:
    """The samples of the frames the fault injector left whole, in the order they were sent."""
    frames = server.injector.intact_frames()
    return np.frombuffer(b"".join(f[5:45] for f in frames), dtype=SAMPLE_DTYPE)


def locate_run(got: np.ndarray, expected: np.ndarray, max_skipped: int) -> int:
    """``got`` must be ``expected[k:k + len(got)]`` bit for bit; returns k."""
    assert len(got) > 0
    k = int(np.searchsorted(expected["t_us"], got["t_us"][0]))
    assert k <= max_skipped, f"the capture starts {k} good frames late"
    assert got.tobytes() == expected[k:k + len(got)].tobytes()
    return k


def test_simulator_with_faults_to_file_keeps_every_intact_frame(tmp_path: Path) -> None:
    faults = FaultSpec(garbage=0.02, bitflip=0.02, truncate=0.02, drop=0.01, stall=0.005, stall_s=0.1, seed=3)
    path = tmp_path / "faults.h5"
    with PtyServer(seed=7, rate_hz=500, faults=faults, record=True) as server:
        with open_device(server.port_path) as dev:
            result = record(dev, path, duration_s=2.0)
    assert result.ended_by == "duration" and result.error is None
    got = read_samples(path)
    expected = intact_samples(server)
    # Opening a port flushes what the OS buffered before: at most the first block may be missing.
    k = locate_run(got, expected, max_skipped=25)
    t0 = int(got["t_us"][0])
    assert int(got["t_us"][-1]) - t0 < 2_000_000
    follows = expected[k + len(got):]
    assert len(follows) == 0 or int(follows["t_us"][0]) - t0 >= 2_000_000  # nothing good left out at the end
    stats = result.link
    counts = server.injector.counts
    assert counts.bitflips > 0 and counts.truncated > 0 and counts.dropped > 0 and counts.garbage_runs > 0
    assert stats.crc_errors + stats.truncated + stats.length_errors > 0 and stats.lost > 0
    assert read_capture(path).link["lost"] == stats.lost


def run_cli(args: list[str], **kw) -> subprocess.Popen:
    return subprocess.Popen(CLI + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def wait_for_line(proc: subprocess.Popen, text: str, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stderr], [], [], 0.1)
        if ready:
            line = proc.stderr.readline()
            if text in line:
                return
            if not line and proc.poll() is not None:
                break
    raise AssertionError(f"'{text}' never appeared on stderr of {proc.args}")


def test_port_vanishing_mid_capture_exits_3_with_everything_received(tmp_path: Path) -> None:
    path = tmp_path / "lost.csv"
    # The link ends after ~2.5 s of samples sent to the host, however long the CLI takes to start.
    faults = FaultSpec(garbage=0.01, disconnect_after_bytes=60_000, seed=2)
    with PtyServer(seed=3, rate_hz=500, faults=faults, record=True) as server:
        proc = run_cli(["capture", "--port", server.port_path, "-o", str(path)])
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 3, err
    assert "the port went away" in err and "every sample received before was kept" in err
    cap = read_capture(path)
    got = np.zeros(len(cap), dtype=SAMPLE_DTYPE)
    got["t_us"] = np.round(cap.t * 1e6).astype(np.uint64)
    got["acc"], got["gyro"], got["temp"] = cap.acc, cap.gyro, cap.temp
    expected = intact_samples(server)
    k = int(np.searchsorted(expected["t_us"], got["t_us"][0]))
    assert k <= 25
    run = expected[k:k + len(got)].copy()
    run["seq"] = 0  # the CSV has no seq column
    assert got.tobytes() == run.tobytes()
    # The kernel drops what the pty still held when its master closed: at most the last blocks.
    assert len(expected) - k - len(got) <= 25
    assert f"wrote {len(got)} samples" in out
    status = next(line for line in err.splitlines() if line.startswith("capturing"))
    assert f"{len(got)} samples" in status and " errors" in status and " lost" in status


def test_ctrl_c_saves_everything_and_the_h5_file_is_flushed_while_capturing(tmp_path: Path) -> None:
    path = tmp_path / "ctrl-c.h5"
    with PtyServer(seed=4, rate_hz=500, record=True) as server:
        proc = run_cli(["capture", "--port", server.port_path, "-o", str(path)])
        wait_for_line(proc, "unit: imu-sim")
        time.sleep(2.5)
        os.kill(proc.pid, signal.SIGSTOP)  # freeze it between writes to look at the file it is writing
        try:
            with h5py.File(path, "r", locking=False) as f:
                flushed = len(f["t_us"])
        finally:
            os.kill(proc.pid, signal.SIGCONT)
        assert flushed >= 500  # at least a second of samples reached the file while capturing
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 130, err
    assert "interrupted; the file keeps every sample received" in err
    got = read_samples(path)
    assert len(got) >= flushed
    locate_run(got, server.sent(), max_skipped=25)
    assert read_capture(path).device["serial"] == server.device.info()["serial"]


def test_missing_port_is_a_clear_error_with_exit_code_3(tmp_path: Path) -> None:
    proc = run_cli(["capture", "--port", "/dev/imu-missing", "-o", str(tmp_path / "x.csv")])
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 3
    assert err.strip().splitlines()[-1] == (
        "imu-station capture: error: /dev/imu-missing: no such port; check the cable and the name "
        "(list the ports with `imu-station ports`)")
    assert not (tmp_path / "x.csv").exists()


# --- an independent implementation of the native protocol, from the spec, with struct ------------

def spec_crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit: poly 0x1021, init 0xFFFF, no reflection, no xorout."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def spec_frame(msg_id: int, payload: bytes) -> bytes:
    body = struct.pack("<BH", msg_id, len(payload)) + payload
    return b"\xa5\x5a" + body + struct.pack("<H", spec_crc16(body))


class IndependentUnit(threading.Thread):
    """Streams spec-built frames at 1 kHz on a pty, with faults; keeps the payloads sent whole."""

    def __init__(self, pty: RawPty, seconds: float, seed: int = 9):
        super().__init__(daemon=True)
        self.pty, self.seconds = pty, seconds
        self.rng = np.random.default_rng(seed)
        self.good: list[bytes] = []
        self.kinds: dict[str, int] = {}

    def payload(self, k: int, t_us: int) -> bytes:
        while True:  # any finite float32 bit pattern: sign, subnormals, extremes
            bits = self.rng.integers(0, 2**32, 7, dtype=np.uint64)
            values = bits.astype(np.uint32).view(np.float32)
            if np.all(np.isfinite(values)):
                return struct.pack("<IQ7I", (k + 4_294_967_000) % 2**32, t_us, *map(int, bits))

    def wire(self, k: int, t_us: int) -> bytes:
        frame = spec_frame(0x01, self.payload(k, t_us))
        u = self.rng.random()
        kind = ("bitflip" if u < 0.03 else "truncate" if u < 0.06 else "drop" if u < 0.08
                else "garbage" if u < 0.11 else "bad-length" if u < 0.12 else "info" if u < 0.13
                else "unknown-id" if u < 0.14 else "clean")
        self.kinds[kind] = self.kinds.get(kind, 0) + 1
        if kind == "bitflip":
            f = bytearray(frame)
            bit = int(self.rng.integers(len(f) * 8))
            f[bit // 8] ^= 1 << (bit % 8)
            return bytes(f)
        if kind == "truncate":
            return frame[: int(self.rng.integers(1, len(frame)))]
        if kind == "drop":
            return b""
        self.good.append(frame[5:45])
        if kind == "garbage":
            junk = bytes(self.rng.integers(0, 256, int(self.rng.integers(1, 40)), dtype=np.uint8))
            return junk + b"\xa5\x5a" + junk[:3] + frame
        if kind == "bad-length":
            return b"\xa5\x5a\x01\xff\xff" + frame
        if kind == "info":
            info = b'{"serial":"IND-1","model":"spec","firmware":"0","rate_hz":1000}'
            return spec_frame(0x02, info) + frame
        if kind == "unknown-id":
            return spec_frame(0x7E, b"\x00\x01\x02") + frame
        return frame

    def run(self) -> None:
        # Start when the host speaks (its GET_INFO): the port is open, nothing is flushed any more.
        select.select([self.pty.master], [], [], 20)
        t0 = time.monotonic()
        t_us = 86_400_000_000 + 123  # a day after power-up
        k = 0
        while k < self.seconds * 1000:
            block = b""
            for _ in range(10):
                t_us += 1000 + int(self.rng.integers(-20, 21))
                block += self.wire(k, t_us)
                k += 1
            self.pty.write(block)
            time.sleep(max(0.0, t0 + k / 1000 - time.monotonic()))


@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_independent_encoder_with_faults_every_good_frame_bit_exact(tmp_path: Path, suffix: str) -> None:
    pty = RawPty()
    unit = IndependentUnit(pty, seconds=4.0)
    unit.start()
    path = tmp_path / f"independent{suffix}"
    try:
        proc = run_cli(["capture", "--port", pty.path, "--duration", "2", "-o", str(path)])
        out, err = proc.communicate(timeout=30)
    finally:
        unit.join(10)
        pty.close()
    assert proc.returncode == 0, err
    assert all(unit.kinds.get(k, 0) > 0 for k in ("bitflip", "truncate", "drop", "garbage", "bad-length"))
    good = np.frombuffer(b"".join(unit.good), dtype=SAMPLE_DTYPE)
    expected = good[good["t_us"] - good["t_us"][0] < 2_000_000]
    if suffix == ".h5":
        assert read_samples(path).tobytes() == expected.tobytes()
    else:
        cap = read_capture(path)
        assert np.array_equal(np.round(cap.t * 1e6).astype(np.uint64), expected["t_us"])
        for name, column in (("acc", cap.acc), ("gyro", cap.gyro), ("temp", cap.temp)):
            assert column.astype(np.float32).tobytes() == expected[name].tobytes(), name


def test_demo_steps_capture_verify_and_report(tmp_path: Path) -> None:
    import io

    from station.commands import demo

    # The acquisition steps only: the whole demo runs in tests/test_demo.py.
    mine = (demo.start_simulated_unit, demo.capture_samples, demo.verify_capture, demo.report_link)
    steps = [(title, step) for title, step in demo.STEPS if step in mine]
    assert len(steps) == 4
    out = io.StringIO()
    # 4 s of device clock at x20: the capture takes a fifth of a second of wall clock.
    ctx = demo.DemoContext(out_dir=tmp_path / "demo", seconds=4.0, rate_hz=400, speed=20.0, out=out,
                           err=io.StringIO())
    demo.run_demo(ctx, steps)
    assert ctx.results["verified"] is True
    assert ctx.results["link"]["lost"] == 0 and ctx.results["link"]["errors"] == 0
    capture = read_capture(tmp_path / "demo" / "capture.h5")
    assert len(capture) == 1600 and np.all(np.round(np.diff(capture.t) * 1e6) == 2500)
    assert ctx.results["step_s"]["capture from it"] < 4.0
    assert not ctx.server.running  # the simulated unit was stopped at the end
    text = out.getvalue()
    assert "[4/4] report the link" in text and "all 1600 samples equal, bit for bit" in text
    assert re.search(r"^\s+capture\.h5\s*$", text, flags=re.M) and "device clock x20" in text


def test_capture_sets_the_rate_it_is_given(tmp_path: Path) -> None:
    import io

    from mocks import register_sim_url
    from station.acquisition.port_capture import capture_to_file

    register_sim_url()  # what --port sim:// does on the command line
    err = io.StringIO()
    path = tmp_path / "rate.h5"
    result = capture_to_file("sim://?seed=5&rate=200", path, duration_s=0.5, rate_hz=500, err=err)
    got = read_samples(path)
    assert result.error is None and "at 200 Hz" in err.getvalue()  # what the unit said before SET_RATE
    assert len(got) == 250 and np.all(np.diff(got["t_us"]) == 2000)  # only samples at the new rate
    assert read_capture(path).device["rate_hz"] == 500
