"""Native protocol v1: CRC, frame round trips, and resynchronisation under any split and garbage."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.base import SAMPLE_DTYPE
from protocols.crc import crc16_ccitt_false, crc16_rows
from protocols.native import (
    ACK,
    DEVICE_INFO,
    SAMPLE_FRAME_SIZE,
    SYNC,
    NativeDecoder,
    decode_sample_frames,
    encode_ack,
    encode_device_info,
    encode_frame,
    encode_samples,
    parse_ack,
    parse_device_info,
)


def make_samples(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n) + 7
    s["t_us"] = np.arange(n) * 1000 + 123
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25 + rng.normal(0, 0.1, n)
    return s


def test_crc_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1


def test_vectorised_crc_equals_bytewise() -> None:
    rows = np.random.default_rng(1).integers(0, 256, (50, 43), dtype=np.uint8)
    assert list(crc16_rows(rows)) == [crc16_ccitt_false(r.tobytes()) for r in rows]


def test_sample_frame_layout_matches_spec() -> None:
    s = make_samples(1)
    frame = encode_samples(s)
    assert len(frame) == SAMPLE_FRAME_SIZE == 47
    assert frame[:2] == SYNC and frame[2] == 0x01 and struct.unpack("<H", frame[3:5])[0] == 40
    seq, t_us, *vals = struct.unpack("<IQ7f", frame[5:45])
    assert seq == s["seq"][0] and t_us == s["t_us"][0]
    assert np.allclose(vals[:3], s["acc"][0]) and np.allclose(vals[6], s["temp"][0])
    assert struct.unpack("<H", frame[45:])[0] == crc16_ccitt_false(frame[2:45])
    assert encode_frame(0x01, frame[5:45]) == frame


def test_round_trip_samples_and_messages() -> None:
    s = make_samples(100)
    info = {"serial": "SN1", "model": "sim", "firmware": "1.0", "rate_hz": 200}
    stream = encode_samples(s[:50]) + encode_device_info(info) + encode_ack(0x11) + encode_samples(s[50:])
    dec = NativeDecoder()
    out = dec.feed(stream)
    assert out.samples.tobytes() == s.tobytes()
    assert [m.msg_id for m in out.messages] == [DEVICE_INFO, ACK]
    assert parse_device_info(out.messages[0].payload) == info
    assert parse_ack(out.messages[1].payload).ok
    assert dec.stats.errors == 0 and dec.stats.garbage_bytes == 0 and dec.stats.samples == 100


def test_decode_sample_frames_stops_at_bad_crc() -> None:
    buf = bytearray(encode_samples(make_samples(10)))
    buf[5 * SAMPLE_FRAME_SIZE + 20] ^= 0x01
    samples, used = decode_sample_frames(bytes(buf))
    assert len(samples) == 5 and used == 5 * SAMPLE_FRAME_SIZE


def test_each_error_kind_is_counted() -> None:
    s = make_samples(4)
    good = [encode_samples(s[i : i + 1]) for i in range(4)]
    bad_crc = bytearray(good[1])
    bad_crc[10] ^= 0xFF
    bad_len = SYNC + b"\x01" + struct.pack("<H", 2000)
    truncated = good[2][:30]
    stream = b"junk" + good[0] + bytes(bad_crc) + bad_len + truncated + good[3]
    dec = NativeDecoder()
    out = dec.feed(stream)
    assert out.samples.tobytes() == (s[0:1].tobytes() + s[3:4].tobytes())
    st_ = dec.stats
    assert (st_.crc_errors, st_.length_errors, st_.truncated) == (1, 1, 1)
    assert st_.garbage_bytes >= 4


def test_sample_id_with_wrong_length_is_a_bad_payload() -> None:
    dec = NativeDecoder()
    out = dec.feed(encode_frame(0x01, b"\x00" * 8) + encode_samples(make_samples(1)))
    assert len(out.samples) == 1 and dec.stats.bad_payloads == 1


def test_unknown_ids_are_returned_and_counted() -> None:
    dec = NativeDecoder()
    out = dec.feed(encode_frame(0x7E, b"hello"))
    assert out.messages[0].msg_id == 0x7E and out.messages[0].payload == b"hello"
    assert dec.stats.unknown_ids == 1


def _garbage() -> st.SearchStrategy[bytes]:
    # Garbage never contains a sync pair, so it cannot itself hold a valid frame.
    return st.binary(max_size=60).filter(lambda b: SYNC not in b and not b.endswith(b"\xa5"))


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 30),
    garbage=st.lists(_garbage(), min_size=31, max_size=31),
    cuts=st.lists(st.integers(0, 2000), max_size=40),
    seed=st.integers(0, 2**16),
)
def test_any_split_and_garbage_decode_to_the_good_frames(n: int, garbage: list[bytes], cuts: list[int],
                                                         seed: int) -> None:
    s = make_samples(n, seed)
    frames = [encode_samples(s[i : i + 1]) for i in range(n)]
    stream = garbage[0] + b"".join(f + g for f, g in zip(frames, garbage[1:], strict=False))
    points = sorted({c % (len(stream) + 1) for c in cuts})
    dec = NativeDecoder()
    got = []
    prev = 0
    for p in points + [len(stream)]:
        got.append(dec.feed(stream[prev:p]).samples)
        prev = p
    dec.flush()
    assert np.concatenate(got).tobytes() == s.tobytes()


@settings(max_examples=100, deadline=None)
@given(n=st.integers(2, 30), flips=st.lists(st.integers(0, 10_000), min_size=1, max_size=5),
       chunk=st.integers(1, 200))
def test_corrupted_frames_are_dropped_and_the_rest_kept(n: int, flips: list[int], chunk: int) -> None:
    s = make_samples(n)
    stream = bytearray(encode_samples(s))
    hit = set()
    for f in flips:
        pos = f % len(stream)
        stream[pos] ^= 0x5A
        hit.add(pos // SAMPLE_FRAME_SIZE)
    dec = NativeDecoder()
    parts = [dec.feed(bytes(stream[i : i + chunk])).samples for i in range(0, len(stream), chunk)]
    # A corrupted length can hold good frames back until the stream ends: flush releases them.
    got = np.concatenate(parts + [dec.flush().samples])
    expected = np.delete(s, sorted(hit))
    # Every untouched frame survives; a corrupted one never comes out as a sample of its own.
    assert set(expected["seq"]) <= set(got["seq"])
    for rec in got:
        assert rec.tobytes() in {x.tobytes() for x in s}
