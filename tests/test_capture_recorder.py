"""The capture loop over a real pty: duration on the device clock, link loss, stop, labels, ordering."""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fs_helpers import mount_tmpfs
from test_drivers_serial import RawPty, make_samples

from drivers import NoSamples, PortLost, open_device
from protocols.native import encode_samples
from station.acquisition.capture import read_capture
from station.acquisition.capture_h5 import read_samples
from station.acquisition.recorder import Recorder, record
from station.errors import OutputFileError


@pytest.fixture
def pty():
    p = RawPty()
    yield p
    p.close()


def feed_later(pty: RawPty, data: bytes, delay_s: float = 0.2,
               then_vanish_s: float | None = None) -> threading.Thread:
    def run() -> None:
        time.sleep(delay_s)
        pty.write(data)
        if then_vanish_s is not None:
            time.sleep(then_vanish_s)
            pty.vanish()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_duration_counts_device_time_and_the_file_holds_link_stats(pty: RawPty, tmp_path: Path) -> None:
    sent = make_samples(3000)  # 3 s of device clock at 1 kHz, sent in one burst
    path = tmp_path / "cap.h5"
    with open_device(pty.path) as dev:
        feed_later(pty, encode_samples(sent))
        statuses = []
        result = record(dev, path, duration_s=1.0, on_status=lambda *a: statuses.append(a),
                        status_interval_s=0)
    assert result.ended_by == "duration" and result.error is None
    assert result.rows == 1000  # t - t0 < 1.000000 s exactly
    assert read_samples(path).tobytes() == sent[:1000].tobytes()
    cap = read_capture(path)
    assert cap.link["samples"] >= 1000 and cap.link["lost"] == 0 and cap.link["errors"] == 0
    assert statuses and statuses[-1][1] == 1000


def test_port_lost_mid_capture_keeps_every_sample_received(pty: RawPty, tmp_path: Path) -> None:
    sent = make_samples(700, seed=4)
    path = tmp_path / "cap.csv"
    with open_device(pty.path) as dev:
        feed_later(pty, encode_samples(sent), then_vanish_s=0.3)
        result = record(dev, path)
    assert result.ended_by == "link error" and isinstance(result.error, PortLost)
    cap = read_capture(path)
    assert len(cap) == 700 == result.rows
    assert np.array_equal(cap.acc.astype(np.float32), sent["acc"])
    assert np.array_equal(np.round(cap.t * 1e6).astype(np.uint64), sent["t_us"])


def test_stop_event_ends_the_capture(pty: RawPty, tmp_path: Path) -> None:
    stop = threading.Event()
    with open_device(pty.path) as dev:
        feed_later(pty, encode_samples(make_samples(50)))
        threading.Timer(0.6, stop.set).start()
        result = record(dev, tmp_path / "cap.csv", stop=stop)
    assert result.ended_by == "stopped" and result.rows == 50


def test_a_silent_port_ends_with_no_samples(pty: RawPty, tmp_path: Path) -> None:
    with open_device(pty.path) as dev:
        result = record(dev, tmp_path / "cap.csv", no_samples_timeout_s=0.3)
    assert isinstance(result.error, NoSamples)
    assert "no sample arrived in 0.3 s" in str(result.error) and result.rows == 0


def test_samples_whose_time_does_not_increase_are_left_out(tmp_path: Path) -> None:
    s = make_samples(10)
    replayed = np.concatenate([s[:6], s[4:5], s[6:]])  # frame 4 comes again
    rec = Recorder(tmp_path / "cap.csv")
    assert rec.write(replayed[:3]) == 3
    assert rec.write(replayed[3:]) == 7
    rec.close()
    assert rec.non_increasing == 1
    assert len(read_capture(tmp_path / "cap.csv")) == 10


@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_rows_carry_the_step_label_current_when_written(tmp_path: Path, suffix: str) -> None:
    s = make_samples(30)
    rec = Recorder(tmp_path / f"cap{suffix}", with_step=True)
    rec.step = "+z"
    rec.write(s[:10])
    rec.step = ""
    rec.write(s[10:15])
    rec.step = "rot+z"
    rec.write(s[15:])
    rec.close()
    cap = read_capture(tmp_path / f"cap{suffix}")
    assert cap.step.tolist() == ["+z"] * 10 + [""] * 5 + ["rot+z"] * 15


@pytest.fixture
def small_fs(tmp_path: Path):
    """A real 8 MiB tmpfs that the capture fills (needs the right to mount: root in CI containers)."""
    mnt = tmp_path / "small"
    mount_tmpfs(mnt, "8m")
    yield mnt
    subprocess.run(["umount", "--lazy", str(mnt)], check=True)


@pytest.mark.parametrize("suffix", [".h5", ".csv"])
def test_a_filling_disk_stops_the_capture_with_a_complete_file(small_fs: Path, suffix: str) -> None:
    path = small_fs / f"cap{suffix}"
    s = make_samples(400_000)
    rec = Recorder(path)
    full = r"the disk is almost full .* the capture stopped at \d+ samples and the file is complete"
    with pytest.raises(OutputFileError, match=full) as exc:
        for i in range(0, len(s), 5000):
            rec.write(s[i:i + 5000])
    rec.close()
    kept = rec.rows
    assert 0 < kept < len(s) and f"stopped at {kept} samples" in str(exc.value)
    if suffix == ".h5":
        assert read_samples(path).tobytes() == s[:kept].tobytes()
    else:
        cap = read_capture(path)
        assert len(cap) == kept and np.array_equal(cap.acc.astype(np.float32), s["acc"][:kept])
