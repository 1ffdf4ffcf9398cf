"""The decoder's fast path as the reader thread drives it: table CRC, windows, chunk borders."""

from __future__ import annotations

import numpy as np
import pytest

from protocols import native
from protocols.base import SAMPLE_DTYPE
from protocols.crc import crc16_ccitt_false
from protocols.native import SAMPLE_FRAME_SIZE, NativeDecoder, decode_sample_frames, encode_samples


def samples(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.arange(n) * 1000
    s["acc"] = rng.normal(0, 9.8, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = rng.normal(25, 3, n)
    return s


def test_table_crc_of_the_fast_path_equals_the_bytewise_crc() -> None:
    rng = np.random.default_rng(2)
    payloads = rng.integers(0, 256, (3000, 40), dtype=np.uint8)
    body = np.hstack([np.tile(np.array([0x01, 40, 0], np.uint8), (3000, 1)), payloads])
    expected = np.array([crc16_ccitt_false(row.tobytes()) for row in body], dtype=np.uint16)
    table = np.bitwise_xor.reduce(native._SAMPLE_CRC_FLAT[payloads + native._TABLE_OFFSETS], axis=1)
    assert np.array_equal(table ^ native._SAMPLE_CRC_BASE, expected)


@pytest.mark.parametrize("bad", [0, 254, 255, 256, 257, 511, 512, 999])
def test_a_damaged_frame_at_any_window_position_costs_only_itself(bad: int) -> None:
    s = samples(1000, seed=bad)
    stream = bytearray(encode_samples(s))
    stream[bad * SAMPLE_FRAME_SIZE + 9] ^= 0x04  # one payload bit: a CRC error
    dec = NativeDecoder()
    got = dec.feed(bytes(stream)).samples
    assert got.tobytes() == np.delete(s, bad).tobytes()
    assert dec.stats.crc_errors == 1 and dec.stats.garbage_bytes == SAMPLE_FRAME_SIZE


def test_fast_path_returns_at_most_one_window_and_resumes() -> None:
    s = samples(700)
    stream = encode_samples(s)
    first, used = decode_sample_frames(stream)
    assert 0 < len(first) < 700 and used == len(first) * SAMPLE_FRAME_SIZE
    assert first.tobytes() == s[: len(first)].tobytes()


def test_a_clean_stream_split_after_a_crc_ending_in_a5_counts_no_garbage() -> None:
    """Regression: a frame whose CRC ends in 0xA5, cut right after it, left a phantom garbage byte."""
    s = samples(2000, seed=5)
    frames = [encode_samples(s[i:i + 1]) for i in range(len(s))]
    assert any(f.endswith(b"\xa5") for f in frames)  # the case this guards
    dec = NativeDecoder()
    got = [dec.feed(f).samples for f in frames]  # one frame per chunk, as a slow port delivers them
    assert np.concatenate(got).tobytes() == s.tobytes()
    assert dec.stats.garbage_bytes == 0 and dec.stats.resyncs == 0
