"""Fault injection: the injector reports exactly the frames it left intact, whatever the blocking.

The check is end to end through the station's own native decoder: decoding the faulty stream
must give exactly the intact frames, in order, bit-exact, and nothing else.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.faults import FaultInjector, FaultSpec
from mocks.rig import Static, simulate
from mocks.truth import UnitTruth
from protocols.native import NativeDecoder, encode_samples

SAMPLES = simulate(UnitTruth.random(1), [Static("+z", 4.0)], rate_hz=500, seed=1).samples()
FRAMES = [encode_samples(SAMPLES[i : i + 1]) for i in range(len(SAMPLES))]


def run(spec: FaultSpec, blocks: list[int] | None = None, record: bool = True) -> tuple[FaultInjector, bytes]:
    injector = FaultInjector(spec, record=record)
    out = bytearray()
    start = 0
    for size in blocks or [len(FRAMES)]:
        out += injector.apply(FRAMES[start : start + size]).data
        start += size
    return injector, bytes(out)


def decode(data: bytes, chunk: int = 997) -> tuple[np.ndarray, NativeDecoder]:
    dec = NativeDecoder()
    parts = [dec.feed(data[i : i + chunk]).samples for i in range(0, len(data), chunk)]
    parts.append(dec.flush().samples)
    return np.concatenate(parts), dec


@pytest.mark.parametrize("spec", [
    FaultSpec(garbage=0.05, seed=1),
    FaultSpec(bitflip=0.05, seed=2),
    FaultSpec(truncate=0.05, seed=3),
    FaultSpec(drop=0.05, seed=4),
    FaultSpec(garbage=0.05, bitflip=0.03, truncate=0.03, drop=0.03, garbage_max=64, seed=5),
], ids=["garbage", "bitflip", "truncate", "drop", "all"])
def test_decoder_gets_exactly_the_intact_frames(spec: FaultSpec) -> None:
    injector, data = run(spec)
    decoded, dec = decode(data)
    intact = injector.intact_indices()
    np.testing.assert_array_equal(decoded, SAMPLES[intact])
    assert b"".join(injector.intact_frames()) == b"".join(FRAMES[i] for i in intact)
    c = injector.counts
    assert c.frames == len(FRAMES)
    assert c.intact + c.dropped + c.truncated + c.bitflips == c.frames
    assert c.intact == len(intact)
    assert (c.intact < len(FRAMES)) == bool(spec.bitflip or spec.truncate or spec.drop)
    if spec.garbage:
        assert c.garbage_runs > 0 and dec.stats.garbage_bytes >= c.garbage_bytes
    if spec.bitflip or spec.truncate:
        assert dec.stats.errors > 0


def test_fault_rates_match_their_probabilities() -> None:
    spec = FaultSpec(garbage=0.1, drop=0.05, truncate=0.05, bitflip=0.1, seed=7)
    injector, _ = run(spec)
    n = len(FRAMES)
    c = injector.counts
    for count, p in ((c.garbage_runs, 0.1), (c.dropped, 0.05), (c.truncated, 0.05), (c.bitflips, 0.1)):
        assert abs(count - p * n) < 5 * np.sqrt(n * p * (1 - p))  # 5 sigma of a binomial


def test_faults_do_not_depend_on_block_sizes() -> None:
    spec = FaultSpec(garbage=0.05, bitflip=0.02, truncate=0.02, drop=0.02, stall=0.01, seed=9)
    whole_injector, whole = run(spec)
    rng = np.random.default_rng(0)
    sizes = list(rng.integers(0, 40, 200))
    sizes.append(len(FRAMES) - sum(sizes))
    parts_injector, parts = run(spec, sizes)
    assert parts == whole
    np.testing.assert_array_equal(parts_injector.intact_indices(), whole_injector.intact_indices())
    assert parts_injector.counts == whole_injector.counts


def test_disconnect_after_bytes_cuts_the_link_there() -> None:
    spec = FaultSpec(garbage=0.05, disconnect_after_bytes=10_000, seed=3)
    injector, data = run(spec, [300, 300, len(FRAMES) - 600])
    assert len(data) == 10_000
    assert injector.disconnected
    decoded, _ = decode(data)
    np.testing.assert_array_equal(decoded, SAMPLES[injector.intact_indices()])
    assert injector.apply(FRAMES[:5]).data == b""  # nothing after the end of the link


def test_stalls_are_reported_per_block() -> None:
    injector = FaultInjector(FaultSpec(stall=1.0, stall_s=0.25))
    out = injector.apply(FRAMES[:3])
    assert out.stall_s == pytest.approx(0.75)
    assert out.data == b"".join(FRAMES[:3])


def test_protected_frames_pass_untouched() -> None:
    injector = FaultInjector(FaultSpec(drop=1.0))
    out = injector.apply(FRAMES[:4], protected=[False, True, False, True])
    assert out.data == FRAMES[1] + FRAMES[3]
    np.testing.assert_array_equal(injector.intact_indices(), [1, 3])


def test_without_record_no_frame_bytes_are_kept() -> None:
    injector, _ = run(FaultSpec(drop=0.1), record=False)
    assert len(injector.intact_indices()) > 0
    with pytest.raises(ValueError, match="record=False"):
        injector.intact_frames()


def test_spec_parsing() -> None:
    spec = FaultSpec.parse("garbage=0.01, drop=0.002,stall=0.1,stall_s=0.5,disconnect_s=3,"
                           "disconnect_bytes=900,seed=4")
    assert spec == FaultSpec(garbage=0.01, drop=0.002, stall=0.1, stall_s=0.5, disconnect_after_s=3.0,
                             disconnect_after_bytes=900, seed=4)
    assert FaultSpec.parse(spec.describe()) == spec
    assert not FaultSpec.parse("").active and FaultSpec().describe() == "none"
    for bad, message in (("garbage", "NAME=VALUE"), ("noise=0.1", "NAME=VALUE"),
                         ("drop=lots", "not a number"), ("drop=1.5", r"\[0, 1\]"),
                         ("drop=0.6,bitflip=0.6", "exceed")):
        with pytest.raises(ValueError, match=message):
            FaultSpec.parse(bad)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), garbage=st.floats(0, 0.3), bitflip=st.floats(0, 0.2),
       truncate=st.floats(0, 0.2), drop=st.floats(0, 0.2), chunk=st.integers(7, 500))
def test_any_faults_any_split_give_exactly_the_intact_frames(seed: int, garbage: float, bitflip: float,
                                                            truncate: float, drop: float, chunk: int) -> None:
    spec = FaultSpec(garbage=garbage, bitflip=bitflip, truncate=truncate, drop=drop, seed=seed)
    injector = FaultInjector(spec)
    data = injector.apply(FRAMES[:150]).data
    decoded, _ = decode(data, chunk)
    np.testing.assert_array_equal(decoded, SAMPLES[injector.intact_indices()])
