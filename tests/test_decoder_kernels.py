"""The decoders' array and C kernels (issue 30) give what the one-at-a-time references give: the CRCs
in C against the byte loops, the text table's numbers against ``float()`` / ``int()`` on fuzzed
fields, and the text line forms against the decoder's regular expression on damaged lines."""

from __future__ import annotations

import numpy as np
import pytest

from protocols import ascii_lines
from protocols._fixed_lines import fixed_form, read_fixed
from protocols._text_table import form_mask, number_table, simple_table
from protocols.crc import crc16_bytewise, crc16_ccitt_false
from protocols.mavlink import _x25, _x25_bytewise

FIELD_BYTES = b"0123456789" * 4 + b"-+.eE \t"


def test_crcs_in_c_equal_the_byte_loops() -> None:
    rng = np.random.default_rng(1)
    for n in [*range(0, 40), 255, 1024, 4096]:
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        for init in (0, 0xFFFF, int(rng.integers(0, 65536))):
            assert crc16_ccitt_false(data, init) == crc16_bytewise(data, init)
        assert _x25(data) == _x25_bytewise(data)
        assert _x25(bytearray(data)) == _x25_bytewise(data)


def _fuzzed_field(rng: np.random.Generator) -> bytes:
    """A number as devices write it (fixed, signed, leading zeros, exponent, long), or bytes near one."""
    kind = int(rng.integers(0, 6))
    value = float(rng.normal(0, 10 ** int(rng.integers(-6, 7))))
    if kind == 0:
        return f"{value:.9g}".encode()
    if kind == 1:
        return f"{value:+0{int(rng.integers(1, 12))}.{int(rng.integers(0, 9))}f}".encode()
    if kind == 2:
        return str(int(rng.integers(-(2**40), 2**40))).encode()
    if kind == 3:
        frac = "." + "1" * int(rng.integers(0, 5)) if rng.random() < 0.5 else ""
        return ("9" * int(rng.integers(14, 20)) + frac).encode()  # around the 15 digits of the fast path
    if kind == 4:
        return f"{value:.17g}".encode()
    return bytes(rng.choice(np.frombuffer(FIELD_BYTES, np.uint8), int(rng.integers(0, 6))).tolist())


def _reference(lines: list[bytes], width: int, integers: bool) -> tuple[np.ndarray, np.ndarray]:
    table, good = np.full((len(lines), width), np.nan), np.ones(len(lines), dtype=bool)
    for i, line in enumerate(lines):
        try:
            table[i] = [float(int(f)) if integers else float(f) for f in line.split(b",")]
        except (ValueError, OverflowError):
            good[i] = False
            table[i] = np.nan
    return table, good


@pytest.mark.parametrize("integers", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_number_table_equals_float_on_fuzzed_fields(seed: int, integers: bool) -> None:
    rng = np.random.default_rng(seed)
    width = int(rng.integers(1, 13))
    lines = []
    for _ in range(400):
        fields = [_fuzzed_field(rng) for _ in range(width)]
        if integers:
            fields = [f.split(b".")[0] if rng.random() < 0.9 else f for f in fields]
        lines.append(b",".join(fields))
    got = number_table(lines, b",", width, integers)
    assert got is not None
    want = _reference(lines, width, integers)
    np.testing.assert_array_equal(got[1], want[1])
    # Bit for bit: the same doubles, -0.0 included.
    assert got[0].tobytes() == want[0].tobytes()


def test_number_table_refuses_lines_of_other_field_counts() -> None:
    assert number_table([b"1,2,3", b"4,5"], b",", 3) is None
    assert number_table([b"1,2,3,4", b"5,6"], b",", 3) is None
    assert number_table([b"1,2", b"3,4"], b";", 2) is None
    table, good = number_table([b"1;2", b"-3.5;+.25", b"7;x"], b";", 2) or (None, None)
    assert table is not None and good is not None
    assert good.tolist() == [True, True, False]
    assert table[:2].tolist() == [[1.0, 2.0], [-3.5, 0.25]]


SIMPLE_BYTES = b"0123456789" * 3 + b"-+."


def _simple_field(rng: np.random.Generator) -> bytes:
    """A number of at most 15 characters as devices write it."""
    kind = int(rng.integers(0, 4))
    value = float(rng.normal(0, 10 ** int(rng.integers(-4, 5))))
    if kind == 0:
        return f"{value:.7g}".encode() if "e" not in f"{value:.7g}" else b"-0.000"
    if kind == 1:
        return f"{value:+0{int(rng.integers(1, 9))}.{int(rng.integers(0, 6))}f}".encode()[:15]
    if kind == 2:
        return str(int(rng.integers(-(10**14), 10**14))).encode()
    return rng.choice([b"-0", b"+0", b"0.", b".0", b"-.5", b"5.", b"007", b"-00.10", b"0"])


def _near_simple_field(rng: np.random.Generator) -> bytes:
    """Bytes of numbers that may not be one: a lone sign, a dot, two of them, a sign inside, nothing."""
    if rng.random() < 0.3:
        return _fuzzed_field(rng)
    return bytes(rng.choice(np.frombuffer(SIMPLE_BYTES, np.uint8), int(rng.integers(0, 4))).tolist())


@pytest.mark.parametrize("integers", [False, True])
@pytest.mark.parametrize("seed", range(60))
def test_simple_table_equals_float_or_refuses(seed: int, integers: bool) -> None:
    """Where every field is simple, the table of float() (int()) bit for bit; else None, never a number
    float() would not give (half the batches all simple, the others with a field that may not be)."""
    rng = np.random.default_rng(seed)
    width = int(rng.integers(1, 10))
    lines = []
    for _ in range(int(rng.integers(1, 60))):
        fields = [_simple_field(rng) for _ in range(width)]
        if integers:
            fields = [f.split(b".")[0] or b"0" for f in fields]
        lines.append(fields)
    if seed % 2:
        line = lines[int(rng.integers(0, len(lines)))]
        line[int(rng.integers(0, width))] = _near_simple_field(rng)
    text = [b",".join(fields) for fields in lines]
    if seed % 10 == 3 and len(text) > 1:  # a field too many in one line and one too few in another
        text[0] += b",1"
        text[-1] = text[-1].rpartition(b",")[0]
    got = simple_table(b"\n".join(text), len(text), b",", width, integers)
    want = _reference(text, width, integers)
    simple = all(len(line.split(b",")) == width and all(
        len(f) <= 15 and f.lstrip(b"+-").replace(b".", b"", 0 if integers else 1).isdigit()
        and f[1:].lstrip(b"0123456789.") == b"" for f in line.split(b",")) for line in text)
    if got is None:
        assert not simple, "refused simple numbers"
        return
    assert simple and bool(want[1].all()) and bool(got[1].all())
    assert got[0].tobytes() == want[0].tobytes()  # bit for bit: -0.0 included


def test_simple_table_refuses_what_float_refuses() -> None:
    for lines in ([b"1,-,2"], [b"1,+.,2"], [b"1,.,2"], [b"1,,2"], [b",1,2"], [b"1,2,"], [b"5-,1,2"],
                  [b"1,2-3,4"], [b"1..2,3,4"], [b"1,2.3.4,5"], [b"1e5,2,3"], [b"1, 2,3"],
                  [b"1234567890123456,1,2"], [b"1,2,3", b"4,5,6,7"], [b"1,2,3,4", b"5,6"], [b"-", b"1,2,3"]):
        assert simple_table(b"\n".join(lines), len(lines), b",", 3) is None, lines
    assert simple_table(b"1.5,2,3", 1, b",", 3, integers=True) is None
    table, good = simple_table(b"-0.000,+0,-0\n5.,.5,-.5\n007,-00.10,123456789012345", 3, b",", 3) \
        or (None, None)
    assert table is not None and good is not None and good.all()
    assert table.tolist() == [[-0.0, 0.0, -0.0], [5.0, 0.5, -0.5], [7.0, -0.1, 123456789012345.0]]
    assert np.signbit(table[0]).tolist() == [True, False, True]


def _damaged_lines(data: bytes, seed: int) -> list[bytes]:
    rng = np.random.default_rng(seed)
    raw = bytearray(data)
    for at in rng.integers(0, len(raw), len(raw) // 40):
        raw[int(at)] = int(rng.integers(0, 256)) if rng.random() < 0.5 else raw[int(at)] ^ 0x5A
    return [line for line in bytes(raw).replace(b"\r", b"\n").split(b"\n") if line]


@pytest.mark.parametrize("columns", [ascii_lines.DEFAULT_COLUMNS, "t,ax,ay,az,gx,gy,gz,temp,mx,my,mz"])
@pytest.mark.parametrize("seed", range(3))
def test_form_mask_equals_the_regex_on_damaged_lines(seed: int, columns: str) -> None:
    rng = np.random.default_rng(seed)
    samples = np.zeros(300, dtype=ascii_lines.MAG_SAMPLE_DTYPE)
    samples["acc"] = rng.normal(0, 5, (300, 3))
    samples["gyro"] = rng.normal(0, 1, (300, 3))
    samples["temp"] = 25.0
    samples["mag"] = rng.normal(0, 40, (300, 3))
    decoder = ascii_lines.AsciiDecoder(columns)
    streams = b"".join((ascii_lines.encode_csv(samples, columns), ascii_lines.encode_motioncal(samples),
                        ascii_lines.encode_vectornav(samples, "VNYMR"),
                        ascii_lines.encode_vectornav(samples, "VNIMU")))
    lines = _damaged_lines(streams, seed)
    match = ascii_lines._line_forms(",", len(decoder.columns.names)).fullmatch
    want = [m.lastindex or 0 if (m := match(line)) else 0 for line in lines]
    kinds = (ascii_lines._CSV, ascii_lines._RAW, ascii_lines._UNI, ascii_lines._VNYMR, ascii_lines._VNIMU)
    for kind in kinds:
        got = form_mask(lines, *decoder._form(kind))
        assert got.tolist() == [k == kind for k in want], kind


def test_form_mask_takes_lines_shorter_than_the_head() -> None:
    lines = [b"\x00", b"R", b"$VN", b"Raw:1,2,3,4,5,6,7,8,9", b"$VNYMR"]
    assert form_mask(lines, b"Raw:", b"-+0123456789 \t", b",", 9, False).tolist() == [False, False, False,
                                                                                      True, False]
    assert not form_mask(lines, b"$VNYMR,", b"-+.0123456789eE \t", b",", 12, True).any()


def _fixed_format(rng: np.random.Generator) -> str:
    """A number format of fixed width as devices print them: sign always, zeros in front, 0 to 9 decimals."""
    decimals = int(rng.integers(0, 10))
    whole = int(rng.integers(1, 16 - decimals))
    return f"{{:+0{whole + decimals + (2 if decimals else 1)}.{decimals}f}}"


@pytest.mark.parametrize("checksum", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_fixed_lines_equal_float_bit_for_bit(seed: int, checksum: bool) -> None:
    """Lines of one width read as a byte matrix: every number of a line of the form is the double
    ``float()`` gives (negative zeros included), and a line is of the form exactly when its bytes are of
    the template's classes (and its checksum matches); damaged lines (bytes replaced, any byte) are not."""
    rng = np.random.default_rng(seed)
    formats = [_fixed_format(rng) for _ in range(int(rng.integers(1, 13)))]
    head = b"$VNXYZ," if checksum else b""

    def line(values: list[float]) -> bytes:
        body = head + ",".join(f.format(v) for f, v in zip(formats, values, strict=True)).encode()
        if checksum:
            body += b"*" + f"{ascii_lines.nmea_xor(body[1:]):02X}".encode()
        return body

    def value(f: str) -> float:
        whole = int(f.split("0")[1].split(".")[0]) - int(f.split(".")[1][0]) - 2  # digits before the dot
        return float(rng.choice([-1, 1]) * rng.uniform(0, 10 ** max(whole, 0))) * float(rng.random() < 0.9)

    lines = [line([value(f) for f in formats]) for _ in range(300)]
    lines = [ln for ln in lines if len(ln) == len(lines[0])]  # a rounding that carried a digit: dropped
    for ending in (b"\r\n", b"\n"):
        form = fixed_form(lines[0], ending, len(head), checksum, b",")
        assert form is not None
        damaged = [bytearray(ln) for ln in lines]
        hit = rng.random(len(damaged)) < 0.2
        for i in np.flatnonzero(hit).tolist():
            at = int(rng.integers(0, len(damaged[i])))
            damaged[i][at] = int(rng.choice(np.frombuffer(b"0123456789+-.,*$AbZ \t\x00\xff", np.uint8)))
        text = b"".join(bytes(d) + ending for d in damaged)
        if b"\n" in b"".join(bytes(d) for d in damaged) or b"\r" in b"".join(bytes(d) for d in damaged):
            continue
        found = read_fixed(form, text)
        assert found is not None
        table, good = found
        for i, d in enumerate(damaged):
            d = bytes(d)
            fields = d[len(head) : len(d) - (3 if checksum else 0)].split(b",")
            same = len(d) == len(lines[0]) and all(
                (a in b"0123456789" and b in b"0123456789") or (a in b"+-" and b in b"+-") or a == b
                for a, b in zip(d[: len(d) - (2 if checksum else 0)], lines[0], strict=False))
            if checksum:
                hex_sum = all(c in b"0123456789ABCDEFabcdef" for c in d[-2:])
                same = same and hex_sum and int(d[-2:], 16) == ascii_lines.nmea_xor(d[1:-3])
            assert bool(good[i]) == same, (d, lines[0])
            if same:
                want = np.array([float(f) for f in fields])
                np.testing.assert_array_equal(table[i].view(np.int64), want.view(np.int64))


def test_fixed_form_refuses_lines_that_are_not_simple_numbers() -> None:
    for line in (b"1e5,2", b"1, 2", b"1,", b"1,-", b"1234567890123456,1", b"1.2.3,4"):
        assert fixed_form(line, b"\n", 0, False, b",") is None, line
    assert fixed_form(b"1.,.5,-0", b"\n", 0, False, b",") is not None
    assert read_fixed(fixed_form(b"1,2", b"\n", 0, False, b","), b"1,2\n1,22\n") is None  # not one width
    assert read_fixed(fixed_form(b"1,2", b"\n", 0, False, b","), b"1,2\n1\n2\n") is None  # a break inside
