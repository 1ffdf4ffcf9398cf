"""The decoder a frame description compiles into (``protocols/frame.py``): checksums, every field type in
both byte orders, scale and offset, wrapping counters and clocks, clockless boards, and the native
protocol's resync rules under any chunking and garbage (hypothesis)."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from frame_helpers import SPEC_EXAMPLE, plain_frames, spec_example, still_samples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocols.frame import FrameDecoder, encode_frames
from protocols.frame_checksums import CHECKSUM_TYPES, RowChecksum, checksum, checksum_rows
from protocols.frame_description import describe

CHECK = b"123456789"


@pytest.mark.parametrize(("name", "expected"), [
    ("sum8", sum(CHECK) & 0xFF), ("sum16", sum(CHECK) & 0xFFFF), ("xor8", 0x31),
    # the catalogue's check values (CRC RevEng): CRC-8/SMBUS, -16/IBM-3740, -16/XMODEM, -16/MODBUS
    ("crc8", 0xF4), ("crc16-ccitt-false", 0x29B1), ("crc16-xmodem", 0x31C3), ("crc16-modbus", 0x4B37),
    ("crc32", zlib.crc32(CHECK)),
])
def test_every_checksum_gives_its_check_value(name: str, expected: int) -> None:
    assert checksum(name, CHECK) == expected


def test_the_table_and_the_spec_list_the_same_checksums() -> None:
    assert set(CHECKSUM_TYPES) == {"none", "sum8", "xor8", "sum16", "crc8", "crc16-ccitt-false",
                                   "crc16-xmodem", "crc16-modbus", "crc32"}


def _frame_by_hand(kind: str, order: str, raw: int | float, crc_type: str) -> bytes:
    """One frame built with struct (not the module's encoder): sync, ax of ``kind``, zeros, checksum."""
    prefix = "<" if order == "little" else ">"
    if kind in ("u24", "i24"):
        body = (raw & 0xFFFFFF).to_bytes(3, order)  # type: ignore[operator]
    else:
        code = {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "i32": "i", "u64": "Q", "i64": "q",
                "f32": "f", "f64": "d"}[kind]
        body = struct.pack(prefix + code, raw)
    frame = b"\xc3\x3c" + body.ljust(8, b"\0") + bytes(12)  # ax at 2, gx.. zero
    size = {"crc32": 4, "sum16": 2}.get(crc_type, 2 if crc_type.startswith("crc16") else 1)
    value = checksum(crc_type, frame[2:])
    return frame + value.to_bytes(size, order)


def _one_field_description(kind: str, order: str, crc_type: str) -> dict:
    size = {"crc32": 4, "sum16": 2}.get(crc_type, 2 if crc_type.startswith("crc16") else 1)
    return {
        "schema": "imu-station/frame/1", "byte_order": order, "sync": [0xC3, 0x3C], "length": 22 + size,
        "checksum": {"type": crc_type}, "rate_hz": 100,
        "fields": [{"name": "ax", "at": 2, "type": kind, "scale": 0.5, "offset": -1.0},
                   *[{"name": n, "at": 10 + 2 * i, "type": "i16"}
                     for i, n in enumerate(("ay", "az", "gx", "gy", "gz"))]],
    }


RAW = {"u8": 250, "i8": -100, "u16": 65000, "i16": -30000, "u24": 0xFEDCBA, "i24": -0x7FFFF0,
       "u32": 4_000_000_000, "i32": -2_000_000_000, "u64": 2**63 + 12345, "i64": -(2**62) - 7, "f32": -1234.5,
       "f64": 6.02214076e23}


@pytest.mark.parametrize("order", ["little", "big"])
@pytest.mark.parametrize("kind", list(RAW))
def test_every_field_type_in_either_byte_order_is_read_with_scale_and_offset(kind: str, order: str) -> None:
    crc_type = ["crc8", "crc16-xmodem", "crc16-modbus", "crc32", "sum16", "xor8"][len(kind + order) % 6]
    decoder = FrameDecoder(describe(_one_field_description(kind, order, crc_type)))
    frame = _frame_by_hand(kind, order, RAW[kind], crc_type)
    out = decoder.feed(frame * 3)
    assert len(out.samples) == 3 and decoder.stats.errors == 0
    expected = float(RAW[kind]) * 0.5 - 1.0
    assert decoder.last_values["ax"][0] == pytest.approx(expected, rel=1e-15)
    assert out.samples["acc"][0, 0] == np.float32(expected)


def test_a_bad_checksum_in_either_byte_order_is_an_error() -> None:
    for order in ("little", "big"):
        frame = bytearray(_frame_by_hand("i16", order, 1000, "crc16-ccitt-false"))
        frame[-2], frame[-1] = frame[-1], frame[-2]  # the checksum in the other byte order
        decoder = FrameDecoder(describe(_one_field_description("i16", order, "crc16-ccitt-false")))
        assert len(decoder.feed(bytes(frame)).samples) == 0 and decoder.stats.crc_errors == 1


def test_a_counter_and_a_clock_that_wrap_are_unwrapped_across_feeds() -> None:
    desc = describe(spec_example())
    n = 300
    seq = (65_400 + np.arange(n)) % 65_536
    t_raw = (2**32 - 100 * 5_000 + np.arange(n) * 5_000) % 2**32
    values = {"seq": seq, "t": t_raw * 1e-6, "ax": np.zeros(n), "ay": np.zeros(n), "az": np.full(n, 9.8),
              "gx": np.zeros(n), "gy": np.zeros(n), "gz": np.zeros(n)}
    data = encode_frames(desc, values)
    decoder = FrameDecoder(desc)
    got = np.concatenate([decoder.feed(data[i : i + 1000]).samples for i in range(0, len(data), 1000)])
    assert np.array_equal(got["seq"], 65_400 + np.arange(n))
    assert np.all(np.diff(got["t_us"].astype(np.int64)) == 5_000)
    assert got["t_us"][0] == 2**32 - 500_000


def test_a_clock_stepping_back_a_little_steps_back() -> None:
    desc = describe(spec_example())
    t = np.array([1.0, 1.005, 1.010, 1.005, 1.010, 1.015])
    values = {"seq": np.arange(6), "t": t, **{n: np.zeros(6) for n in ("ax", "ay", "az", "gx", "gy", "gz")}}
    got = FrameDecoder(desc).feed(encode_frames(desc, values)).samples
    assert list(got["t_us"]) == [1_000_000, 1_005_000, 1_010_000, 1_005_000, 1_010_000, 1_015_000]


def _clockless(seq: bool) -> dict:
    fields = [f for f in SPEC_EXAMPLE["fields"] if f["name"] != "t" and (seq or f["name"] != "seq")]  # type: ignore
    return spec_example(fields=fields, rate_hz=50)


def test_a_clockless_board_with_a_counter_is_timed_by_its_counter_at_its_rate() -> None:
    desc = describe(_clockless(seq=True))
    seq = np.array([7, 8, 9, 12, 13])  # two samples lost after 9
    values = {"seq": seq, **{n: np.ones(5) for n in ("ax", "ay", "az", "gx", "gy", "gz")}}
    got = FrameDecoder(desc).feed(encode_frames(desc, values)).samples
    assert list(got["t_us"]) == [0, 20_000, 40_000, 100_000, 120_000]
    assert list(got["seq"]) == [7, 8, 9, 12, 13]


def test_a_board_with_neither_clock_nor_counter_is_timed_by_the_count_of_samples() -> None:
    desc = describe(_clockless(seq=False))
    values = {n: np.ones(6) for n in ("ax", "ay", "az", "gx", "gy", "gz")}
    data = encode_frames(desc, values)
    decoder = FrameDecoder(desc)
    got = np.concatenate([decoder.feed(data[:50]).samples, decoder.feed(data[50:]).samples])
    assert list(got["t_us"]) == [0, 20_000, 40_000, 60_000, 80_000, 100_000]
    assert list(got["seq"]) == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize("rate_hz", [200, None])
def test_without_a_counter_a_clock_gap_of_more_than_1_5_periods_counts_the_samples_missing(rate_hz) -> None:
    fields = [f for f in SPEC_EXAMPLE["fields"] if f["name"] != "seq"]  # type: ignore[union-attr]
    desc = describe(spec_example(fields=fields, rate_hz=rate_hz))
    t_ms = np.array([0, 5, 10, 15, 20, 25, 30, 35, 42, 50, 55, 60, 80, 85])  # 7 ms: none lost; 8, 20 ms: 1, 3
    values = {"t": t_ms * 1e-3, **{n: np.ones(len(t_ms)) for n in ("ax", "ay", "az", "gx", "gy", "gz")}}
    got = FrameDecoder(desc).feed(encode_frames(desc, values)).samples
    assert list(np.diff(got["seq"].astype(int))) == [1, 1, 1, 1, 1, 1, 1, 1, 2, 1, 1, 4, 1]


def test_a_long_sync_cut_between_chunks_is_kept_and_a_frame_fed_a_byte_at_a_time_comes_out() -> None:
    desc = describe(spec_example(sync=[0xDE, 0xAD, 0xBE], fields=[
        {"name": n, "at": 4 + 2 * i, "type": "i16"} for i, n in enumerate(("t", "ax", "ay", "az", "gx", "gy",
                                                                             "gz"))]))
    samples = still_samples(5, 200.0)
    data = b"\xde\xad" + plain_frames(desc, samples)  # a false partial sync first
    decoder = FrameDecoder(desc)
    got = [decoder.feed(data[i : i + 1]).samples for i in range(len(data))]
    assert sum(len(g) for g in got) == 5 and decoder.stats.garbage_bytes == 2


def test_garbage_a_bad_checksum_and_a_cut_frame_are_counted_and_skipped() -> None:
    desc = describe(spec_example())
    frames = plain_frames(desc, still_samples(4, 200.0))
    f = [frames[i * 28 : (i + 1) * 28] for i in range(4)]
    bad = bytearray(f[1])
    bad[10] ^= 1
    data = b"xyz" + f[0] + bytes(bad) + f[2][:15] + f[3] + b"\xaa"
    decoder = FrameDecoder(desc)
    got = decoder.feed(data).samples
    assert list(got["seq"]) == [0, 3]
    s = decoder.stats
    assert (s.crc_errors, s.truncated, s.frames) == (1, 1, 2)
    decoder.flush()
    assert decoder.stats.garbage_bytes == 3 + 28 + 15 + 1


def test_flush_counts_every_frame_start_left_as_truncated() -> None:
    desc = describe(spec_example())
    frame = plain_frames(desc, still_samples(1, 200.0))
    decoder = FrameDecoder(desc)
    assert len(decoder.feed(frame[:20] + frame[:20]).samples) == 0
    decoder.flush()
    assert decoder.stats.truncated == 2 and decoder.stats.garbage_bytes == 40


_SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# A CRC-32 (a false frame start passes it once in 2^32), so the garbage hypothesis draws never makes a
# frame whose check passes by chance.
_EXAMPLE_DESC = describe(spec_example(checksum={"type": "crc32", "from": 2, "to": -4, "at": -4}))
_GOOD = plain_frames(_EXAMPLE_DESC, still_samples(12, 200.0))
_FRAMES = [_GOOD[i * 28 : (i + 1) * 28] for i in range(12)]


@_SETTINGS
@given(pieces=st.lists(st.tuples(st.booleans(), st.binary(max_size=60), st.integers(0, 27)), max_size=12),
       cuts=st.lists(st.integers(0, 1200), max_size=15).map(sorted))
def test_any_chunking_and_garbage_give_exactly_the_good_frames(pieces, cuts) -> None:
    """Between the good frames: random bytes, sync-led noise or a cut good frame; fed in any chunks."""
    data = bytearray()
    for i, frame in enumerate(_FRAMES):
        if i < len(pieces):
            sync_led, noise, cut = pieces[i]
            data += (b"\xaa\x55" + noise) if sync_led else noise
            data += _FRAMES[(i + 5) % 12][:cut]
        data += frame
    decoder = FrameDecoder(_EXAMPLE_DESC)
    out, start = [], 0
    for cut in [*cuts, len(data)]:
        if cut > start:
            out.append(decoder.feed(bytes(data[start:cut])).samples)
            start = cut
    out.append(decoder.flush().samples)
    got = np.concatenate(out)
    alone = FrameDecoder(_EXAMPLE_DESC).feed(_GOOD).samples
    assert got.tobytes() == alone.tobytes()
    s = decoder.stats
    assert s.frames == 12 and s.garbage_bytes == len(data) - len(_GOOD)


@pytest.mark.parametrize("kind", [k for k in CHECKSUM_TYPES if k != "none"])
def test_a_kept_checksum_kernel_gives_fresh_values_of_any_batch_size(kind: str) -> None:
    # The decoder keeps one kernel and its work arrays; batches grow and shrink from call to call.
    rng = np.random.default_rng(7)
    kernel = RowChecksum(kind, 28)
    results = []
    for n in (128, 5, 300, 1, 128):
        rows = rng.integers(0, 256, (n, 32), dtype=np.uint8)[:, 2:30]
        got = kernel(rows)
        results.append((got, got.copy()))
        np.testing.assert_array_equal(got, checksum_rows(kind, rows))
        assert int(got[0]) == checksum(kind, rows[0].tobytes())
    for got, copy in results:  # a later call does not overwrite what an earlier one returned
        np.testing.assert_array_equal(got, copy)
