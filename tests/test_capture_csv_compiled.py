"""The compiled parse of a capture CSV's rows (``station/acquisition/_csv_kernel.py``) against the reader it
stands in for (``np.loadtxt``, line by line where a chunk fails): the same chunks, bit for bit, on real
recordings written as the station writes them and in other forms, and the same refusals and warnings,
naming the same line and column, whatever the file holds and wherever in it."""

from __future__ import annotations

import gzip
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from station.acquisition import capture_csv, csv_halves
from station.acquisition.capture_data import Capture
from station.errors import InputFileError

DATA = Path(__file__).parent / "data"
FIELDS = ("t", "acc", "gyro", "temp", "dtemp", "mag")


def _read(path: Path, compiled: bool, monkeypatch: pytest.MonkeyPatch, chunk_rows: int) -> list[Capture]:
    monkeypatch.setattr(capture_csv, "FAST_BYTES", 0 if compiled else 1 << 62)
    return list(capture_csv.iter_csv_chunks(path, chunk_rows))


def assert_same_chunks(path: Path, monkeypatch: pytest.MonkeyPatch, chunk_rows: int = 7_000) -> int:
    """Both readers give the same chunks, every array bit for bit; returns the rows."""
    fast = _read(path, True, monkeypatch, chunk_rows)
    slow = _read(path, False, monkeypatch, chunk_rows)
    assert [len(c) for c in fast] == [len(c) for c in slow]
    for a, b in zip(fast, slow, strict=True):
        for name in FIELDS:
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None) == (y is None), name
            if x is not None:
                assert x.dtype == y.dtype and x.shape == y.shape, name
                assert x.tobytes() == y.tobytes(), name  # bit for bit: -0.0 and NaN alike
        assert a.device == b.device and a.source == b.source
    return sum(len(c) for c in fast)


def _xsens() -> Capture:
    """imu_tk's Xsens session (raw counts, about 100 Hz) as a capture."""
    acc, gyro = (np.loadtxt(DATA / "xsens-imu_tk" / f"xsens_{n}.txt.gz") for n in ("acc", "gyro"))
    return Capture(acc[:, 0], acc[:, 1:], gyro[:, 1:])


def _ferraris() -> Capture:
    """imucal's Ferraris session (raw counts at 204.8 Hz) scaled to SI-like magnitudes, with a temperature."""
    with gzip.open(DATA / "imucal-ferraris" / "annotated_session.csv.gz", "rt") as fh:
        v = np.loadtxt(fh, delimiter=",", skiprows=1, usecols=range(1, 8))
    temp = 25.0 + np.sin(np.arange(len(v)) / 997.0) / 3.0
    t = np.arange(len(v)) / 204.8  # its sample numbers start again in each part
    return Capture(t, v[:, 1:4] * 9.80665 / 2048.0, np.radians(v[:, 4:7] / 16.4), temp)


@pytest.mark.parametrize("session", [_xsens, _ferraris], ids=["xsens-imu_tk", "imucal-ferraris"])
def test_real_recordings_written_by_the_station_read_alike(session: Callable[[], Capture], tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    capture = session()
    path = tmp_path / "session.csv"
    capture_csv.write_csv(path, capture)
    monkeypatch.setattr(capture_csv, "FAST_BYTES", 0)
    assert capture_csv.reads_compiled(path)
    assert assert_same_chunks(path, monkeypatch) == len(capture.t)


def _printed(capture: Capture, path: Path, row: Callable[[int], str], header: str = "t,ax,ay,az,gx,gy,gz",
             end: str = "\n") -> Path:
    with path.open("w", encoding="utf-8", newline="") as fh:
        fh.write("# serial: SN-COMPILED" + end + header + end)
        fh.writelines(row(k) + end for k in range(len(capture.t)))
    return path


@pytest.mark.parametrize("form", ["repr", "exponent", "crlf", "columns", "signs", "long", "gz"])
def test_real_values_printed_in_other_forms_read_alike(form: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    c = _ferraris()
    cols = np.column_stack([c.t, c.acc, c.gyro])
    path = tmp_path / "forms.csv"
    if form == "repr":  # the shortest repr: up to 17 significant digits
        _printed(c, path, lambda k: ",".join(repr(float(v)) for v in cols[k]))
    elif form == "exponent":  # %.6e, and np.savetxt's %.18e in the last chunks (19 digits: np.loadtxt's)
        _printed(c, path, lambda k: ",".join(f"{v:.18e}" if k > 8_000 else f"{v:.6e}" for v in cols[k]))
    elif form == "crlf":
        _printed(c, path, lambda k: ",".join(f"{v:.9g}" for v in cols[k]), end="\r\n")
    elif form == "columns":  # unknown columns (text among them), another order, a temperature of nan
        _printed(c, path, lambda k: (f"A-{k},{c.gyro[k, 2]:.9g},{c.t[k]:.6f},nan,{c.acc[k, 0]:.9g},x y z,"
                                     f"{c.acc[k, 1]:.9g},{c.acc[k, 2]:.9g},{c.gyro[k, 0]:.9g},"
                                     f"{c.gyro[k, 1]:.9g}"),
                 header="label,gz,t,temp,ax,note,ay,az,gx,gy")
    elif form == "signs":  # '+' signs, '.5' and '5.' forms, upper-case exponents, negative zeros
        _printed(c, path, lambda k: f"{c.t[k]:+.6f},+.5,5.,-0,-0.0,{c.gyro[k, 2]:+.4E},{-c.gyro[k, 0]:.3E}")
    elif form == "long":  # trailing zeros; the powers of ten at the ends; 2**53 + 1 in the last chunks
        _printed(c, path, lambda k: f"{c.t[k]:.17f},1000000000000000000000,{c.acc[k, 2]:.15f},1e22,1e-22,"
                                    f"{9007199254740993 if k > 8_000 else 9007199254740992},"
                                    f"{c.gyro[k, 1]:.3e}")
    else:
        plain = _printed(c, tmp_path / "plain.csv", lambda k: ",".join(f"{v:.9g}" for v in cols[k]))
        path = tmp_path / "forms.csv.gz"
        path.write_bytes(gzip.compress(plain.read_bytes()))
    assert assert_same_chunks(path, monkeypatch, chunk_rows=1_024) == len(c.t)
    # the loop read them (but the 17 digits of a shortest repr, np.loadtxt's from the first rows)
    monkeypatch.setattr(capture_csv, "FAST_BYTES", 0)
    assert capture_csv.reads_compiled(path) == (form != "repr")


def test_chunks_end_where_the_text_reader_ends_them_by_characters(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(capture_csv, "CHUNK_CHARS", 50_000)
    path = tmp_path / "chars.csv"
    capture_csv.write_csv(path, _xsens())
    assert assert_same_chunks(path, monkeypatch, chunk_rows=5_000) == 51_175


ROWS = 20_000


def _good_lines() -> list[str]:
    t = np.arange(ROWS) / 100.0
    rng = np.random.default_rng(5)
    v = rng.normal(size=(ROWS, 7))
    return [f"{t[k]:.2f}," + ",".join(f"{x:.9g}" for x in v[k]) + "\n" for k in range(ROWS)]


def _set(k: int, change: Callable[[str], str]) -> Callable[[list[str]], None]:
    def damage(lines: list[str]) -> None:
        lines[k] = change(lines[k])
    return damage


def _append(tail: str) -> Callable[[list[str]], None]:
    return lambda lines: lines.append(tail)


# Damage to the data rows, and what the text reader makes of it: refused, read with a warning, or read.
DAMAGE: dict[str, tuple[Callable[[list[str]], None], str]] = {
    "bad value": (_set(15_123, lambda ln: ln.replace(",", ",1x", 2)), "refused"),
    "short row": (_set(9_000, lambda ln: ln.rsplit(",", 3)[0] + "\n"), "refused"),
    "blank line": (_set(17_777, lambda ln: "\n"), "refused"),
    "infinity": (_set(11_000, lambda ln: ln.replace(",", ",inf,", 1).replace(",", "", 1)), "refused"),
    "nan required": (_set(4_099, lambda ln: "40.99,nan" + ln[ln.index(",", 6):]), "refused"),
    "time back": (_set(8_192, lambda ln: "1.00" + ln[ln.index(","):]), "refused"),
    "lone cr": (_set(6_000, lambda ln: ln.replace(",", "\r", 1)), "refused"),
    "not utf-8": (_set(14_500, lambda ln: ln.replace(",", ",\udcff", 1)), "refused"),
    "endless line": (_append("1" * (3 * capture_csv.MAX_LINE_CHARS)), "refused"),
    "cut last line": (_append("200.00,0.1,0.2"), "warned"),
    "a field too many": (_set(12_001, lambda ln: ln.rstrip("\n") + ",5\n"), "read"),
    "comment": (_set(13_000, lambda ln: ln.rstrip("\n") + " # note\n"), "read"),
    "blank in a field": (_set(16_000, lambda ln: ln.replace(",", ", ", 1)), "read"),
    "blank lines at the end": (_append("\n\n"), "read"),
    "last line without its end": (_append("200.00,1,2,3,4,5,6,7"), "read"),
}


def _outcome(path: Path, monkeypatch: pytest.MonkeyPatch, compiled: bool) -> tuple[object, ...]:
    """What the reader gives: the rows and warnings, or the refusal's text, line and column."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        try:
            chunks = _read(path, compiled, monkeypatch, 2_048)
        except InputFileError as exc:
            return "refused", str(exc), exc.line, exc.column, [str(w.message) for w in said]
    rows = np.concatenate([np.column_stack([c.t, c.acc, c.gyro, c.temp if c.temp is not None else c.t])
                           for c in chunks])
    return "read", rows.tobytes(), [len(c) for c in chunks], [str(w.message) for w in said]


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz"])
@pytest.mark.parametrize("damage", list(DAMAGE))
def test_every_refusal_and_warning_is_the_text_readers(damage: str, suffix: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    lines = _good_lines()
    change, expected = DAMAGE[damage]
    change(lines)
    path = tmp_path / f"damaged{suffix}"
    text = "# serial: SN-DAMAGED\nt,ax,ay,az,gx,gy,gz,temp\n" + "".join(lines)
    data = text.encode("utf-8", "surrogateescape")
    path.write_bytes(gzip.compress(data) if suffix == ".csv.gz" else data)
    fast, slow = _outcome(path, monkeypatch, True), _outcome(path, monkeypatch, False)
    assert fast == slow
    seen = fast[0] if fast[0] == "refused" else "warned" if fast[-1] else "read"
    assert seen == expected, fast[1] if seen == "refused" else fast[-1]


def test_long_files_the_loop_reads_are_read_by_one_process(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(csv_halves, "MIN_BYTES", 1)
    monkeypatch.setattr(capture_csv, "FAST_BYTES", 1)
    path = tmp_path / "station.csv"
    capture_csv.write_csv(path, _xsens())
    assert capture_csv.reads_compiled(path) and not csv_halves._parallel(path)
    # the same file with step labels, or with numbers of 19 digits, still goes to two processes
    labelled = tmp_path / "labelled.csv"
    c = _xsens()
    steps = np.full(len(c.t), "still", dtype=object)
    capture_csv.write_csv(labelled, Capture(c.t, c.acc, c.gyro, step=steps))
    long = _printed(c, tmp_path / "long.csv", lambda k: f"{c.t[k]:.18e},1,2,3,4,5,6")
    for path in (labelled, long):
        assert not capture_csv.reads_compiled(path) and csv_halves._parallel(path)
    monkeypatch.setattr(capture_csv, "FAST_BYTES", 1 << 62)
    assert not capture_csv.reads_compiled(tmp_path / "station.csv")


def test_the_parser_compiled_ahead_is_the_one_a_read_calls(tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """``./scripts/setup`` compiles the loop (``compile_now``) for the argument types a read passes: with a
    read before or after it, the loop has one compiled signature (another would make the first read after
    an install wait for the compiler)."""
    from station.acquisition import _csv_kernel

    _csv_kernel.compile_now()
    path = tmp_path / "cap.csv"
    capture_csv.write_csv(path, _xsens())
    assert assert_same_chunks(path, monkeypatch) > 0
    assert len(_csv_kernel.parse_rows.signatures) == 1
