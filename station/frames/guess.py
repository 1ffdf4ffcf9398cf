"""Proposing a frame description from a raw byte capture (``imu-station frame guess``), to confirm.

Where the bytes allow it:

- the frame length is the period of the stream: the smallest lag at which the bytes repeat almost
  as often as at the best lag (the autocorrelation of byte equality; multiples of the period
  score as high);
- the sync is the longest run of byte positions that hold the same value in almost every frame;
- the checksum is found by trying every type the schema lists, in either byte order, at the
  frame's end, over each start: the one that matches the most frames, if nearly all;
- a counter is a 1-, 2- or 4-byte value that steps by one, a clock one that steps by a steady
  amount; the remaining bytes are proposed as 16-bit values in the schema's field order, in the
  byte order whose low byte varies most. Scales cannot be guessed from bytes: they stay 1 with a
  comment, for ``imu-station frame check`` to help set.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from protocols.frame_checksums import CHECKSUM_SIZES, checksum_rows
from protocols.frame_description import MAX_SYNC, REQUIRED_FIELDS
from station.common.text import PATH_CHARS, printable

MIN_LENGTH = 6
MAX_LENGTH = 256
CONSTANT = 0.95  # share of frames in which a sync byte holds its value
MATCH = 0.9  # share of frames whose checksum must match
MIN_FRAMES = 20
BLOCK = 32  # periods looked at together for constant bytes
MAX_BYTES = 256 * 1024  # of the capture; a few thousand frames say all there is to say


@dataclass
class Guess:
    """What the bytes say about their frames; ``problems`` when they say too little."""

    length: int | None = None
    score: float = 0.0
    sync: bytes = b""
    frames: int = 0
    checksum: tuple[str, int, int, int, str, int] | None = None  # type, from, to, at, byte order, matched
    seq: tuple[int, str, str, float] | None = None  # at, type, byte order, share stepping by one
    clock: tuple[int, str, str, float] | None = None  # at, type, byte order, median step
    values: list[tuple[str, int]] = field(default_factory=list)  # name, at (16-bit)
    byte_order: str = "little"
    leftover: list[int] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def frame_period(data: np.ndarray) -> tuple[int | None, float]:
    """The period of a byte stream in bytes and its score (share of equal bytes one period apart)."""
    top = min(MAX_LENGTH, len(data) // 4)
    if top < MIN_LENGTH:
        return None, 0.0
    scores = np.array([np.mean(data[:-lag] == data[lag:]) for lag in range(MIN_LENGTH, top + 1)])
    best = float(scores.max())
    if best < 0.1:
        return None, best
    lag = int(np.flatnonzero(scores >= 0.9 * best)[0]) + MIN_LENGTH
    return lag, float(scores[lag - MIN_LENGTH])


def _constant_runs(frames: np.ndarray) -> list[bytes]:
    """The values of each run of byte positions that hold one value in ``CONSTANT`` of ``frames``."""
    length = frames.shape[1]
    counts = [np.bincount(frames[:, c], minlength=256) for c in range(length)]
    constant = np.array([c.max() >= CONSTANT * len(frames) for c in counts])
    if constant.all() or not constant.any():
        return []
    runs = []
    for start in range(length):  # runs may wrap around the end of the period
        if constant[start] and not constant[start - 1]:
            run = 0
            while run < min(length, MAX_SYNC) and constant[(start + run) % length]:
                run += 1
            runs.append(bytes(int(counts[(start + i) % length].argmax()) for i in range(run)))
    return runs


def find_sync(raw: bytes, length: int) -> tuple[bytes, np.ndarray]:
    """The sync and the frames it starts.

    Runs of constant byte positions are collected from blocks of ``BLOCK`` periods (a block with
    garbage in it shifts the phase; the others do not). A sync is constant in every block, where
    the high bytes of slowly changing values (a counter's, a clock's, gravity's axis) join and
    leave the runs around them: the runs found in the most blocks are kept; of those, the ones that
    start nearly the most whole frames, and of these the one found least often in the stream.
    """
    data = np.frombuffer(raw, dtype=np.uint8)
    periods = len(data) // length
    blocks: Counter[bytes] = Counter()
    for first in range(0, max(periods - BLOCK, 0) + 1, BLOCK):
        block = data[first * length : (first + BLOCK) * length]
        blocks.update(set(_constant_runs(block[: len(block) // length * length].reshape(-1, length))))
    if not blocks:
        return b"", np.zeros((0, length), dtype=np.uint8)
    steadiest = max(blocks.values())
    found = {sync: aligned_frames(raw, sync, length) for sync, n in sorted(blocks.items()) if n == steadiest}
    most = max(len(frames) for frames in found.values())
    near = [sync for sync, frames in found.items() if len(frames) >= 0.95 * most]
    sync = max(near, key=lambda s: (-raw.count(s), len(s)))
    return sync, found[sync]


def aligned_frames(raw: bytes, sync: bytes, length: int) -> np.ndarray:
    """Every frame that starts with ``sync`` and is followed by another one ``length`` bytes on."""
    starts, at = [], raw.find(sync)
    while at >= 0 and at + length <= len(raw):
        if raw.startswith(sync, at + length) or at + length == len(raw):
            starts.append(at)
            at += length
            if not raw.startswith(sync, at):
                at = raw.find(sync, at)
        else:
            at = raw.find(sync, at + 1)
    data = np.frombuffer(raw, dtype=np.uint8)
    if not starts:
        return np.zeros((0, length), dtype=np.uint8)
    return data[np.array(starts)[:, None] + np.arange(length)]


def find_checksum(frames: np.ndarray, sync_len: int) -> tuple[str, int, int, int, str, int] | None:
    """The checksum type, covered bytes, offset and byte order that match the most frames (or None)."""
    length = frames.shape[1]
    best = None
    for kind, size in CHECKSUM_SIZES.items():
        if size == 0:
            continue
        at = length - size
        stored = {order: _column(frames, at, size, order) for order in ("little", "big")}
        for start in range(0, at):
            computed = checksum_rows(kind, frames[:, start:at]).astype(np.uint64)
            for order in ("little", "big") if size > 1 else ("little",):
                matched = int((computed == stored[order]).sum())
                # The first (widest) cover that matches wins; a CRC before a sum on a tie.
                if matched >= MATCH * len(frames) and (best is None or matched > best[5]):
                    best = (kind, start, at, at, order, matched)
    return best


def _column(frames: np.ndarray, at: int, size: int, order: str) -> np.ndarray:
    cols = frames[:, at : at + size].astype(np.uint64)
    if order == "little":
        cols = cols[:, ::-1]
    value = np.zeros(len(frames), dtype=np.uint64)
    for c in range(size):
        value = (value << np.uint64(8)) | cols[:, c]
    return value


def _steps(frames: np.ndarray, free: list[int],
           sizes: tuple[int, ...]) -> Iterator[tuple[int, int, str, np.ndarray]]:
    """Each value of ``sizes`` bytes in either byte order among the free bytes, with its steps."""
    for size in sizes:
        for at in free:
            if any(b not in free for b in range(at, at + size)):
                continue
            for order in ("little", "big") if size > 1 else ("little",):
                steps = np.mod(np.diff(_column(frames, at, size, order).astype(np.int64)), 1 << (8 * size))
                if len(steps):
                    yield at, size, order, steps


def find_counter(frames: np.ndarray, free: list[int]) -> tuple[int, str, str, float] | None:
    """The value that steps by one (wrapping) in the most frames, if nearly all: the widest on a tie
    (a 16-bit counter's low byte steps by one too)."""
    best = None
    for at, size, order, steps in _steps(frames, free, (1, 2, 4)):
        key = (round(float(np.mean(steps == 1)), 3), size)
        if key[0] >= MATCH and (best is None or key > best[0]):
            best = (key, (at, f"u{8 * size}", order, key[0]))
    return best[1] if best else None


def find_clock(frames: np.ndarray, free: list[int]) -> tuple[int, str, str, float] | None:
    """The value that steps by a steady amount (more than one) in nearly all frames: the widest."""
    best = None
    for at, size, order, steps in _steps(frames, free, (2, 4)):
        median = float(np.median(steps))
        steady = round(float(np.mean(np.abs(steps - median) <= 0.02 * median)), 3)
        if median > 1 and steady >= MATCH and (best is None or (steady, size) > best[0]):
            best = ((steady, size), (at, f"u{8 * size}", order, median))
    return best[1] if best else None


def _repeats_exactly(data: np.ndarray, length: int) -> bool:
    """Whether nearly every byte equals the one ``length`` bytes before it (no value varies)."""
    return len(data) > length and float(np.mean(data[:-length] == data[length:])) >= CONSTANT


def guess(raw: bytes) -> Guess:
    """What a raw capture's bytes say about its frames.

    Parameters
    ----------
    raw : bytes
        Bytes as the unit sent them (a few hundred frames or more).

    Returns
    -------
    Guess
        The length, sync, checksum, counter, clock and values found, and the problems met.
    """
    out = Guess()
    raw = raw[:MAX_BYTES]
    data = np.frombuffer(raw, dtype=np.uint8)
    if len(data) and (data == data[0]).all():
        # every lag "repeats" a constant stream: no period, sync or value can be told from it
        out.problems.append(f"every byte is 0x{data[0]:02x}: the stream is constant and carries no frames "
                            "(a line held idle, the unit not streaming, or the wrong baud rate?)")
        return out
    out.length, out.score = frame_period(data)
    if out.length is None:
        out.problems.append("the bytes do not repeat with any period up to 256: is this a binary stream at "
                            "the right baud rate?")
        return out
    out.sync, frames = find_sync(raw, out.length)
    if not out.sync and _repeats_exactly(data, out.length):
        out.problems.append(f"the bytes repeat exactly every {out.length} bytes: the stream carries no "
                            "varying data (a unit sending a fixed pattern?): no sync can be told from values")
        return out
    if not out.sync:
        out.problems.append(f"no byte holds its value in {CONSTANT:.0%} of the {out.length}-byte periods: "
                            "no sync")
        return out
    out.frames = len(frames)
    if out.frames < MIN_FRAMES:
        out.problems.append(f"only {out.frames} frames start with the sync; record more")
        return out
    out.checksum = find_checksum(frames, len(out.sync))
    end = out.checksum[3] if out.checksum else out.length
    free = list(range(len(out.sync), end))
    out.seq = find_counter(frames, free)
    if out.seq is not None:
        free = [b for b in free if not out.seq[0] <= b < out.seq[0] + int(out.seq[1][1:]) // 8]
    out.clock = find_clock(frames, free)
    if out.clock is not None:
        free = [b for b in free if not out.clock[0] <= b < out.clock[0] + int(out.clock[1][1:]) // 8]
    pairs = [b for b in free if b + 1 in free]
    starts: list[int] = []
    for b in pairs:
        if not starts or b >= starts[-1] + 2:
            starts.append(b)
    if starts:
        first = float(np.mean([np.unique(frames[:, b]).size for b in starts]))
        second = float(np.mean([np.unique(frames[:, b + 1]).size for b in starts]))
        out.byte_order = "little" if first >= second else "big"
    names = [*REQUIRED_FIELDS, "temp"]
    out.values = list(zip(names, starts, strict=False))
    used = {b for _, at in out.values for b in (at, at + 1)}
    out.leftover = [b for b in free if b not in used]
    if len(out.values) < len(REQUIRED_FIELDS):
        out.problems.append(f"only {len(out.values)} 16-bit values fit between the sync and the checksum; "
                            "ax..gz need 6: place the fields by hand")
    return out


def _hex_list(data: bytes) -> str:
    return "[" + ", ".join(f"0x{b:02X}" for b in data) + "]"


def to_yaml(g: Guess, source: str) -> str:
    """The proposed description as YAML, each line saying what it rests on.

    Parameters
    ----------
    g : Guess
        What :func:`guess` found (without problems).
    source : str
        The capture's name, for the header comment.

    Returns
    -------
    str
        A description of schema ``imu-station/frame/1`` for the user to confirm.
    """
    assert g.length is not None
    source = printable(source, PATH_CHARS)  # a file name: one line in a comment, whatever it holds
    varies = "first" if g.byte_order == "little" else "last"
    lines = [f"# proposed by imu-station frame guess from {source} ({g.frames} frames): check every line,",
             "# set the scales, then try it: imu-station frame check THIS.yaml --file " + source,
             "schema: imu-station/frame/1", "name: guessed",
             f"byte_order: {g.byte_order:<14} # the byte that varies most comes {varies}",
             f"sync: {_hex_list(g.sync):<20} # the same in at least {CONSTANT:.0%} of the frames",
             f"length: {g.length:<18} # the stream's period ({g.score:.0%} of bytes repeat at it)"]
    if g.checksum:
        kind, start, end, at, order, matched = g.checksum
        order_text = f", byte_order: {order}" if CHECKSUM_SIZES[kind] > 1 and order != g.byte_order else ""
        lines.append(f"checksum: {{type: {kind}, from: {start}, to: {end}, at: {at}{order_text}}}"
                     f"   # matches {matched} of {g.frames} frames")
    else:
        lines.append("# no checksum matched: without one every frame that fits is taken")
    fields = []
    if g.seq:
        at, kind, order, share = g.seq
        fields.append(f"  - {{name: seq, at: {at}, type: {kind}{_order(order, kind, g)}}}"
                      f"   # steps by one in {share:.0%} of frames")
    if g.clock:
        at, kind, order, step = g.clock
        fields.append(f"  - {{name: t, at: {at}, type: {kind}{_order(order, kind, g)}, scale: 1.0e-6}}"
                      f"   # steps by {step:g}: {1e6 / step:g} Hz if microseconds; set the scale to the tick")
    else:
        lines.append("rate_hz: 100                # no clock found: set the rate the board sends at")
    for name, at in g.values:
        fields.append(f"  - {{name: {name}, at: {at}, type: i16, scale: 1.0}}   # set the scale (per count)")
    if g.leftover:
        fields.append(f"  # bytes {', '.join(map(str, g.leftover))} are not placed")
    return "\n".join([*lines, "fields:", *fields]) + "\n"


def _order(order: str, kind: str, g: Guess) -> str:
    return f", byte_order: {order}" if kind != "u8" and order != g.byte_order else ""
