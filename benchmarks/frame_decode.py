"""Decode speed of a frame description's decoder (``protocols/frame.py``) beside the native one, in one run.

The frame decoder reads 32-byte frames (sync, u16 counter, u32 microsecond clock, nine i16 values
with scales and offsets, CRC-16/CCITT-FALSE); the native decoder its own 47-byte sample frames.
Both streams hold the same samples and are fed in chunks of realistic sizes (4 KiB as a serial read
returns at a few hundred kbit/s, 64 KiB as a USB-CDC port delivers in bursts), clean and with one
frame in a hundred damaged. Frames per CPU second (one core), medians of repeats; the machine may
be shared, so the two decoders are timed alternately. Target: at least 1,000,000 frames/s.

    .venv/bin/python benchmarks/frame_decode.py [--frames N] [--repeats R]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
from timing import feed_in_chunks

from protocols.base import SAMPLE_DTYPE, StreamDecoderBase
from protocols.frame import FrameDecoder, encode_frames
from protocols.frame_description import FrameDescription, describe
from protocols.native import SAMPLE_FRAME_SIZE, NativeDecoder, encode_samples

DESCRIPTION = {
    "schema": "imu-station/frame/1", "name": "bench-32", "sync": [0xAA, 0x55], "length": 32,
    "checksum": {"type": "crc16-ccitt-false"},
    "fields": [
        {"name": "seq", "at": 2, "type": "u16"},
        {"name": "t", "at": 4, "type": "u32", "scale": 1.0e-6},
        *[{"name": n, "at": 8 + 2 * i, "type": "i16", "scale": 0.0023956 if i < 3 else 0.00026632}
          for i, n in enumerate(("ax", "ay", "az", "gx", "gy", "gz"))],
        {"name": "temp", "at": 20, "type": "i16", "scale": 0.01, "offset": 25.0},
        *[{"name": n, "at": 22 + 2 * i, "type": "i16", "scale": 0.15}
          for i, n in enumerate(("mx", "my", "mz"))],
    ],
}


def make_samples(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.arange(n) * 1000
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25.0 + rng.normal(0, 1, n)
    return s


def frame_stream(desc: FrameDescription, s: np.ndarray) -> bytes:
    values = {"seq": s["seq"] % 65536, "t": (s["t_us"] % 2**32) * 1e-6, "temp": s["temp"],
              **{f"a{a}": s["acc"][:, i] for i, a in enumerate("xyz")},
              **{f"g{a}": s["gyro"][:, i] for i, a in enumerate("xyz")},
              **{f"m{a}": np.full(len(s), 20.0) for a in "xyz"}}
    return encode_frames(desc, values)


def damage(data: bytes, size: int, every: int) -> bytes:
    """Flip a byte in the middle of one frame in ``every``."""
    out = bytearray(data)
    out[size // 2 :: size * every] = bytes(b ^ 0x5A for b in out[size // 2 :: size * every])
    return bytes(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=500_000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    desc = describe(DESCRIPTION)
    samples = make_samples(args.frames)
    streams = {"frame": frame_stream(desc, samples), "native": encode_samples(samples)}
    sizes = {"frame": desc.length, "native": SAMPLE_FRAME_SIZE}
    makers: dict[str, Callable[[], StreamDecoderBase]] = {"frame": lambda: FrameDecoder(desc),
                                                          "native": NativeDecoder}
    print(f"{args.frames} frames ({desc.length}-byte description frames, {SAMPLE_FRAME_SIZE}-byte native "
          f"frames), {args.repeats} repeats, frames per CPU second (medians)")
    print(f"{'stream':<24}{'chunk':>8}{'frame decoder':>16}{'native decoder':>16}{'ratio':>8}")
    for label, every in (("clean", 0), ("1 in 100 damaged", 100)):
        data = {k: damage(v, sizes[k], every) if every else v for k, v in streams.items()}
        for chunk in (4096, 65536):
            runs = {k: feed_in_chunks(makers[k], data[k], chunk) for k in streams}
            cpu: dict[str, list[float]] = {k: [] for k in streams}
            decoded = {}
            for _ in range(args.repeats):
                for k, run in runs.items():
                    start = time.process_time()
                    decoded[k] = run()
                    cpu[k].append(time.process_time() - start)
            rate = {k: decoded[k] / statistics.median(v) for k, v in cpu.items()}
            print(f"{label:<24}{chunk:>8}{rate['frame']:>16,.0f}{rate['native']:>16,.0f}"
                  f"{rate['frame'] / rate['native']:>8.2f}")


if __name__ == "__main__":
    main()
