"""A long capture CSV read by two processes gives exactly what one reader gives, and every problem in
the child's half is reported as one reader reports it (the file's own line numbers)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from station.acquisition import csv_halves
from station.acquisition.capture_csv import iter_csv_chunks
from station.errors import InputFileError

ROWS = 5000
CHUNK = 1000


@pytest.fixture(autouse=True)
def small_files_split(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(csv_halves, "MIN_BYTES", 1)  # a test file of 300 KB is split as a long record is


def capture(path: Path, rows: int = ROWS, tail: str = "") -> Path:
    rng = np.random.default_rng(3)
    values = rng.normal(size=(rows, 6))
    with path.open("w", encoding="utf-8") as fh:
        fh.write("# serial: SN-HALVES\n# rate_hz: 100\nt,ax,ay,az,gx,gy,gz\n")
        for k in range(rows):
            fh.write(f"{k / 100:.2f}," + ",".join(f"{v:.9g}" for v in values[k]) + "\n")
        fh.write(tail)
    return path


def one_reader(path: Path) -> list[np.ndarray]:
    chunks = [(c.t, c.acc, c.gyro) for c in iter_csv_chunks(path, CHUNK)]
    return [np.concatenate([c[k] for c in chunks]) for k in range(3)]


def two_readers(path: Path) -> list[np.ndarray]:
    chunks = list(csv_halves.iter_chunks(path, CHUNK))
    return [np.concatenate([c[k] for c in chunks]) for k in range(3)]


def test_two_processes_read_what_one_reads(tmp_path: Path) -> None:
    path = capture(tmp_path / "long.csv")
    split = csv_halves._split(path, CHUNK)
    assert split is not None and 0 < split[1] < ROWS and split[1] % CHUNK == 0
    for mine, one in zip(two_readers(path), one_reader(path), strict=True):
        np.testing.assert_array_equal(mine, one)
    # the child's half came back whole, as one chunk (read here, it would come in chunks of CHUNK rows)
    assert len(list(csv_halves.iter_chunks(path, CHUNK))) == split[1] // CHUNK + 1


def test_a_bad_value_in_the_second_half_names_the_files_own_line(tmp_path: Path) -> None:
    path = capture(tmp_path / "bad.csv")
    lines = path.read_text().splitlines(keepends=True)
    lines[4500] = lines[4500].replace(",", ",x", 1)  # a data row in the child's half
    path.write_text("".join(lines))
    with pytest.raises(InputFileError) as one:
        one_reader(path)
    with pytest.raises(InputFileError) as two:
        two_readers(path)
    assert str(two.value) == str(one.value) and "line 4501" in str(two.value)


def test_a_cut_last_line_is_left_out_with_one_warning_naming_it(tmp_path: Path) -> None:
    path = capture(tmp_path / "cut.csv", tail="50.00,0.1,0.2")
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        mine = two_readers(path)
    assert len(said) == 1 and "line 5004" in str(said[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = one_reader(path)
    for a, b in zip(mine, one, strict=True):
        np.testing.assert_array_equal(a, b)


def test_time_that_goes_back_across_the_split_is_refused_as_one_reader_refuses_it(tmp_path: Path) -> None:
    path = capture(tmp_path / "back.csv")
    offset, rows = csv_halves._split(path, CHUNK) or (0, 0)
    text = path.read_bytes()
    line = text[offset:text.index(b"\n", offset)]
    path.write_bytes(text[:offset] + b"0.00" + line[line.index(b","):] + text[text.index(b"\n", offset):])
    with pytest.raises(InputFileError) as one:
        one_reader(path)
    with pytest.raises(InputFileError) as two:
        two_readers(path)
    assert str(two.value) == str(one.value) and "does not increase" in str(two.value)


def test_short_or_compressed_files_are_read_by_one_process(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(csv_halves, "MIN_BYTES", 10**9)
    path = capture(tmp_path / "short.csv", rows=300)
    assert not csv_halves._parallel(path)
    for mine, one in zip(two_readers(path), one_reader(path), strict=True):
        np.testing.assert_array_equal(mine, one)
