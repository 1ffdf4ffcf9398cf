"""``imu-station capture --instances``: a simulated board of three IMUs (``mocks.imu_board``) on a real pty,
over MAVLink SCALED_IMU/2/3 and over a frame description with ``imu:``, into one file per instance whose
values are the truth each instance sent; the note without ``--instances``; Ctrl-C and an unplugged board
keep every file's samples (skips without pymavlink)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_imu_instances import board_description

from drivers import open_device
from mocks.faults import FaultSpec
from mocks.imu_board import ImuBoard
from mocks.pty_server import PtyServer
from protocols.frame_description import describe
from station.acquisition.capture import read_capture
from station.acquisition.instance_capture import instance_path, parse_instances, record_instances
from station.cli import main

pytest.importorskip("pymavlink", reason="pymavlink is not installed")

from protocols.mavlink import MILLI_G  # noqa: E402

CLI = [sys.executable, "-m", "station"]


def located(got_t_us: np.ndarray, sent: np.ndarray, max_skipped: int = 40) -> np.ndarray:
    """The run of ``sent`` the capture holds: it starts within the first ``max_skipped`` and has no gap."""
    t_sent = sent["t_us"] // 1000 * 1000  # SCALED_IMU carries milliseconds
    k = int(np.searchsorted(t_sent, got_t_us[0]))
    assert k <= max_skipped
    run = sent[k : k + len(got_t_us)]
    assert (t_sent[k : k + len(got_t_us)] == got_t_us).all()
    return run


ACC_ATOL = MILLI_G / 2 + 1e-6  # SCALED_IMU carries milli-g
GYRO_ATOL = 0.5e-3 + 1e-7  # and mrad/s


def assert_file_is_the_instance(path: Path, sent: np.ndarray, instance: int, atol_acc: float = ACC_ATOL,
                                atol_gyro: float = GYRO_ATOL) -> int:
    cap = read_capture(path)
    t_us = np.round(cap.t * 1e6).astype(np.int64)
    run = located(t_us, sent)
    np.testing.assert_allclose(cap.acc, run["acc"], atol=atol_acc)
    np.testing.assert_allclose(cap.gyro, run["gyro"], atol=atol_gyro)
    assert str(cap.device["instance"]) == str(instance)
    return len(cap)


def test_instance_files_are_named_after_the_first() -> None:
    assert instance_path("cap.csv", 0) == Path("cap.csv")
    assert instance_path("out/cap.csv", 2) == Path("out/cap.imu2.csv")
    assert instance_path("board.h5", 1) == Path("board.imu1.h5")
    assert parse_instances("all") is None and parse_instances("0, 2") == (0, 2)
    for bad in ("x", "1,1", "256", "-1", ""):
        with pytest.raises(ValueError):
            parse_instances(bad)


def test_three_scaled_imu_instances_over_a_pty_into_three_files(tmp_path: Path, capsys) -> None:
    board = ImuBoard(seed=3, rate_hz=50.0)
    with PtyServer(board, record=True, speed=4.0) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "mavlink", "--instances", "all",
                     "--duration", "6", "-o", str(tmp_path / "board.csv")])
        sent = server.sent()
    out = capsys.readouterr()
    assert code == 0, out.err
    rows = []
    for k in range(3):
        path = instance_path(tmp_path / "board.csv", k)
        rows.append(assert_file_is_the_instance(path, sent[f"imu{k}"], k))
        assert f"IMU instance {k}: wrote {rows[-1]} samples" in out.out
    assert min(rows) >= 250 and max(rows) - min(rows) <= 2
    # three truths: the still board's mean specific force differs by each instance's own bias and scale
    means = [read_capture(instance_path(tmp_path / "board.csv", k)).acc.mean(axis=0) for k in range(3)]
    for k, truth in enumerate(board.truths):
        expected = truth.accel.matrix @ np.array([0.0, 0.0, 9.80665]) + truth.accel.bias
        np.testing.assert_allclose(means[k], expected, atol=0.05)
    assert np.abs(means[1] - means[0]).max() > 0.01


def test_a_frame_of_three_imus_over_a_pty_into_three_h5_files(tmp_path: Path, capsys) -> None:
    doc = board_description()
    for field in doc["fields"]:
        if field["name"] in ("gx", "gy", "gz"):
            field["scale"] = 1e-4
    desc_path = tmp_path / "tri.yaml"
    desc_path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    board = ImuBoard(seed=5, rate_hz=100.0, protocol=describe(doc))
    with PtyServer(board, record=True, speed=2.0) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", f"frame:{desc_path}",
                     "--instances", "1,2", "--duration", "3", "-o", str(tmp_path / "tri.h5")])
        sent = server.sent()
    assert code == 0, capsys.readouterr().err
    assert not (tmp_path / "tri.h5").exists()  # instance 0 was not asked for
    for k in (1, 2):
        n = assert_file_is_the_instance(instance_path(tmp_path / "tri.h5", k), sent[f"imu{k}"], k,
                                        atol_acc=0.005 + 1e-6, atol_gyro=5e-5 + 1e-7)
        assert n >= 250


def test_without_instances_instance_0_is_recorded_and_a_note_names_the_others(tmp_path: Path, capsys) -> None:
    with PtyServer(ImuBoard(seed=4), record=True, speed=4.0) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "mavlink", "--duration", "2",
                     "-o", str(tmp_path / "one.csv")])
        sent = server.sent()
    err = capsys.readouterr().err
    assert code == 0, err
    assert err.count("the board also streams IMU instances 1, 2: --instances all records them") == 1
    assert "instance" not in read_capture(tmp_path / "one.csv").device
    cap = read_capture(tmp_path / "one.csv")
    located(np.round(cap.t * 1e6).astype(np.int64), sent["imu0"])
    assert not instance_path(tmp_path / "one.csv", 1).exists()


def test_instances_of_a_protocol_of_one_imu_or_of_several_ports_are_refused(tmp_path: Path, capsys) -> None:
    assert main(["capture", "--port", "sim://", "--instances", "all", "-o", str(tmp_path / "x.csv")]) == 4
    assert "--instances: the native protocol carries one IMU" in capsys.readouterr().err
    assert main(["capture", "--port", "/dev/a", "--port", "/dev/b", "--instances", "all", "-o",
                 str(tmp_path)]) == 4
    assert "--instances records the IMUs of one board" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["capture", "--port", "sim://", "--instances", "0,x", "-o", str(tmp_path / "x.csv")])
    assert "'x' (in '0,x') is not an IMU instance" in capsys.readouterr().err


def test_an_instance_the_board_does_not_send_is_named(tmp_path: Path, capsys) -> None:
    with PtyServer(ImuBoard(seed=6, count=2), speed=4.0) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "mavlink", "--instances", "1,2",
                     "--duration", "1", "-o", str(tmp_path / "b.csv")])
    out = capsys.readouterr().out
    assert code == 0 and instance_path(tmp_path / "b.csv", 1).exists()
    assert "no file for IMU instance(s) 2: the board did not send them (it streams 0, 1)" in out


def test_an_unplugged_board_leaves_every_instance_its_samples(tmp_path: Path) -> None:
    faults = FaultSpec(disconnect_after_s=3.0)
    with PtyServer(ImuBoard(seed=7), faults=faults, record=True, speed=2.0) as server:
        with open_device(server.port_path, protocol="mavlink", instances=True) as dev:
            result = record_instances(dev, tmp_path / "lost.csv", handle_sigint=False)
        sent = server.sent()
    assert result.ended_by == "link error" and "went away" in str(result.error)
    assert sorted(result.captures) == [0, 1, 2]
    for k in range(3):
        n = assert_file_is_the_instance(instance_path(tmp_path / "lost.csv", k), sent[f"imu{k}"], k)
        assert n == result.captures[k].rows and len(sent) - n <= 40  # the kernel drops the pty's last blocks


def test_ctrl_c_mid_capture_keeps_every_files_samples(tmp_path: Path) -> None:
    path = tmp_path / "ctrl-c.csv"
    with PtyServer(ImuBoard(seed=8), record=True, speed=2.0) as server:
        proc = subprocess.Popen(CLI + ["capture", "--port", server.port_path, "--protocol", "mavlink",
                                       "--instances", "all", "-o", str(path)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 30
            # every file written and flushed (a second's flush) before the interrupt
            while not all(_rows_on_disk(instance_path(path, k)) >= 60 for k in range(3)):
                assert proc.poll() is None and time.monotonic() < deadline
                time.sleep(0.05)
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
        sent = server.sent()
    assert proc.returncode == 130, err
    assert "interrupted; the files keep every sample received" in err
    for k in range(3):
        n = assert_file_is_the_instance(instance_path(path, k), sent[f"imu{k}"], k)
        assert f"IMU instance {k}: wrote {n} samples" in out


def _rows_on_disk(path: Path) -> int:
    try:
        return sum(1 for line in path.read_text().splitlines() if line and not line.startswith(("#", "t")))
    except FileNotFoundError:
        return 0
