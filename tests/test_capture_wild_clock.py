"""Wild device timestamps: one sample dated an hour ahead no longer ends a capture, a unit that
restarts its clock is bridged, and a capture that kept nothing says so. Through the clock guard
alone, through real ptys with the simulated unit (``record``), and through ``imu-station capture``.
"""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from clock_faults import HOUR_US, restarting_clock, wild_clock
from test_drivers_serial import RawPty

from drivers import NoSamples, open_device
from mocks.device import ENCODERS, SimDevice
from mocks.pty_server import PtyServer
from protocols import native
from protocols.base import SAMPLE_DTYPE
from station.acquisition.capture import read_capture
from station.acquisition.capture_h5 import read_samples
from station.acquisition.clock_guard import CONFIRM, ClockGuard
from station.acquisition.recorder import Recorder, record
from station.cli import main

WILD_SEQ = 200  # the sample dated an hour ahead: 1.0 s into a 200 Hz stream
WILD_EVERY = 400  # on the simulated unit, every 400th sample from WILD_SEQ on: 3 in any 6 s at 200 Hz
RESTART_SEQ = 600  # where the unit restarts: its clock and counter start again


@pytest.fixture(autouse=True)
def _faulty_clock_encoders(monkeypatch) -> None:
    """The two faulty clocks, registered only while a test of this file runs."""
    monkeypatch.setitem(ENCODERS, "native-wild-clock", wild_clock(WILD_EVERY, WILD_SEQ))
    monkeypatch.setitem(ENCODERS, "native-restart", restarting_clock(RESTART_SEQ))


def stream(n: int, rate_hz: float = 200.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = 17 + np.round(np.arange(n) * 1e6 / rate_hz).astype(np.uint64)
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25.0
    return s


def through_guard(samples: np.ndarray, batch: int = 37) -> tuple[ClockGuard, np.ndarray, np.ndarray]:
    guard = ClockGuard()
    outs = [guard.push(samples[i : i + batch]) for i in range(0, len(samples), batch)] + [guard.finish()]
    return (guard, np.concatenate([o.samples for o in outs]),
            np.concatenate([o.continuous_us for o in outs]))


# ------------------------------------------------------------------ the rule, on the guard alone


@pytest.mark.parametrize("batch", [1, 5, 37, 2000])
def test_an_isolated_outlier_is_left_out_and_counted_whatever_the_batches(batch: int) -> None:
    s = stream(1359)
    wild = s.copy()
    wild["t_us"][WILD_SEQ] += HOUR_US
    guard, got, continuous = through_guard(wild, batch)
    assert guard.outliers == 1 and not guard.jumps and guard.non_increasing == 0
    assert got.tobytes() == np.delete(s, WILD_SEQ).tobytes()
    assert continuous.tolist() == got["t_us"].astype(np.int64).tolist()


@pytest.mark.parametrize("offset_us", [HOUR_US, -1_000_000, 2**31 * 100, 300_000])
def test_outliers_ahead_or_behind_in_a_row_shorter_than_the_confirmation(offset_us: int) -> None:
    s = stream(500)
    wild = s.copy()
    rows = [100, 101, 300]  # two in a row agreeing with each other, then one alone
    wild["t_us"][rows] = (wild["t_us"][rows].astype(np.int64) + offset_us).astype(np.uint64)
    guard, got, _ = through_guard(wild, 64)
    assert guard.outliers == 3 and not guard.jumps
    assert got.tobytes() == np.delete(s, rows).tobytes()


def test_a_restart_is_a_jump_bridged_by_one_period_and_counted_once() -> None:
    s = stream(1000)
    s["t_us"][RESTART_SEQ:] -= RESTART_SEQ * 5000 - 1000
    s["seq"][RESTART_SEQ:] -= RESTART_SEQ
    guard, got, continuous = through_guard(s, 50)
    assert guard.outliers == 0 and len(guard.jumps) == 1 and len(got) == 1000
    jump = guard.jumps[0]
    # From the last sample before (t 17 + 599 periods) to 1 ms, one period being expected.
    assert jump.row == RESTART_SEQ and jump.step_s == pytest.approx(-(RESTART_SEQ * 0.005 - 0.001))
    assert "went back" in jump.describe() and f"row {RESTART_SEQ}" in jump.describe()
    steps = np.diff(got["t_us"].astype(np.int64))
    assert (steps == 5000).all()  # re-based: the new piece follows one period after the old one
    assert (np.diff(continuous) == 5000).all()
    np.testing.assert_array_equal(got["acc"], s["acc"])


def test_a_jump_ahead_that_the_samples_confirm_keeps_their_time_and_the_duration_skips_it() -> None:
    s = stream(400)
    s["t_us"][250:] += HOUR_US
    guard, got, continuous = through_guard(s, 64)
    assert len(guard.jumps) == 1 and guard.jumps[0].step_s == pytest.approx(3600.0)
    assert got.tobytes() == s.tobytes()  # time still increases: written as the unit sent it
    assert continuous[-1] - continuous[0] == 399 * 5000


def test_a_gap_of_lost_samples_that_seq_explains_is_no_jump() -> None:
    s = np.delete(stream(3000), np.arange(1000, 2500))  # 7.5 s lost on the link
    guard, got, continuous = through_guard(s, 100)
    assert not guard.jumps and guard.outliers == 0 and got.tobytes() == s.tobytes()
    assert continuous[-1] - continuous[0] == 2999 * 5000


def test_a_replayed_frame_is_still_left_out_as_not_increasing() -> None:
    s = stream(50)
    replayed = np.concatenate([s[:30], s[25:26], s[30:]])
    guard, got, _ = through_guard(replayed, 7)
    assert guard.non_increasing == 1 and guard.outliers == 0 and got.tobytes() == s.tobytes()


def test_a_wild_first_timestamp_does_not_anchor_the_line() -> None:
    s = stream(100)
    wild = s.copy()
    wild["t_us"][0] += HOUR_US
    guard, got, _ = through_guard(wild, 10)
    assert guard.outliers == 1 and not guard.jumps and got.tobytes() == s[1:].tobytes()


def test_at_the_end_unconfirmed_samples_are_outliers_and_a_short_stream_is_kept() -> None:
    s = stream(100)
    s["t_us"][-(CONFIRM - 1):] += HOUR_US
    guard, got, _ = through_guard(s, 100)
    assert guard.outliers == CONFIRM - 1 and len(got) == 100 - (CONFIRM - 1)
    short = stream(CONFIRM - 1)
    guard, got, _ = through_guard(short, 1)
    assert got.tobytes() == short.tobytes() and guard.outliers == 0


def test_text_lines_whose_seq_counts_samples_received() -> None:
    """ASCII and MAVLink number the samples they decode: seq always steps by one."""
    s = stream(600)
    s["t_us"][300] += 12_345_678
    s["seq"] = np.arange(600)
    guard, got, _ = through_guard(s, 20)
    assert guard.outliers == 1 and len(got) == 599


# ------------------------------------------------------------------ through a real pty


def test_record_over_a_pty_keeps_going_past_samples_an_hour_ahead(tmp_path: Path) -> None:
    """Before: --duration 6 returned at the first one (after 0.995 s of device clock), with exit 0."""
    path = tmp_path / "wild.h5"
    device = SimDevice(seed=3, rate_hz=200, encoder="native-wild-clock")
    with PtyServer(device, record=True, speed=5) as server, open_device(server.port_path) as dev:
        result = record(dev, path, duration_s=6.0)
        sent = server.sent()
    assert result.ended_by == "duration" and result.error is None
    got = read_samples(path)
    first = int(got["seq"][0])
    window = sent[first : first + 1200]  # 6 s of device clock from the first row
    expected = window[window["seq"] % WILD_EVERY != WILD_SEQ]
    assert len(expected) == 1197 == len(got) == result.rows
    assert got.tobytes() == expected.tobytes()
    assert 3 <= result.link.clock_outliers <= 4 and result.link.clock_jumps == 0
    assert f"{result.link.clock_outliers} clock outliers (left out)" in result.link.summary()
    assert read_capture(path).link["clock_outliers"] == result.link.clock_outliers


def test_record_without_a_duration_leaves_out_only_the_wild_sample(tmp_path: Path) -> None:
    """Before: 1,158 of 1,359 samples were left out as 'not increasing'."""
    pty = RawPty()
    s = stream(1359)
    wild = s.copy()
    wild["t_us"][WILD_SEQ] += HOUR_US
    stop = threading.Event()

    def feed() -> None:
        time.sleep(0.2)
        pty.write(native.encode_samples(wild))
        time.sleep(0.6)
        stop.set()

    threading.Thread(target=feed, daemon=True).start()
    try:
        with open_device(pty.path) as dev:
            result = record(dev, tmp_path / "wild.csv", stop=stop)
    finally:
        pty.close()
    assert result.rows == 1358 and result.non_increasing == 0 and result.link.clock_outliers == 1
    cap = read_capture(tmp_path / "wild.csv")
    np.testing.assert_array_equal(np.round(cap.t * 1e6).astype(np.uint64), np.delete(s, WILD_SEQ)["t_us"])


def test_record_over_a_pty_bridges_a_unit_restart_and_counts_duration_on_the_pieces(tmp_path: Path) -> None:
    path = tmp_path / "restart.h5"
    device = SimDevice(seed=4, rate_hz=200, encoder="native-restart")
    with PtyServer(device, record=True, speed=2) as server, open_device(server.port_path) as dev:
        result = record(dev, path, duration_s=4.0)
        sent = server.sent()
    assert result.ended_by == "duration" and result.error is None
    got = read_samples(path)
    first = int(got["seq"][0])
    assert first < RESTART_SEQ, "the capture must start before the unit restarts"
    assert result.rows == 800 and result.link.clock_jumps == 1 and result.link.clock_outliers == 0
    assert len(result.clock_jumps) == 1 and result.clock_jumps[0].step_s < -2.0
    assert result.clock_jumps[0].row == RESTART_SEQ - first
    assert (np.diff(got["t_us"].astype(np.int64)) == 5000).all()  # the new piece follows on
    np.testing.assert_array_equal(got["acc"], sent["acc"][first : first + 800])
    assert result.device_time_s == pytest.approx(3.995)


def test_capture_command_records_the_whole_duration_past_wild_timestamps(tmp_path: Path, capsys) -> None:
    out = tmp_path / "wild.csv"
    device = SimDevice(seed=5, rate_hz=200, encoder="native-wild-clock")
    with PtyServer(device, record=True, speed=5) as server:
        code = main(["capture", "--port", server.port_path, "--duration", "6", "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "wrote 1197 samples (5.99" in captured.out
    assert re.search(r"link: .*, [34] clock outliers \(left out\)", captured.out)
    assert len(read_capture(out)) == 1197


def test_capture_command_reports_a_unit_restart_and_goes_on(tmp_path: Path, capsys) -> None:
    out = tmp_path / "restart.csv"
    with PtyServer(SimDevice(seed=6, rate_hz=200, encoder="native-restart"), speed=2) as server:
        code = main(["capture", "--port", server.port_path, "--duration", "4", "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "wrote 800 samples (3.995 s of device clock)" in captured.out
    assert re.search(r"clock jump: the device clock went back 2\.\d+ s at row \d+ \(a unit restart\?\); "
                     r"the rows after it are re-based to follow on", captured.out)
    assert re.search(r"link: .*, 1 clock jump, \d+ bytes", captured.out)
    assert (np.diff(read_capture(out).t) > 0).all()


# ------------------------------------------------------------------ a capture that kept nothing


@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_a_capture_without_a_sample_leaves_no_file_and_says_so(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"empty{suffix}"
    pty = RawPty()
    try:
        with open_device(pty.path) as dev:
            result = record(dev, path, no_samples_timeout_s=0.3)
    finally:
        pty.close()
    assert isinstance(result.error, NoSamples) and result.rows == 0
    assert "no sample was captured, so no file was written" in str(result.error)
    assert not path.exists()


def test_a_capture_stopped_before_any_sample_says_it_got_none(tmp_path: Path) -> None:
    path = tmp_path / "stopped.csv"
    stop = threading.Event()
    stop.set()
    pty = RawPty()
    try:
        with open_device(pty.path) as dev:
            result = record(dev, path, stop=stop)
    finally:
        pty.close()
    assert isinstance(result.error, NoSamples) and not path.exists()
    assert "the capture ended before any sample was kept" in str(result.error)


def test_capture_command_on_a_silent_unit_exits_3_without_a_file(tmp_path: Path, capsys) -> None:
    out = tmp_path / "silent.csv"
    pty = RawPty()
    try:
        code = main(["capture", "--port", pty.path, "-o", str(out)])
    finally:
        pty.close()
    err = capsys.readouterr().err
    assert code == 3 and "no sample arrived" in err and "no file was written" in err
    assert not out.exists()


def test_samples_waiting_in_the_clock_guard_are_written_at_close(tmp_path: Path) -> None:
    s = stream(CONFIRM - 1)
    rec = Recorder(tmp_path / "cap.csv")
    assert rec.write(s) == 0  # too few yet to make a line
    rec.close()
    assert rec.rows == CONFIRM - 1 and len(read_capture(tmp_path / "cap.csv")) == CONFIRM - 1
