"""Decoders under bad input, in one run: exceptions on fuzzed inputs and good frames lost.

For every decoder of ``tests/fuzz_cases.py`` (native, Xsens in each precision and the high-rate
source, MAVLink, text lines as CSV, MotionCal and VectorNav, and ``auto``):

1. **fuzzed inputs**, each fed in random chunks and flushed, counting the exceptions raised:
   random bytes, sync-rich noise (the frame start sprinkled through random bytes), good streams
   mutated (bits flipped, bytes replaced, inserted, deleted, runs repeated, over-long
   numbers inserted), over-long numbers where a line starts) and good frames
   carrying wild values (times and counters anywhere in their range, stepping back, numbers
   at and past float limits);
2. **good frames lost** among N sent, through the project's own fault injector
   (``mocks.faults``: garbage, bit flips, cut frames, drops) and through sync-rich noise
   (cut frames and frame starts between every pair of good frames).

    .venv/bin/python benchmarks/fuzz.py [--inputs N] [--frames N] [--seed S] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import struct
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzz_cases import (  # noqa: E402
    Case,
    available_cases,
    feed_chunks,
    lost_frames,
    make_samples,
)

from mocks.faults import FaultInjector, FaultSpec  # noqa: E402
from protocols.base import SAMPLE_DTYPE  # noqa: E402

# Lines with nothing to resynchronise on but the line end (CSV): the injector's garbage and cut lines
# glue themselves to the next line, which is then lost whatever the decoder does.
LINE_FRAMED = ("ascii-csv",)


def random_cuts(rng: np.random.Generator, n: int, max_chunk: int = 97) -> list[int]:
    cuts, pos = [], 0
    while pos < n:
        pos += int(rng.integers(1, max_chunk + 1))
        cuts.append(min(pos, n))
    return cuts


def wild_samples(rng: np.random.Generator, n: int) -> np.ndarray:
    """Samples whose fields wander anywhere: times back and forth, huge counters, float limits."""
    s = make_samples(n, seed=int(rng.integers(1 << 31)))
    kind = int(rng.integers(5))
    if kind == 0:
        s["t_us"] = rng.integers(0, 1 << 63, n, dtype=np.uint64)
    elif kind == 1:  # a step back past the first sample's time
        back = rng.integers(0, 1 << 40, n - 1, dtype=np.uint64)
        s["t_us"][1:] = s["t_us"][1:] - np.minimum(s["t_us"][1:], back)
        s["t_us"][0] = int(rng.integers(0, 5_000))
    elif kind == 2:
        s["seq"] = rng.integers(0, 1 << 32, n, dtype=np.uint64).astype(np.uint32)
    extremes = np.array([0.0, -0.0, 1e-45, 3.4e38, -3.4e38, np.inf, -np.inf, np.nan, 1e30, 65504.0],
                        dtype=np.float32)
    mask = rng.random((n, 3)) < 0.3
    s["acc"][mask] = rng.choice(extremes, int(mask.sum()))
    mask = rng.random((n, 3)) < 0.3
    s["gyro"][mask] = rng.choice(extremes, int(mask.sum()))
    s["temp"][rng.random(n) < 0.3] = rng.choice(extremes)
    return s


def wild_frames(case: Case, rng: np.random.Generator) -> bytes:
    s = wild_samples(rng, int(rng.integers(2, 12)))
    try:
        with np.errstate(all="ignore"):
            return b"".join(case.frames(s))
    except (ValueError, OverflowError, struct.error):  # an encoder that refuses a value it cannot send
        return b"".join(case.frames(make_samples(len(s))))


def mutate(rng: np.random.Generator, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(int(rng.integers(1, 8))):
        if not buf:
            break
        i = int(rng.integers(len(buf)))
        op = int(rng.integers(6))
        if op == 0:
            buf[i] ^= 1 << int(rng.integers(8))
        elif op == 1:
            buf[i] = int(rng.integers(256))
        elif op == 2:
            buf[i:i] = rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8).tobytes()
        elif op == 3:
            del buf[i : i + int(rng.integers(1, 9))]
        elif op == 4:  # an over-long number, where a field starts when the input has fields
            starts = [m + 1 for m in range(len(buf)) if buf[m] in b",\n:"]
            at = starts[int(rng.integers(len(starts)))] if starts else i
            buf[at:at] = b"9" * int(rng.integers(300, 420))
        else:
            j = min(len(buf), i + int(rng.integers(1, 60)))
            buf[i:i] = buf[i:j]
    return bytes(buf)


def long_number(rng: np.random.Generator, data: bytes) -> bytes:
    """A run of 300-420 digits where a line starts (in text: the first field, often the time)."""
    starts = [0] + [m + 1 for m in range(len(data)) if data[m] in b"\n"]
    at = starts[int(rng.integers(len(starts)))]
    return data[:at] + b"9" * int(rng.integers(300, 420)) + data[at:]


def sync_rich_noise(rng: np.random.Generator, sync: bytes, size: int) -> bytes:
    out = bytearray(rng.integers(0, 256, size, dtype=np.uint8).tobytes())
    for _ in range(max(1, size // 8)):
        i = int(rng.integers(len(out) + 1))
        out[i:i] = sync
    return bytes(out)


def fuzz_input(case: Case, rng: np.random.Generator, good: list[bytes]) -> bytes:
    kind = int(rng.integers(5))
    if kind == 0:
        return rng.integers(0, 256, int(rng.integers(0, 600)), dtype=np.uint8).tobytes()
    if kind == 1:
        return sync_rich_noise(rng, case.sync, int(rng.integers(0, 400)))
    if kind == 2:
        start = int(rng.integers(len(good) - 8))
        return mutate(rng, b"".join(good[start : start + int(rng.integers(1, 8))]))
    if kind == 3:
        return wild_frames(case, rng)
    start = int(rng.integers(len(good) - 8))
    return long_number(rng, b"".join(good[start : start + int(rng.integers(1, 8))]))


def count_exceptions(case: Case, inputs: int, seed: int) -> tuple[Counter, str]:
    rng = np.random.default_rng([seed, 1])
    good = case.frames(make_samples(64, seed=seed))
    raised: Counter = Counter()
    example = ""
    for _ in range(inputs):
        data = fuzz_input(case, rng, good)
        try:
            feed_chunks(case.decoder(), data, random_cuts(rng, len(data)))
        except Exception as exc:  # the point: count what escapes, whatever it is
            raised[type(exc).__name__] += 1
            if not example:
                example = "".join(traceback.format_exception_only(exc)).strip()
    return raised, example


def losses_with_injector(case: Case, frames: int, seed: int) -> tuple[int, int]:
    good = case.frames(make_samples(frames, seed=seed))
    injector = FaultInjector(FaultSpec(garbage=0.05, garbage_max=40, bitflip=0.02, truncate=0.05, drop=0.01,
                                       seed=seed), record=True)
    data = injector.apply(good).data
    intact = injector.intact_frames()
    got = feed_chunks(case.decoder(), data, random_cuts(np.random.default_rng(seed), len(data), 4096))
    return len(lost_frames(case, intact, got)), len(intact)


def losses_in_sync_rich_noise(case: Case, frames: int, seed: int) -> tuple[int, int]:
    """Between every two good frames: a cut good frame (its header and some of its bytes) or random
    bytes full of frame starts."""
    rng = np.random.default_rng([seed, 2])
    good = case.frames(make_samples(frames, seed=seed + 1))
    pieces = []
    for frame in good:
        if rng.random() < 0.5:
            cut = good[int(rng.integers(len(good)))]
            pieces.append(cut[: int(rng.integers(1, len(cut) - 2))])  # as the injector cuts: 3+ bytes short
        else:
            pieces.append(sync_rich_noise(rng, case.sync, int(rng.integers(0, 24))))
        pieces[-1] = case.fit_garbage(pieces[-1])
        pieces.append(frame)
    data = b"".join(pieces)
    got = feed_chunks(case.decoder(), data, random_cuts(rng, len(data), 4096))
    return len(lost_frames(case, good, got)), len(good)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inputs", type=int, default=3000, help="fuzzed inputs per decoder (default 3000)")
    parser.add_argument("--frames", type=int, default=20000, help="good frames per loss test (default 20000)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--only", nargs="*", help="case names to run (default: all)")
    args = parser.parse_args(argv)
    assert SAMPLE_DTYPE.itemsize == 40
    print(f"fuzzed inputs per decoder: {args.inputs}; good frames per loss test: {args.frames}; "
          f"seed {args.seed}")
    print(f"{'decoder':18} {'inputs':>7} {'raised':>7}  {'lost/injector':>15}  {'lost/sync-rich':>15}  "
          f"{'time':>6}  exceptions")
    total_raised = total_lost = 0
    for case in available_cases():
        if args.only and case.name not in args.only:
            continue
        t0 = time.perf_counter()
        raised, example = count_exceptions(case, args.inputs, args.seed)
        lost_i, sent_i = losses_with_injector(case, args.frames, args.seed)
        lost_n, sent_n = losses_in_sync_rich_noise(case, args.frames, args.seed)
        n_raised = sum(raised.values())
        total_raised += n_raised
        total_lost += lost_n + (lost_i if case.name not in LINE_FRAMED else 0)
        kinds = ", ".join(f"{k} x{v}" for k, v in raised.most_common()) or "-"
        print(f"{case.name:18} {args.inputs:7d} {n_raised:7d}  {lost_i:6d}/{sent_i:<8d}  "
              f"{lost_n:6d}/{sent_n:<8d}  {time.perf_counter() - t0:5.1f}s  {kinds}")
        if example:
            print(f"{'':18} first: {example[:150]}")
    print(f"total: {total_raised} exceptions; {total_lost} good frames lost (CSV lines glued to garbage or a "
          f"cut line by the injector are not counted: their framing cannot recover them)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
