"""Text lines: configurable CSV, MotionCal Raw/Uni, VectorNav $VNYMR/$VNIMU with checksums,
length caps and plausibility checks, under any split of the stream."""

from __future__ import annotations

import math

import decode_helpers
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.ascii_lines import (
    MSG_TEXT,
    MSG_VECTORNAV,
    STANDARD_GRAVITY,
    AsciiDecoder,
    encode_csv,
    encode_samples,
    nmea_xor,
    parse_columns,
    vectornav_sentence,
)
from protocols.base import SAMPLE_DTYPE
from protocols.mag_batches import with_mag


def feed_ragged(decoder, data: bytes, seed: int = 0, max_chunk: int = 41):
    return decode_helpers.feed_ragged(decoder, data, seed, max_chunk)


def make_samples(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.arange(n) * 10_000
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25 + rng.normal(0, 0.5, n)
    return s


# ------------------------------------------------------------------ VectorNav


@pytest.mark.parametrize("sentence", [
    # Examples printed in the VN-100 / VN-200 user manuals, with their published checksums.
    b"$VNYPR,+010.071,+000.278,-002.026*60", b"$VNYPR,+010.071,+000.278,-002.026,T1162704*2F",
    b"$VNRRG,30,2,0,0,0,1,0,1*6E", b"$VNRRG,11*73", b"$VNERR,03*72",
])
def test_xor_checksum_of_the_manuals_examples(sentence: bytes) -> None:
    assert nmea_xor(sentence[1 : sentence.index(b"*")]) == int(sentence[-2:], 16)
    dec = AsciiDecoder()
    out = dec.feed(sentence + b"\r\n")
    assert dec.stats.errors == 0 and [m.msg_id for m in out.messages] == [MSG_VECTORNAV]


def vectornav_manual_crc(data: bytes) -> int:
    """The CRC routine printed in the VN-100 user manual (section 3.8.3), transcribed."""
    crc = 0
    for b in data:
        crc = ((crc >> 8) | (crc << 8)) & 0xFFFF
        crc ^= b
        crc ^= (crc & 0xFF) >> 4
        crc = (crc ^ (crc << 12)) & 0xFFFF
        crc = (crc ^ ((crc & 0x00FF) << 5)) & 0xFFFF
    return crc


def test_crc16_equals_the_manuals_routine() -> None:
    for body in (b"VNRRG,11", b"VNYMR,+006.380,+000.023,-001.953,+1.0640,-0.2531,+3.0614,+00.005,+00.344"):
        line = vectornav_sentence(body.decode(), crc16=True)
        assert int(line[-6:-2], 16) == vectornav_manual_crc(body)


def test_vnymr_fields_and_appended_counter() -> None:
    body = ("VNYMR,+006.380,+000.023,-001.953,+1.0640,-0.2531,+3.0614,+00.005,+00.344,-09.758,"
            "-0.001222,-0.000450,-0.001218,T1162704")
    dec = AsciiDecoder()
    out = dec.feed(vectornav_sentence(body))
    assert dec.stats.errors == 0 and len(out.samples) == 1
    np.testing.assert_allclose(out.samples["acc"][0], [0.005, 0.344, -9.758], rtol=1e-6)
    np.testing.assert_allclose(out.samples["gyro"][0], [-0.001222, -0.000450, -0.001218], rtol=1e-6)
    assert math.isnan(out.samples["temp"][0])
    np.testing.assert_allclose(out.samples["mag"][0], [106.40, -25.31, 306.14], rtol=1e-6)  # gauss -> uT


def test_vectornav_crc16_and_bad_checksums() -> None:
    body = "VNYMR,+000.000,+000.000,+000.000,+0.0000,+0.0000,+0.0000,+00.100,+00.200,-09.800,+0.1,+0.2,+0.3"
    good16 = vectornav_sentence(body, crc16=True)
    bad8 = bytearray(vectornav_sentence(body))
    bad8[-3] = ord("0") if bad8[-3] != ord("0") else ord("1")
    dec = AsciiDecoder()
    out = dec.feed(good16 + bytes(bad8) + b"$VNYMR,1,2,3\r\n" + vectornav_sentence("VNYPR,+1,+2,+3"))
    assert len(out.samples) == 1 and np.allclose(out.samples["gyro"][0], [0.1, 0.2, 0.3])
    assert dec.stats.crc_errors == 1 and dec.stats.bad_payloads == 1
    assert [m.msg_id for m in out.messages] == [MSG_VECTORNAV]  # $VNYPR: no inertial data


@pytest.mark.parametrize("kind", ["vnymr", "vnimu"])
def test_vectornav_round_trip(kind: str) -> None:
    s = with_mag(make_samples(50, seed=1))
    s["mag"] = np.random.default_rng(4).normal(0.0, 30.0, (50, 3))
    dec = AsciiDecoder(rate_hz=200)
    out, _ = feed_ragged(dec, encode_samples(s, kind), seed=2)
    assert dec.stats.errors == 0 and len(out) == 50
    np.testing.assert_allclose(out["acc"], s["acc"], atol=5e-4)
    np.testing.assert_allclose(out["gyro"], s["gyro"], atol=5e-7)
    np.testing.assert_allclose(out["mag"], s["mag"], atol=0.005 + 1e-9)  # 1e-4 gauss = 0.01 uT steps
    assert out["seq"].tolist() == list(range(50)) and out["t_us"].tolist() == [i * 5000 for i in range(50)]
    if kind == "vnimu":
        np.testing.assert_allclose(out["temp"], s["temp"], atol=0.05)


# ------------------------------------------------------------------ MotionCal


def test_motioncal_raw_scales() -> None:
    # 8192 counts per g, 16 counts per deg/s, 10 counts per uT (MotionCal's imuread.h)
    dec = AsciiDecoder()
    out = dec.feed(b"Raw:0,-8192,16384,16,-32,5760,120,-30,400\r\n").samples
    np.testing.assert_allclose(out["acc"][0], [0, -STANDARD_GRAVITY, 2 * STANDARD_GRAVITY], rtol=1e-6)
    np.testing.assert_allclose(out["gyro"][0], np.radians([1, -2, 360]), rtol=1e-6)
    np.testing.assert_allclose(out["mag"][0], [12.0, -3.0, 40.0], rtol=1e-6)


def test_motioncal_round_trip_and_uni_lines() -> None:
    s = with_mag(make_samples(40, seed=3))
    s["mag"] = np.random.default_rng(5).normal(0.0, 30.0, (40, 3))
    s["mag"][7] = np.nan  # a sample without a field is written with MotionCal's constant one
    dec = AsciiDecoder()
    out, _ = feed_ragged(dec, encode_samples(s, "motioncal") + b"Uni:0.1,0.2,9.7,0.01,0.02,0.03,20,0,-40\n")
    assert dec.stats.errors == 0 and len(out) == 41
    np.testing.assert_allclose(out["acc"][:40], s["acc"], atol=STANDARD_GRAVITY / 8192 / 2 + 1e-6)
    np.testing.assert_allclose(out["gyro"][:40], s["gyro"], atol=math.radians(1 / 16) / 2 + 1e-7)
    known = np.arange(40) != 7
    np.testing.assert_allclose(out["mag"][:40][known], s["mag"][known], atol=0.05 + 1e-9)  # 0.1 uT counts
    np.testing.assert_allclose(out["mag"][7], [20.0, 0.0, -40.0])
    np.testing.assert_allclose(out["acc"][40], [0.1, 0.2, 9.7], rtol=1e-6)
    np.testing.assert_allclose(out["mag"][40], [20.0, 0.0, -40.0], rtol=1e-6)
    assert dec.kinds_seen == {"motioncal": 41}


# ------------------------------------------------------------------ CSV


def test_column_spec_units_and_errors() -> None:
    cols = parse_columns("t:ms, ax:g, ay:mg, az:m/s^2, gx:dps, gy:mrad/s, gz:0.5, _, temp:cdegC")
    assert cols.names == ("t", "ax", "ay", "az", "gx", "gy", "gz", "_", "temp")
    assert cols.scales == pytest.approx([1e-3, STANDARD_GRAVITY, STANDARD_GRAVITY / 1000, 1, math.pi / 180,
                                         1e-3, 0.5, 1, 0.01])
    for bad, words in [("t,ax,ay,az,gx,gy", "lacks gz"), ("t,ax,ax,ay,az,gx,gy,gz", "twice"),
                       ("t,ax:furlong,ay,az,gx,gy,gz", "unknown unit 'furlong'"),
                       ("x,ax", "unknown column 'x'")]:
        with pytest.raises(ValueError, match=words):
            parse_columns(bad)


def test_csv_in_device_units_round_trips() -> None:
    s = make_samples(30, seed=4)
    spec = "seq,t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps,temp"
    data = b"# IMU logger v2\r\nseq,t_ms,ax,ay,az,gx,gy,gz,temp\r\n" + encode_csv(s, spec)
    dec = AsciiDecoder(columns=spec)
    out, messages = feed_ragged(dec, data, seed=5)
    assert dec.stats.errors == 0 and len(out) == 30
    assert [m.msg_id for m in messages] == [MSG_TEXT, MSG_TEXT]
    assert (out["seq"] == s["seq"]).all() and (out["t_us"] == s["t_us"]).all()
    for field in ("acc", "gyro", "temp"):
        np.testing.assert_allclose(out[field], s[field], rtol=1e-6)


def test_line_caps_plausibility_and_malformed_lines_are_counted() -> None:
    good = b"0.01,0,0,9.8,0,0,0,25\n"
    lines = [
        b"7,0,9.8,0,0,0,25\n",  # partial first line: the tail of one sent before we listened
        good,
        b"1" * 600 + b"\n",  # too long
        b"0.02,0,0,9.8,0,0\n",  # too few fields
        b"0.03,0,0,x9.8,0,0,0,25\n",  # not a number
        b"0.04,0,0,9.8e9,0,0,0,25\n",  # implausible acceleration
        b"0.05,0,0,9.8,0,99,0,25\n",  # implausible rate
        b"0.06,0,0,9.8,0,0,0,400\n",  # implausible temperature
        b"0.07,0,0,nan,0,0,0,25\n",  # not finite
        b"\xff\xfe\x00binary\n",  # not text
        good.replace(b"0.01", b"0.08"),
    ]
    dec = AsciiDecoder()
    out, _ = feed_ragged(dec, b"".join(lines), seed=6, max_chunk=90)
    assert out["t_us"].tolist() == [10_000, 80_000]
    assert dec.stats.length_errors == 1 and dec.stats.bad_payloads == 6 and dec.stats.errors == 7
    assert dec.stats.garbage_bytes >= 600 + len(lines[0])


def test_endless_line_is_dropped_in_pieces_without_growing_the_buffer() -> None:
    dec = AsciiDecoder(max_line=100)
    for _ in range(50):
        dec.feed(b"9" * 64)
        assert len(dec._buf) <= 100 + 64
    out = dec.feed(b"\n0.5,0,0,9.8,0,0,0,25\n")
    assert len(out.samples) == 1 and dec.stats.length_errors == 1


def test_last_line_without_end_is_read_at_flush() -> None:
    dec = AsciiDecoder()
    assert len(dec.feed(b"0,0,0,9.8,0,0,0,25\n0.01,0,0,9.8,0,0,0,25").samples) == 1
    assert len(dec.flush().samples) == 1


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 2**32 - 1))
def test_arbitrary_bytes_never_raise(data: bytes, seed: int) -> None:
    dec = AsciiDecoder()
    out, _ = feed_ragged(dec, data, seed=seed)
    assert dec.stats.samples == len(out) <= dec.stats.frames


@settings(max_examples=40, deadline=None)
@given(st.lists(st.binary(max_size=30).filter(lambda b: b"\n" not in b and b"\r" not in b), min_size=1,
                max_size=6), st.integers(0, 2**32 - 1))
def test_garbage_lines_never_cost_a_good_line(garbage: list[bytes], seed: int) -> None:
    s = make_samples(len(garbage), seed=seed % 100)
    lines = [encode_samples(s[i : i + 1], "vnymr") for i in range(len(s))]
    stream = b"".join(b"\n" + g + b"\n" + line for g, line in zip(garbage, lines, strict=True))
    dec = AsciiDecoder()
    out, _ = feed_ragged(dec, stream, seed=seed)
    assert len(out) == len(s)
    np.testing.assert_allclose(out["acc"], s["acc"], atol=5e-4)


def test_option_string_sets_columns_and_the_rate_of_lines_without_a_clock() -> None:
    dec = AsciiDecoder.from_option("@50")
    out = dec.feed(b"Raw:0,0,8192,0,0,0,0,0,0\nRaw:0,0,8192,0,0,0,0,0,0\n").samples
    assert out["t_us"].tolist() == [0, 20_000] and dec.clock_lines == 0
    dec = AsciiDecoder.from_option("ax,ay,az,gx,gy,gz@200")
    assert dec.columns.names == ("ax", "ay", "az", "gx", "gy", "gz") and dec.rate_hz == 200
    for bad in ("@fast", "@0", "t,ax@"):
        with pytest.raises(ValueError):
            AsciiDecoder.from_option(bad)


def test_block_and_line_by_line_paths_give_the_same_samples() -> None:
    s = make_samples(200, seed=9)
    spec = "seq,t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps,temp"
    lines = encode_csv(s, spec).splitlines(keepends=True)
    clean = AsciiDecoder(columns=spec)
    clean.feed(b"header\n")
    fast = clean.feed(b"".join(lines)).samples  # every line a plausible sample: one block
    mixed = AsciiDecoder(columns=spec)
    mixed.feed(b"header\n")
    slow = mixed.feed(b"".join(lines[:100]) + b"# a note in the middle\n" + b"".join(lines[100:])).samples
    assert fast.tobytes() == slow.tobytes() and len(fast) == 200
    assert clean.kinds_seen["csv"] == mixed.kinds_seen["csv"] == 200 and mixed.kinds_seen["text"] == 2
    assert clean.clock_lines == mixed.clock_lines == 200


def test_tagged_lines_of_other_kinds_are_text_not_errors() -> None:
    dec = AsciiDecoder()
    out = dec.feed(b"Raw:0,0,8192,0,0,0,0,0,0\nCal1:0.1,0.2,0.3,1,2,3,4,5,6,7\nInfo: 100 Hz\n")
    assert len(out.samples) == 1 and dec.stats.errors == 0
    assert [m.payload for m in out.messages] == [b"Cal1:0.1,0.2,0.3,1,2,3,4,5,6,7", b"Info: 100 Hz"]
