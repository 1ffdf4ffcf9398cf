"""Capture CSV: the spec's rules on malformed input, round trips of the streaming writer, disk full."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from fs_helpers import mount_tmpfs

from protocols.base import SAMPLE_DTYPE
from station.acquisition.capture import read_capture
from station.acquisition.capture_csv import CsvCaptureWriter, iter_csv_chunks, read_csv
from station.errors import InputFileError, OutputFileError

GOOD_HEADER = "t,ax,ay,az,gx,gy,gz,temp"


def samples(n: int, seed: int = 0, t0_us: int = 1_000_017) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = t0_us + np.arange(n) * 2500
    s["acc"] = rng.normal(0, 9.8, (n, 3))
    s["gyro"] = rng.normal(0, 2.0, (n, 3))
    s["temp"] = 20 + rng.normal(0, 5, n)
    return s


def write(tmp_path: Path, text: str, name: str = "bad.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def refusal(path: Path, chunk_rows: int = 200_000) -> InputFileError:
    with pytest.raises(InputFileError) as exc:
        list(iter_csv_chunks(path, chunk_rows=chunk_rows))
    return exc.value


def test_missing_required_column_names_file_line_and_column(tmp_path: Path) -> None:
    p = write(tmp_path, "t,ax,ay,az,gx,gy,temp\n0,0,0,9.8,0,0,25\n")
    err = refusal(p)
    assert (err.line, err.column) == (1, "gz")
    assert str(err).startswith(f"{p}, line 1, column 'gz': header lacks the required column")


def test_non_numeric_value_names_file_line_and_column(tmp_path: Path) -> None:
    rows = [f"{i * 0.01:.2f},0,0,9.8,0,0,0,25" for i in range(6)]
    rows[3] = "0.03,0,abc,9.8,0,0,0,25"
    p = write(tmp_path, GOOD_HEADER + "\n" + "\n".join(rows) + "\n")
    err = refusal(p)
    assert (err.line, err.column) == (5, "ay")
    assert "value 'abc' is not a number" in str(err) and str(p) in str(err)


def test_non_increasing_t_names_the_line_even_across_chunks(tmp_path: Path) -> None:
    ts = [0.0, 0.01, 0.02, 0.03, 0.03, 0.05]
    p = write(tmp_path, GOOD_HEADER + "\n" + "".join(f"{t},0,0,9.8,0,0,0,25\n" for t in ts))
    for chunk_rows in (2, 4, 100):  # the repeated t falls on a chunk border for chunk_rows=4
        err = refusal(p, chunk_rows)
        assert (err.line, err.column) == (6, "t")
        assert "does not increase" in str(err)


def test_non_finite_required_value_and_short_row_are_refused(tmp_path: Path) -> None:
    p = write(tmp_path, GOOD_HEADER + "\n0,0,0,9.8,0,0,0,25\n0.1,nan,0,9.8,0,0,0,25\n")
    err = refusal(p)
    assert (err.line, err.column) == (3, "ax") and "not a finite number" in str(err)
    p = write(tmp_path, GOOD_HEADER + "\n0,0,0,9.8,0,0,0,25\n0.1,0,0,9.8\n", "short.csv")
    err = refusal(p)
    assert err.line == 3 and err.column == "gx"


def test_empty_and_missing_files_are_refused(tmp_path: Path) -> None:
    assert refusal(write(tmp_path, "")).line == 1
    with pytest.raises(InputFileError, match="does not exist"):
        read_csv(tmp_path / "nothing.csv")
    with pytest.raises(InputFileError, match="no sample rows"):
        read_csv(write(tmp_path, GOOD_HEADER + "\n", "header-only.csv"))


def test_columns_in_any_order_unknown_ignored_optional_absent(tmp_path: Path) -> None:
    p = write(tmp_path, "gz,note,t,ay,ax,gx,az,gy\n3,x,0.5,2,1,4,9.5,5\n6,y,0.75,2,1,4,9.5,5\n")
    cap = read_csv(p)
    assert cap.t.tolist() == [0.5, 0.75]
    assert cap.acc[0].tolist() == [1, 2, 9.5] and cap.gyro[1].tolist() == [4, 5, 6]
    assert cap.temp is None and cap.dtemp is None and cap.step is None


def test_streaming_writer_round_trip_is_exact(tmp_path: Path) -> None:
    s = samples(3000, seed=1)
    path = tmp_path / "cap.csv"
    w = CsvCaptureWriter(path, with_step=True)
    labels = np.array(["+z"] * 1000 + [""] * 500 + ["rot+x:180"] * 1500, dtype=object)
    for i in range(0, len(s), 700):  # batches of any size
        w.write(s[i:i + 700], step=labels[i:i + 700])
    w.flush()
    w.close()
    assert w.rows == 3000
    cap = read_capture(path)
    # t is the device clock in seconds, exact to the microsecond; values are float32-exact.
    assert np.array_equal(np.round(cap.t * 1e6).astype(np.uint64), s["t_us"])
    assert np.array_equal(cap.acc.astype(np.float32), s["acc"])
    assert np.array_equal(cap.gyro.astype(np.float32), s["gyro"])
    assert np.array_equal(cap.temp.astype(np.float32), s["temp"])
    assert cap.step.tolist() == labels.tolist()
    assert [lab for lab, _ in cap.segments()] == ["+z", "rot+x:180"]


def test_writer_refuses_a_path_it_cannot_create(tmp_path: Path) -> None:
    with pytest.raises(OutputFileError, match="cannot be created"):
        CsvCaptureWriter(tmp_path / "no-such-dir" / "cap.csv")


@pytest.fixture
def tiny_fs(tmp_path: Path):
    """A real 64 KiB tmpfs, so the disk really fills (needs the right to mount: root in CI containers)."""
    mnt = tmp_path / "tiny"
    mount_tmpfs(mnt, "64k")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=True)


def test_disk_full_keeps_whole_batches_and_says_so(tiny_fs: Path) -> None:
    path = tiny_fs / "cap.csv"
    s = samples(5000, seed=2)
    w = CsvCaptureWriter(path)
    written = 0
    with pytest.raises(OutputFileError, match=r"No space left on device.*keeps the first \d+ samples") as exc:
        for i in range(0, len(s), 100):
            w.write(s[i:i + 100])
            written += 100
    assert f"keeps the first {written} samples" in str(exc.value)
    assert 0 < written < 5000
    cap = read_csv(path)  # still a valid capture: only whole batches remain
    assert len(cap) == written
    assert np.array_equal(cap.acc.astype(np.float32), s["acc"][:written])
    w.close()
