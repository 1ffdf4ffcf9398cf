"""The text decoder's batches (every dialect parsed in arrays, issue 30) give what reading the lines
one at a time gives: the same samples (values and dtype of every ``feed``), counters, line kinds and
messages, on clean, damaged and spliced streams cut at many chunk sizes.

Two references: the decoder with its batches turned off (every line through ``_line``, always
available), and the decoder as it was before the batches (``protocols/ascii_lines.py`` of commit
c19b3a0, read from git when the repository's history is there).
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protocols import ascii_lines
from protocols.ascii_lines import AsciiDecoder
from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, Message
from protocols.mag_batches import with_mag

ROOT = Path(__file__).resolve().parent.parent
BEFORE = "c19b3a0"
MAG_COLUMNS = "t,ax,ay,az,gx,gy,gz,temp,mx,my,mz"
SEQ_COLUMNS = "seq,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps,_"


class _OneByOne(AsciiDecoder):
    """Every line alone, through ``_line``."""

    def _batched(self, rows: list[tuple], messages: list[Message]) -> tuple[int, list[np.ndarray], bool]:
        return 0, [], False


def _previous_module():
    try:
        source = subprocess.run(["git", "show", f"{BEFORE}:protocols/ascii_lines.py"], cwd=ROOT,
                                capture_output=True, check=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    spec = importlib.util.spec_from_loader("_ascii_lines_before", loader=None)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["_ascii_lines_before"] = module
    exec(compile(source, "ascii_lines_before.py", "exec"), module.__dict__)  # noqa: S102
    return module


PREVIOUS = _previous_module()


def _samples(n: int, seed: int, mag: bool) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.zeros(n, dtype=MAG_SAMPLE_DTYPE if mag else SAMPLE_DTYPE)
    out["seq"] = np.arange(n) + 3
    out["t_us"] = 1_000_000 + np.arange(n) * 2500
    out["acc"] = rng.normal(0, 5, (n, 3))
    out["gyro"] = rng.normal(0, 1, (n, 3))
    out["temp"] = 25 + rng.normal(0, 1, n)
    if mag:
        out["mag"] = rng.normal(0, 40, (n, 3))
        out["mag"][::7] = np.nan  # a mag column that holds nan
    return out


def _stream(kind: str, n: int, seed: int) -> bytes:
    six, nine = _samples(n, seed, False), _samples(n, seed, True)
    if kind == "csv":
        return ascii_lines.encode_csv(six)
    if kind == "csv-mag":
        return ascii_lines.encode_csv(nine, MAG_COLUMNS)
    if kind == "csv-seq":
        return ascii_lines.encode_csv(six, SEQ_COLUMNS)
    if kind == "raw":
        return ascii_lines.encode_motioncal(nine)
    if kind == "uni":
        return "".join(f"Uni:{a[0]:.4f},{a[1]:.4f},{a[2]:.4f},{g[0]:.5f},{g[1]:.5f},{g[2]:.5f},{m[0]:.2f},"
                       f"{m[1]:.2f},{m[2]:.2f}\n" for a, g, m in zip(nine["acc"], nine["gyro"], nine["mag"],
                                                                     strict=True)).encode()
    if kind == "vnymr":
        return ascii_lines.encode_vectornav(nine, "VNYMR")
    if kind == "vnimu":
        return ascii_lines.encode_vectornav(six, "VNIMU")
    if kind == "vnymr-crc16":
        return ascii_lines.encode_vectornav(nine, "VNYMR", crc16=True)
    raise AssertionError(kind)


KINDS = ("csv", "csv-mag", "csv-seq", "raw", "uni", "vnymr", "vnimu", "vnymr-crc16")
COLUMNS = {"csv": ascii_lines.DEFAULT_COLUMNS, "csv-mag": MAG_COLUMNS, "csv-seq": SEQ_COLUMNS}


def _damaged(data: bytes, seed: int, every: int = 10) -> bytes:
    """A byte flipped in the middle of one line in ``every`` (as benchmarks/decoders.py), and a few
    random flips, drops and doubled bytes."""
    out = np.frombuffer(data, dtype=np.uint8).copy()
    starts = np.flatnonzero(np.frombuffer(b"\n" + data[:-1], np.uint8) == 10)
    ends = np.append(starts[1:], len(data))
    out[((starts + ends) // 2)[::every]] ^= 0x5A
    rng = np.random.default_rng(seed)
    b = bytearray(out.tobytes())
    for _ in range(max(1, len(b) // 500)):
        at = int(rng.integers(0, len(b)))
        op = int(rng.integers(0, 3))
        if op == 0:
            b[at] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            del b[at]
        else:
            b[at:at] = b[at : at + 1]
    return bytes(b)


def _spliced(seed: int, columns: str) -> bytes:
    """Dialects one after the other and mixed, with text lines, an over-long line, glued starts, blank
    lines and bare CR / LF ends."""
    rng = np.random.default_rng(seed)
    csv_kind = {ascii_lines.DEFAULT_COLUMNS: "csv", MAG_COLUMNS: "csv-mag", SEQ_COLUMNS: "csv-seq"}[columns]
    parts = [b"# imu board v1.2\r\n", b"t,ax,ay,az,gx,gy,gz,temp\r\n"]
    for i in range(12):
        kind = [csv_kind, "raw", "uni", "vnymr", "vnimu", "vnymr-crc16"][int(rng.integers(0, 6))]
        block = _stream(kind, int(rng.integers(1, 40)), seed * 100 + i)
        if rng.random() < 0.3:
            block = _damaged(block, seed + i, every=3)
        parts.append(block)
        extra = int(rng.integers(0, 8))
        parts.append([b"Cal1:0,0,0\n", b"\r\n\r\n", b"x" * 700 + b"\n", b"noise$VNYMR,1,2\n", b"garbage",
                      b"\r", b"\n", b"Info: ready\n"][extra])
    return b"".join(parts)


def _feed(decoder: AsciiDecoder, data: bytes, cuts: list[int]) -> list[np.ndarray]:
    out, pos = [], 0
    for cut in [*cuts, len(data)]:
        out.append(decoder.feed(data[pos:cut]))
        pos = cut
    out.append(decoder.flush())
    return out


def _cuts(size: int, length: int, seed: int) -> list[int]:
    if size > 0:
        return list(range(size, length, size))
    rng = np.random.default_rng(seed)
    return sorted(set(rng.integers(0, length, max(2, length // 300)).tolist()))


def _same_batch(got: np.ndarray, want: np.ndarray, exact_dtype: bool) -> None:
    if exact_dtype:
        assert got.dtype == want.dtype
    if not exact_dtype and got.dtype != want.dtype:
        got, want = with_mag(got), with_mag(want)
    assert len(got) == len(want)
    for name in want.dtype.names or ():
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)


def _compare(columns: str, data: bytes, cuts: list[int]) -> None:
    new = AsciiDecoder(columns)
    out = _feed(new, data, cuts)
    references = [(_OneByOne(columns), False)]
    if PREVIOUS is not None:
        references.append((PREVIOUS.AsciiDecoder(columns), True))
    for ref, exact in references:
        want = _feed(ref, data, cuts)
        assert len(out) == len(want)
        for got_d, want_d in zip(out, want, strict=True):
            assert got_d.messages == want_d.messages
            _same_batch(got_d.samples, want_d.samples, exact)
        assert new.stats.as_dict() == ref.stats.as_dict()
        assert new.kinds_seen == ref.kinds_seen
        assert new.clock_lines == ref.clock_lines


SIZES = (1, 7, 61, 333, 4096, 65536, 0)  # 0: random cuts


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("size", SIZES)
def test_clean_and_damaged_streams_match_line_by_line(kind: str, size: int) -> None:
    columns = COLUMNS.get(kind, ascii_lines.DEFAULT_COLUMNS)
    n = 30 if size == 1 else 300
    clean = _stream(kind, n, 1)
    for data in (clean, _damaged(clean, 2), _damaged(clean, 3, every=2)):
        _compare(columns, data, _cuts(size, len(data), 4))


@pytest.mark.parametrize("columns", list(COLUMNS.values()))
@pytest.mark.parametrize("seed", range(4))
def test_spliced_streams_match_line_by_line(columns: str, seed: int) -> None:
    data = _spliced(seed, columns)
    for size in (5, 500, 4096, 0):
        _compare(columns, data, _cuts(size, len(data), seed))


def test_previous_decoder_found() -> None:
    """The comparison with the decoder before the batches ran (skipped without the git history)."""
    if PREVIOUS is None:
        pytest.skip("no git history: compared with the line-by-line reference only")
    assert PREVIOUS.AsciiDecoder is not AsciiDecoder


def _fixed_width(kind: str, n: int, seed: int) -> bytes:
    """Lines of one width (the byte-matrix reader's case): VectorNav's, and CSV and ``Uni:`` in fixed formats,
    with negative zeros and values beyond the bounds."""
    nine = _samples(n, seed, True)
    nine["acc"][::13] = -0.0
    nine["gyro"][5::17, 1] = 99.0  # beyond max_gyro: a bad payload
    if kind == "csv":
        rows = zip(nine["t_us"], nine["acc"], nine["gyro"], nine["temp"], strict=True)
        return b"".join(f"{t / 1e6:012.6f},{','.join(f'{v:+08.4f}' for v in (*a, *g))},{c:+07.2f}\r\n"
                        .encode() for t, a, g, c in rows)
    if kind == "uni":
        fields = zip(nine["acc"], nine["gyro"], np.nan_to_num(nine["mag"]), strict=True)
        return b"".join(f"Uni:{','.join(f'{v:+09.4f}' for v in (*a, *g, *m))}\n".encode()
                        for a, g, m in fields)
    return _stream(kind, n, seed)


def _width_kept(data: bytes, seed: int, every: int) -> bytes:
    """One line in ``every`` with a byte replaced by another (a digit, sign, dot, delimiter, letter or line
    end): damage that mostly keeps the lines' width."""
    rng = np.random.default_rng(seed)
    out = bytearray(data)
    starts = [0, *[i + 1 for i, c in enumerate(data) if c == 10][:-1]]
    for start in starts[::every]:
        at = start + int(rng.integers(0, 20))
        out[at] = int(rng.choice(np.frombuffer(b"0123456789+-.,*$Ab\r\n\x00", np.uint8)))
    return bytes(out)


@pytest.mark.parametrize("kind", ["csv", "uni", "vnymr", "vnimu"])
@pytest.mark.parametrize("size", [61, 4096, 0])
def test_fixed_width_lines_match_line_by_line(kind: str, size: int) -> None:
    """The byte-matrix reader of lines of one width (``protocols/_fixed_lines.py``) gives what reading the
    lines one by one gives, on clean streams and streams damaged in place."""
    clean = _fixed_width(kind, 400, 5)
    streams = (clean, _width_kept(clean, 6, 7), _width_kept(clean, 7, 2), _damaged(clean, 8))
    for seed, data in enumerate(streams):
        _compare(ascii_lines.DEFAULT_COLUMNS, data, _cuts(size, len(data), seed))


def test_fixed_width_reader_is_used() -> None:
    """The case above does go through the byte-matrix reader (else it would test nothing new)."""
    decoder = AsciiDecoder()
    data = _fixed_width("vnymr", 200, 1)
    for pos in range(0, len(data), 4096):
        decoder.feed(data[pos : pos + 4096])
    assert decoder._fixed_form is not None


@pytest.mark.parametrize("kind", ["csv", "csv-seq", "raw", "uni"])
def test_few_damaged_lines_found_without_the_form_mask(kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A chunk with a few damaged lines (a byte flipped in one line in a hundred, as the benchmark's) has them
    found by a scan for other bytes, not by classing every line in arrays; still line for line as reading
    every line alone."""
    columns = COLUMNS.get(kind, ascii_lines.DEFAULT_COLUMNS)
    clean = _stream(kind, 600, 9).replace(b"nan", b"0.00")  # a nan field is not a number's bytes: one by one
    out = np.frombuffer(clean, dtype=np.uint8).copy()
    starts = np.flatnonzero(np.frombuffer(b"\n" + clean[:-1], np.uint8) == 10)
    ends = np.append(starts[1:], len(clean))
    out[((starts + ends) // 2)[3::100]] ^= 0x5A
    data = out.tobytes()
    want = _feed(_OneByOne(columns), data, _cuts(4096, len(data), 0))
    monkeypatch.setattr(ascii_lines, "form_mask", None)  # calling it fails the test
    new = AsciiDecoder(columns)
    got = _feed(new, data, _cuts(4096, len(data), 0))
    for got_d, want_d in zip(got, want, strict=True):
        assert got_d.messages == want_d.messages
        _same_batch(got_d.samples, want_d.samples, False)
    _compare(columns, data, _cuts(4096, len(data), 0))
