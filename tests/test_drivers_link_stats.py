"""Link statistics: seq gaps with u32 wrap, device-clock rate, decoder counters."""

from __future__ import annotations

import numpy as np

from drivers.link_stats import SEQ_MODULUS, LinkMonitor
from protocols.base import SAMPLE_DTYPE, DecoderStats


def batch(seq: list[int] | np.ndarray, t_us: list[int] | np.ndarray) -> np.ndarray:
    s = np.zeros(len(seq), dtype=SAMPLE_DTYPE)
    s["seq"] = np.asarray(seq, dtype=np.uint64) % SEQ_MODULUS
    s["t_us"] = t_us
    return s


def test_gaps_within_and_across_batches() -> None:
    mon = LinkMonitor()
    mon.add_samples(batch([10, 11, 14, 15], [0, 1, 4, 5]))  # 12, 13 lost
    mon.add_samples(batch([20, 21], [10, 11]))  # 16..19 lost across the batch border
    assert mon.stats.samples == 6
    assert mon.stats.lost == 2 + 4
    assert mon.stats.seq_resets == 0


def test_seq_wraps_at_2_to_32_without_counting_loss() -> None:
    mon = LinkMonitor()
    top = SEQ_MODULUS - 3
    mon.add_samples(batch([top, top + 1], [0, 1]))
    mon.add_samples(batch([top + 2, top + 3, top + 4, top + 6], [2, 3, 4, 6]))  # wraps to 0, 1, then 3
    assert mon.stats.lost == 1  # only seq 2 after the wrap
    assert mon.stats.seq_resets == 0


def test_seq_going_back_is_a_reset_not_four_billion_lost() -> None:
    mon = LinkMonitor()
    mon.add_samples(batch([1000, 1001, 1002], [0, 1, 2]))
    mon.add_samples(batch([0, 1], [3, 4]))  # device restarted its counter
    assert mon.stats.lost == 0
    assert mon.stats.seq_resets == 1


def test_rate_is_measured_on_the_device_clock_over_a_recent_window() -> None:
    mon = LinkMonitor()
    # 5 s at 200 Hz, then 3 s at 400 Hz, in 100-sample batches: the window forgets the old rate.
    t = np.concatenate([np.arange(1000) * 5000, 5_000_000 + np.arange(1200) * 2500])
    for i in range(0, len(t), 100):
        mon.add_samples(batch(np.arange(i, i + 100), t[i:i + 100]))
        if i == 900:
            assert abs(mon.stats.rate_hz - 200.0) < 1e-6
    assert abs(mon.stats.rate_hz - 400.0) < 1e-6
    assert mon.stats.device_time_s == t[-1] * 1e-6


def test_decoder_counters_are_mirrored_and_summed_into_errors() -> None:
    mon = LinkMonitor()
    mon.update_decoder(DecoderStats(crc_errors=2, truncated=3, length_errors=1, bad_payloads=4, resyncs=9,
                                    garbage_bytes=77))
    mon.add_overflow(5)
    d = mon.stats.as_dict()
    assert (d["crc_errors"], d["truncated"], d["length_errors"], d["bad_payloads"]) == (2, 3, 1, 4)
    assert d["errors"] == 10 and d["resyncs"] == 9 and d["garbage_bytes"] == 77 and d["overflow_drops"] == 5



def test_seq_values_spent_on_packets_without_samples_are_not_lost() -> None:
    mon = LinkMonitor()
    batch = np.zeros(4, dtype=SAMPLE_DTYPE)
    batch["seq"] = [10, 11, 13, 16]  # three seq values missing
    batch["t_us"] = [0, 10_000, 30_000, 60_000]
    mon.add_samples(batch)
    assert mon.stats.lost == 3
    mon.update_decoder(DecoderStats(seq_skipped=2))  # two of them went to non-sample packets
    assert mon.stats.lost == 1 and mon.stats.seq_skipped == 2
    assert "2 seq skipped" in mon.stats.summary()
