"""The Xsens decoder's vectorised path for runs of like MTData2 packets gives what its per-packet path
gives.

The decoder and one with the runs turned off decode the same streams (every precision, with and without
temperature and a field, spliced layouts, damaged: bytes flipped, cut, garbage with frame starts) cut at
many chunk sizes: the same samples, messages and counters.
"""

from __future__ import annotations

import numpy as np
import pytest
from decode_helpers import feed_in_chunks

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE
from protocols.mag_batches import join_batches
from protocols.xsens import PREAMBLE, XsensDecoder, encode_samples

CHUNKS = (1, 7, 54, 100, 997, 4096, 65536)


class PerPacketDecoder(XsensDecoder):
    """The decoder with the vectorised runs turned off: every packet through ``_on_packet``."""

    def _sample_run(self, pos: int) -> tuple[np.ndarray, int] | None:
        return None


def samples(n: int, seed: int, mag: bool) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=MAG_SAMPLE_DTYPE if mag else SAMPLE_DTYPE)
    s["seq"] = np.arange(n) + 65_000  # the packet counter wraps past 2^16
    s["t_us"] = 1_000_000 + np.arange(n) * 2500
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25.0 + rng.normal(0, 1, n)
    if mag:
        s["mag"] = rng.normal(20, 10, (n, 3))
    return s


def decode(cls: type[XsensDecoder], data: bytes, chunk: int):
    dec = cls()
    batches, messages = feed_in_chunks(dec, data, chunk)
    joined = join_batches(batches)
    return (joined.dtype, joined.tobytes(), messages, dec.stats.as_dict(), dict(dec.items_seen),
            dict(dec.message_ids_seen))


def assert_same(data: bytes, chunks=CHUNKS) -> None:
    for chunk in chunks:
        fast = decode(XsensDecoder, data, chunk)
        slow = decode(PerPacketDecoder, data, chunk)
        assert fast[0] == slow[0], chunk
        assert fast[1] == slow[1], chunk
        assert fast[2:] == slow[2:], chunk


def damaged(data: bytes, seed: int) -> bytes:
    rng = np.random.default_rng(seed)
    b = bytearray(data)
    for i in rng.integers(0, len(b), 30):
        b[int(i)] ^= int(rng.integers(1, 256))
    for _ in range(8):
        i = int(rng.integers(0, len(b) - 80))
        del b[i : i + int(rng.integers(1, 60))]
    for _ in range(8):
        i = int(rng.integers(0, len(b)))
        noise = rng.integers(0, 256, int(rng.integers(1, 30)), dtype=np.uint8)
        b[i:i] = bytes(noise) + bytes([PREAMBLE, 0xFF])  # and a frame start
    return bytes(b)


@pytest.mark.parametrize("precision", ["float32", "fp1220", "fp1632", "float64"])
@pytest.mark.parametrize("mag", [False, True])
def test_clean_and_damaged_streams_decode_alike(precision: str, mag: bool) -> None:
    clean = encode_samples(samples(700, 1, mag), precision=precision)
    assert decode(XsensDecoder, clean, 4096)[3]["samples"] == 700
    assert_same(clean)
    assert_same(damaged(clean, 2), chunks=(7, 64, 4096))


def test_spliced_layouts_decode_alike() -> None:
    parts = [
        encode_samples(samples(300, 3, False)),
        encode_samples(samples(200, 4, False), temperature=False),  # another layout, the same first item
        encode_samples(samples(300, 5, True), precision="float64"),
        encode_samples(samples(200, 6, False), deltas=True),
        encode_samples(samples(300, 7, False)),
    ]
    data = b"".join(parts)
    assert_same(data)
    for seed in range(3):
        assert_same(damaged(data, seed), chunks=(3, 61, 4096, 65536))


class RunCounting(XsensDecoder):
    """The decoder, counting the samples its vectorised runs gave."""

    def __init__(self) -> None:
        super().__init__()
        self.in_runs = 0

    def _sample_run(self, pos: int) -> tuple[np.ndarray, int] | None:
        run = super()._sample_run(pos)
        self.in_runs += 0 if run is None else len(run[0])
        return run


def test_a_new_layout_of_the_same_size_is_read_in_runs() -> None:
    """float32 then FP12.20: frames of one size, the same first item, other item ids. The run's layout is
    found again for the second part (not only the first's tried, and every frame left to the per-packet
    path), and both paths still decode alike."""
    data = encode_samples(samples(400, 8, False)) + encode_samples(samples(400, 9, False), precision="fp1220")
    dec = RunCounting()
    batches, _ = feed_in_chunks(dec, data, 4096)
    assert sum(len(b) for b in batches) == 800
    assert dec.in_runs >= 700  # the frames at the end of a read, too few for a run, go the per-packet path
    assert_same(data, chunks=(97, 4096))
