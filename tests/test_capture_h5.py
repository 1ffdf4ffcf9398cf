"""The HDF5 capture file: exact round trip, metadata, chunked resizable datasets, schema refusal."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from protocols.base import SAMPLE_DTYPE
from station.acquisition.capture import read_capture
from station.acquisition.capture_h5 import SCHEMA, H5CaptureWriter, read_h5, read_samples
from station.errors import InputFileError, OutputFileError

DEVICE = {"serial": "SIM-7", "model": "imu-sim", "firmware": "1.0.0", "rate_hz": 400}


def samples(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n) + 2**32 - 100  # wraps inside the capture
    s["t_us"] = 5_000_000 + np.arange(n) * 2500
    s["acc"] = rng.normal(0, 9.8, (n, 3))
    s["gyro"] = rng.normal(0, 2.0, (n, 3))
    s["temp"] = 30 + rng.normal(0, 1, n)
    return s


def write_capture(path: Path, s: np.ndarray, labels: list[str] | None = None, batch: int = 1000) -> None:
    w = H5CaptureWriter(path, device=DEVICE, with_step=labels is not None, port="/dev/pts/9",
                        protocol="native")
    for i in range(0, len(s), batch):
        w.write(s[i:i + batch], None if labels is None else labels[i:i + batch])
        w.flush({"samples": i + batch})
    w.close({"samples": len(s), "lost": 0})


def test_round_trip_is_bit_exact_with_metadata(tmp_path: Path) -> None:
    s = samples(5000)
    labels = ["+x"] * 2000 + [""] * 1000 + ["rot+z"] * 2000
    path = tmp_path / "cap.h5"
    write_capture(path, s, labels, batch=777)
    assert read_samples(path).tobytes() == s.tobytes()
    cap = read_capture(path)
    assert len(cap) == 5000
    assert np.array_equal(np.round(cap.t * 1e6).astype(np.uint64), s["t_us"])
    assert np.array_equal(cap.acc, s["acc"].astype(np.float64))
    assert np.array_equal(cap.temp, s["temp"].astype(np.float64))
    assert cap.step.tolist() == labels
    assert [lab for lab, _ in cap.segments()] == ["+x", "rot+z"]
    assert cap.device == DEVICE
    assert cap.link == {"samples": 5000, "lost": 0}
    with h5py.File(path) as f:
        assert f.attrs["schema"] == SCHEMA and f.attrs["schema_version"] == 1
        assert f.attrs["port"] == "/dev/pts/9" and f.attrs["protocol"] == "native"
        for name in ("seq", "t_us", "acc", "gyro", "temp", "step"):
            assert f[name].chunks is not None and f[name].maxshape[0] is None
        assert f["acc"].attrs["unit"] == "m/s^2"


def test_without_labels_there_is_no_step(tmp_path: Path) -> None:
    path = tmp_path / "cap.hdf5"
    write_capture(path, samples(10))
    assert read_h5(path).step is None


def test_flushed_data_is_readable_while_the_writer_is_open(tmp_path: Path) -> None:
    path = tmp_path / "live.h5"
    w = H5CaptureWriter(path, device=DEVICE)
    w.write(samples(300))
    w.flush({"samples": 300})
    # A second handle in this process (HDF5 shares the open file) sees what was flushed.
    with h5py.File(path, "r") as f:
        assert len(f["t_us"]) == 300 and json.loads(f.attrs["link"]) == {"samples": 300}
    w.close()


def test_unknown_schema_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "other.h5"
    write_capture(path, samples(10))
    with h5py.File(path, "r+") as f:
        f.attrs["schema"] = "imu-station/capture/2"
    with pytest.raises(InputFileError, match=r"column 'schema': has schema 'imu-station/capture/2'; "
                                             r"this station reads 'imu-station/capture/1'"):
        read_capture(path)
    with h5py.File(path, "r+") as f:
        del f.attrs["schema"]
    with pytest.raises(InputFileError, match="has schema None"):
        read_h5(path)


def test_damaged_files_are_refused_with_the_dataset_named(tmp_path: Path) -> None:
    path = tmp_path / "short.h5"
    write_capture(path, samples(10))
    with h5py.File(path, "r+") as f:
        f["gyro"].resize(9, axis=0)
    with pytest.raises(InputFileError, match=r"column 'gyro': dataset has 9 rows, t_us has 10"):
        read_h5(path)
    with h5py.File(path, "r+") as f:
        del f["gyro"]
    with pytest.raises(InputFileError, match=r"column 'gyro': lacks a required dataset"):
        read_h5(path)
    text = tmp_path / "text.h5"
    text.write_text("t,ax\n")
    with pytest.raises(InputFileError, match="is not a readable HDF5 file"):
        read_h5(text)
    with pytest.raises(InputFileError, match="does not exist"):
        read_h5(tmp_path / "none.h5")


def test_time_must_increase(tmp_path: Path) -> None:
    s = samples(10)
    s["t_us"][6] = s["t_us"][5]
    path = tmp_path / "t.h5"
    write_capture(path, s)
    with pytest.raises(InputFileError, match=r"column 't_us': t_us does not increase at row 6"):
        read_h5(path)


def test_writer_refuses_a_path_it_cannot_create(tmp_path: Path) -> None:
    with pytest.raises(OutputFileError, match="cannot be created"):
        H5CaptureWriter(tmp_path / "missing-dir" / "x.h5")
