"""Fuzzing every stream decoder (the table in ``fuzz_cases.py``: native, Xsens in every
precision and the high-rate source, MAVLink, text lines as CSV, MotionCal and VectorNav, and
``auto``), bounded in time: a few seconds per decoder.

- arbitrary bytes, sync-rich noise and good frames carrying wild values, in arbitrary chunks,
  never raise, and the counters add up;
- good frames interleaved with garbage all come out, within what each framing can promise
  (``Case.guarantee``; ``Case.allowed_losses`` names the exceptions).

A new decoder is one line in ``fuzz_cases.CASES``; nothing here changes.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from fuzz_cases import Case, available_cases, feed_chunks, lost_frames, make_samples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE

CASES = available_cases()
IDS = [c.name for c in CASES]
FAST = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])

cuts = st.lists(st.integers(0, 2000), max_size=12).map(sorted)


def _check_counters(case: Case, data: bytes, chunk_at: list[int]) -> None:
    decoder = case.decoder()
    out = feed_chunks(decoder, data, chunk_at)
    # A nine-axis case's stream may never carry a field the decoder can read (wild values).
    assert out.dtype in ((SAMPLE_DTYPE, MAG_SAMPLE_DTYPE) if case.name.endswith("-mag") else (SAMPLE_DTYPE,))
    stats = decoder.stats
    assert stats.samples == len(out) and stats.errors >= 0 and stats.garbage_bytes <= len(data)


@pytest.mark.parametrize("case", CASES, ids=IDS)
@FAST
@given(data=st.binary(max_size=1500), chunk_at=cuts)
def test_arbitrary_bytes_never_raise(case: Case, data: bytes, chunk_at: list[int]) -> None:
    _check_counters(case, data, chunk_at)


@pytest.mark.parametrize("case", CASES, ids=IDS)
@FAST
@given(parts=st.lists(st.tuples(st.integers(0, 3), st.binary(max_size=40), st.integers(0, 7),
                                st.integers(1, 200)), max_size=20), chunk_at=cuts)
def test_sync_rich_noise_and_cut_frames_never_raise(case: Case, parts: list, chunk_at: list[int]) -> None:
    """Frame starts, cut good frames, good frames and random bytes, in any order."""
    frames = case.frames(make_samples(8))
    data = bytearray()
    for kind, noise, index, cut in parts:
        if kind == 0:
            data += case.sync + noise
        elif kind == 1:
            data += frames[index][:cut]
        elif kind == 2:
            data += frames[index]
        else:
            data += noise
    _check_counters(case, bytes(data), chunk_at)


_wild_float = st.floats(width=32, allow_nan=True, allow_infinity=True)
_wild_sample = st.tuples(st.integers(0, 2**32 - 1), st.integers(0, 2**64 - 1),
                         st.lists(_wild_float, min_size=3, max_size=3),
                         st.lists(_wild_float, min_size=3, max_size=3), _wild_float)


def _encode_wild(case: Case, rows: list[tuple]) -> bytes:
    samples = np.zeros(len(rows), dtype=SAMPLE_DTYPE)
    for i, (seq, t_us, acc, gyro, temp) in enumerate(rows):
        samples[i] = (seq, t_us, acc, gyro, temp)
    try:
        with np.errstate(all="ignore"):
            return b"".join(case.frames(samples))
    except (ValueError, OverflowError, struct.error):
        # An encoder that cannot send such numbers (MAVLink's int16 fields): keep the wild times
        # and counters, with values it can send.
        samples["acc"] = np.clip(np.nan_to_num(samples["acc"]), -100, 100)
        samples["gyro"] = np.clip(np.nan_to_num(samples["gyro"]), -10, 10)
        samples["temp"] = 25.0
        return b"".join(case.frames(samples))


@pytest.mark.parametrize("case", CASES, ids=IDS)
@FAST
@given(rows=st.lists(_wild_sample, min_size=1, max_size=12), chunk_at=cuts)
def test_good_frames_with_wild_values_never_raise(case: Case, rows: list[tuple], chunk_at: list[int]) -> None:
    """Times and counters anywhere in their range, stepping back past the first; floats at and past
    their limits: what a flipped bit under a passing checksum, or a GNSS-dated packet, looks like."""
    _check_counters(case, _encode_wild(case, rows), chunk_at)


@pytest.mark.parametrize("case", CASES, ids=IDS)
@FAST
@given(garbage=st.lists(st.one_of(st.binary(max_size=60), st.binary(max_size=8).map(lambda b: b"SYNC" + b)),
                        min_size=1, max_size=10),
       cut_from=st.lists(st.tuples(st.integers(0, 9), st.integers(1, 200)), max_size=10),
       seed=st.integers(0, 2**16), chunk_at=cuts)
def test_interleaved_garbage_loses_no_good_frame(case: Case, garbage: list[bytes], cut_from: list,
                                                 seed: int, chunk_at: list[int]) -> None:
    """Good frames with garbage before each: random bytes, frame starts, cut good frames."""
    good = case.frames(make_samples(len(garbage), seed=seed))
    pieces: list[tuple[bytes, bool]] = []
    for i, (junk, frame) in enumerate(zip(garbage, good, strict=True)):
        junk = junk.replace(b"SYNC", case.sync)
        if i < len(cut_from):
            index, cut = cut_from[i]
            source = good[index % len(good)]
            junk += source[: min(cut, len(source) - 3)]  # cut as the fault injector cuts: 3+ bytes short
        pieces.append((case.fit_garbage(junk), False))
        pieces.append((frame, True))
    data = b"".join(p for p, _ in pieces)
    got = feed_chunks(case.decoder(), data, chunk_at)
    lost = set(lost_frames(case, good, got))
    assert lost <= case.allowed_losses(pieces), f"{case.guarantee}; lost {sorted(lost)}"


def test_every_decoder_of_the_registry_is_fuzzed() -> None:
    """A decoder added to the registry without a line in the fuzz table fails here."""
    from protocols.registry import DECODERS

    fuzzed = {type(case.decoder()).__name__ for case in CASES}
    registered = {name: factory for name, factory in DECODERS.items()
                  if name != "mavlink" or any(c.needs_pymavlink for c in CASES)}
    for name, factory in registered.items():
        assert getattr(factory, "__name__", name) in fuzzed, f"{name} has no line in fuzz_cases.CASES"


@pytest.mark.parametrize("case", CASES, ids=IDS)
@FAST
@given(index=st.integers(0, 7), at=st.integers(0, 200), digits=st.integers(1, 420), chunk_at=cuts)
def test_an_over_long_number_never_raises_and_costs_text_only_its_line(
        case: Case, index: int, at: int, digits: int, chunk_at: list[int]) -> None:
    """A run of digits where a field starts (after a delimiter, or at the start of a frame): in
    text, a number past any float or integer limit. Its line gives no sample and no garbage time;
    every other line gives its own."""
    frames = case.frames(make_samples(8))
    frame = frames[index]
    # Where a field starts; before a tag ('$VN', 'Raw:'), digits would be noise glued before it.
    # A binary frame may hold no delimiter byte at all: its start is the place then.
    starts = [0] * frame[:1].isdigit() + [i + 1 for i, b in enumerate(frame) if b in b",:"] or [0]
    where = starts[at % len(starts)]
    frames[index] = frame[:where] + b"9" * digits + frame[where:]
    decoder = case.decoder()
    got = feed_chunks(decoder, b"".join(frames), chunk_at)
    if case.lines and digits > 30:  # past the float32 range of every field, time included
        expected = make_samples(8)
        assert len(got) == 7 and decoder.stats.samples == 7
        others = np.delete(np.arange(8), index)
        np.testing.assert_allclose(got["acc"], expected["acc"][others], rtol=1e-3, atol=1e-3)
