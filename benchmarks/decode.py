"""Decode speed of the native protocol: the station's decoder against a per-frame struct.unpack loop.

Decodes a 1,000,000-sample native stream fed in chunks of realistic sizes (4 KiB as a serial
read returns at a few hundred kbit/s, 64 KiB as a USB-CDC port delivers in bursts), on one core,
and prints samples per CPU second (median of repeats) and the ratio to the peer: a plain Python loop that
checks each frame's sync, length and CRC (table-driven, ``protocols.crc``) and unpacks it with
``struct.unpack_from``. Target: at least 1,000,000 samples/s.

    .venv/bin/python benchmarks/decode.py [--samples N] [--repeats R]
"""

from __future__ import annotations

import argparse
import statistics
import struct
import time

import numpy as np

from protocols.base import SAMPLE_DTYPE
from protocols.crc import crc16_ccitt_false
from protocols.native import SAMPLE_FRAME_SIZE, NativeDecoder, encode_samples

_HEADER = struct.Struct("<2sBH")
_PAYLOAD = struct.Struct("<IQ7f")
_CRC = struct.Struct("<H")


def make_stream(n: int, damaged_every: int = 0) -> bytes:
    rng = np.random.default_rng(0)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.arange(n) * 1000
    s["acc"] = rng.normal(0, 9.8, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25.0
    data = bytearray(encode_samples(s))
    if damaged_every:
        for i in range(0, n, damaged_every):  # one flipped payload bit: a CRC error to resync over
            data[i * SAMPLE_FRAME_SIZE + 20] ^= 0x10
    return bytes(data)


def decode_station(stream: bytes, chunk: int) -> int:
    dec = NativeDecoder()
    n = 0
    for i in range(0, len(stream), chunk):
        n += len(dec.feed(stream[i:i + chunk]).samples)
    return n


def decode_struct_loop(stream: bytes, chunk: int) -> int:
    """The peer: one frame at a time with struct, resyncing byte by byte on a bad frame."""
    buf = bytearray()
    out = []
    for i in range(0, len(stream), chunk):
        buf += stream[i:i + chunk]
        pos = 0
        while len(buf) - pos >= SAMPLE_FRAME_SIZE:
            sync, msg_id, length = _HEADER.unpack_from(buf, pos)
            if sync != b"\xa5\x5a" or msg_id != 1 or length != 40:
                pos += 1
                continue
            (crc,) = _CRC.unpack_from(buf, pos + 45)
            if crc16_ccitt_false(bytes(buf[pos + 2:pos + 45])) != crc:
                pos += 1
                continue
            out.append(_PAYLOAD.unpack_from(buf, pos + 5))
            pos += SAMPLE_FRAME_SIZE
        del buf[:pos]
    return len(out)


def rate(fn, stream: bytes, chunk: int, repeats: int) -> tuple[float, int]:
    """Samples per second of this process's CPU time (median of repeats): what one core does, even
    when other processes share the machine and stretch the wall clock."""
    times, n = [], 0
    for _ in range(repeats):
        t0 = time.process_time()
        n = fn(stream, chunk)
        times.append(time.process_time() - t0)
    return n / statistics.median(times), n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--peer-samples", type=int, default=50_000,
                        help="samples for the (slow) peer loop; its rate is per sample, so a subset suffices")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    size_mb = args.samples * SAMPLE_FRAME_SIZE / 1e6
    print(f"native protocol decode, {args.samples} samples ({size_mb:.0f} MB), median of {args.repeats} "
          f"repeats, one core")
    print(f"{'stream':<24}{'chunk':>8}{'station samples/s':>20}{'struct loop samples/s':>24}{'ratio':>8}")
    for label, damaged_every in (("clean", 0), ("1% damaged frames", 100)):
        stream = make_stream(args.samples, damaged_every)
        peer_stream = stream[: args.peer_samples * SAMPLE_FRAME_SIZE]
        for chunk in (4096, 65536):
            ours, n = rate(decode_station, stream, chunk, args.repeats)
            peer, n_peer = rate(decode_struct_loop, peer_stream, chunk, max(1, args.repeats // 2))
            expected = args.samples - (len(range(0, args.samples, damaged_every)) if damaged_every else 0)
            assert n == expected, (n, expected)
            print(f"{label:<24}{chunk:>8}{ours:>20,.0f}{peer:>24,.0f}{ours / peer:>7.1f}x")


if __name__ == "__main__":
    main()
