"""The MAVLink decoder's vectorised path for runs of IMU frames gives what its per-frame path gives.

The decoder with the fast path and one with it turned off decode the same streams (every IMU
message, MAVLink 1 and 2, with and without a field, other messages and sources among them,
damaged, spliced, garbage, time_boot_ms wrapping) cut at many chunk sizes: the same samples,
messages and counters (skips without pymavlink).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pymavlink", reason="pymavlink is not installed (pip install 'imu-station[mavlink]')")

from decode_helpers import feed_in_chunks  # noqa: E402

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE  # noqa: E402
from protocols.mag_batches import join_batches  # noqa: E402
from protocols.mavlink import _EMPTY_MAG, IMU_MESSAGES, MavlinkDecoder, encode_samples  # noqa: E402

CHUNKS = (1, 5, 17, 63, 64, 100, 997, 4096, 65536)


class PerFrameDecoder(MavlinkDecoder):
    """The decoder with the fast path turned off: every frame through pymavlink."""

    def _fast_run(self, pos: int) -> tuple[np.ndarray, int]:
        return _EMPTY_MAG, 0


def samples(n: int, seed: int, mag: bool, t0_us: int = 1_000_000) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=MAG_SAMPLE_DTYPE if mag else SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = t0_us + np.arange(n) * 5000
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25.0 + rng.normal(0, 1, n)
    s["temp"][::17] = np.nan
    if mag:
        s["mag"] = rng.normal(20, 10, (n, 3))
        s["mag"][5::23] = np.nan  # frames without a field among those with one
    return s


def decode(cls: type[MavlinkDecoder], data: bytes, chunk: int, source: str | None = None):
    dec = cls(source=source)
    batches, messages = feed_in_chunks(dec, data, chunk)
    for b in batches:  # every batch of a stream has one dtype from its first field on
        assert b.dtype in (SAMPLE_DTYPE, MAG_SAMPLE_DTYPE)
    joined = join_batches(batches)
    return (joined.dtype, joined.tobytes(), messages, dec.stats.as_dict(), dict(dec.messages_seen),
            dict(dec.sources_seen))


def assert_same(data: bytes, chunks=CHUNKS, source: str | None = None) -> None:
    for chunk in chunks:
        fast = decode(MavlinkDecoder, data, chunk, source)
        slow = decode(PerFrameDecoder, data, chunk, source)
        assert fast[0] == slow[0], chunk
        assert fast[1] == slow[1], chunk
        assert fast[2:] == slow[2:], chunk


def damaged(data: bytes, seed: int, flips: int = 30, cuts: int = 10, garbage: int = 10) -> bytes:
    rng = np.random.default_rng(seed)
    b = bytearray(data)
    for i in rng.integers(0, len(b), flips):
        b[int(i)] ^= int(rng.integers(1, 256))
    for _ in range(cuts):
        i = int(rng.integers(0, len(b) - 80))
        del b[i : i + int(rng.integers(1, 70))]
    for _ in range(garbage):
        i = int(rng.integers(0, len(b)))
        b[i:i] = bytes(rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8)) + b"\xfd" * int(
            rng.integers(0, 3))
    return bytes(b)


@pytest.mark.parametrize("mavlink1", [False, True])
@pytest.mark.parametrize("message", IMU_MESSAGES)
@pytest.mark.parametrize("mag", [False, True])
def test_clean_and_damaged_streams_decode_alike(message: str, mavlink1: bool, mag: bool) -> None:
    clean = encode_samples(samples(600, 1, mag), message, mavlink1=mavlink1, heartbeat_every=97)
    assert_same(clean)
    assert_same(damaged(clean, 2), chunks=(7, 64, 4096))


def test_spliced_sources_messages_and_versions_decode_alike() -> None:
    parts = [
        encode_samples(samples(300, 3, False), "HIGHRES_IMU"),
        encode_samples(samples(200, 4, True), "SCALED_IMU2", system=2),
        encode_samples(samples(300, 5, False, t0_us=2_000_000), "HIGHRES_IMU", mavlink1=True),
        encode_samples(samples(100, 6, True), "HIGHRES_IMU", component=7),
        encode_samples(samples(300, 7, True, t0_us=3_000_000), "HIGHRES_IMU", heartbeat_every=50),
        encode_samples(samples(200, 8, False), "RAW_IMU"),
    ]
    data = b"".join(parts)
    assert_same(data)
    assert_same(data, source="SCALED_IMU2")
    for seed in range(4):
        assert_same(damaged(data, seed), chunks=(3, 61, 4096, 65536))


def test_time_boot_ms_wrapping_and_stepping_back_decode_alike() -> None:
    s = samples(400, 9, False)
    s["t_us"] = ((2**32 - 200) + np.arange(400)) * 1000  # wraps past 2^32 ms in the middle
    wrap = encode_samples(s, "SCALED_IMU")
    back = samples(100, 10, False, t0_us=0)  # dated before the stream's clock zero: bad payloads
    data = encode_samples(samples(100, 11, False, t0_us=500_000), "SCALED_IMU3") + encode_samples(
        back, "SCALED_IMU3") + wrap
    assert_same(data)
    assert_same(wrap + data)


def test_trimmed_payloads_of_varying_length_decode_alike() -> None:
    s = samples(500, 12, True)
    s["acc"][::3] = 0.0  # zeros at the payload's end are trimmed: frames of several lengths
    s["mag"][::2] = np.nan
    s["temp"][::4] = np.nan
    for message in IMU_MESSAGES:
        assert_same(encode_samples(s, message), chunks=(11, 4096))


class CountingDecoder(MavlinkDecoder):
    """The decoder, counting the bad frames its runs stepped over (``_FastWindow.quiet``)."""

    stepped = 0

    def _check_window(self, pos: int):
        win = super()._check_window(pos)
        if win is not None:
            CountingDecoder.stepped += len(win.quiet)
        return win


@pytest.mark.parametrize("mavlink1", [False, True])
def test_frames_damaged_inside_decode_alike(mavlink1: bool) -> None:
    """Frames whose CRC fails, with no start inside, with MAVLink 2 starts of unknown flags (stepped over
    by a run) and with starts the per-frame path reads (a MAVLink 1 start, a MAVLink 2 one of known flags:
    the run ends there), at every place in the payload and at the end of a read."""
    data = bytearray(encode_samples(samples(1200, 13, False), "HIGHRES_IMU", mavlink1=mavlink1))
    size = len(data) // 1200
    rng = np.random.default_rng(14)
    kinds = ("flip", "v2 unknown flags", "v2 known flags", "v1 start")
    for k, frame in enumerate(range(3, 1195, 5)):
        kind = kinds[k % 4]
        at = frame * size + int(rng.integers(10, size - 3))  # in the payload: a damaged header ends a run
        if kind == "flip":
            data[at] ^= 0x5A
        else:
            data[at] = 0xFE if kind == "v1 start" else 0xFD
            data[at + 2] = 0x04 if kind == "v2 unknown flags" else 0x00
            data[at + 1] ^= 0x01  # the CRC fails whatever the bytes were
    # A run steps over a bad frame when every start inside is MAVLink 2 with flags unknown (bits but the
    # signing one), read independently here; a window's last frame is the exception (at most two here).
    damaged = list(range(3, 1195, 5))
    quiet = sum(all(data[q] == 0xFD and data[q + 2] & 0xFE for q in range(f * size + 1, (f + 1) * size)
                    if data[q] in (0xFD, 0xFE)) for f in damaged)
    assert quiet > len(damaged) // 4
    for chunk in (64, 997, 4096, 65536):
        CountingDecoder.stepped = 0
        fast = decode(CountingDecoder, bytes(data), chunk)
        slow = decode(PerFrameDecoder, bytes(data), chunk)
        assert fast[1] == slow[1] and fast[2:] == slow[2:], chunk
        assert fast[3]["crc_errors"] + fast[3]["truncated"] >= len(damaged)
    assert quiet - 2 <= CountingDecoder.stepped <= quiet
