"""imu_tk's rules that the turntable-free method follows under ``FreeSettings.imu_tk()``.

The still period (whose gyro mean is the gyro bias and whose accelerometer variance sets the
detector threshold) is imu_tk's ``DataInterval::initialInterval``: samples 0..i inclusive, i the
sample whose timestamp is nearest t0 + S, a tie going to the later sample. On the irregular
timestamps of imu_tk's own Xsens session this is one sample more than S times the rate, and that
sample moves the published gyro misalignments by up to 8e-4 relative (tests/test_calib_free.py).
"""

from __future__ import annotations

import numpy as np

from station.engines.calibration.free import _still_samples


def test_imu_tk_still_period_ends_at_the_sample_nearest_t0_plus_s() -> None:
    # 100 Hz with jitter; t0 is not zero, as in the Xsens session (t0 = 0.02984 s)
    t = 0.02984 + 0.01 * np.arange(200) + np.tile([0.0, 0.0004, -0.0003, 0.0001], 50)
    for s in (0.5, 0.777, 1.2345, 1.0):
        nearest = int(np.argmin(np.abs(t - (t[0] + s))))
        assert _still_samples(t, s, inclusive=True) == nearest + 1
    # t0 + 0.5 s lies 0.3 ms after sample 50 and 10.1 ms before sample 51: 0..50 inclusive
    assert _still_samples(t, 0.5, inclusive=True) == 51


def test_a_clock_with_short_steps_puts_more_samples_in_the_period_than_s_times_the_rate() -> None:
    # steps of 10 ms with every fifth one 8 ms (median 10 ms): 0.5 s after t0 falls on sample 52, so
    # the period holds 53 samples where S / median step + 1 would count 51 (the Xsens session's case)
    steps = np.where(np.arange(1, 200) % 5 == 0, 0.008, 0.010)
    t = 0.02984 + np.concatenate([[0.0], np.cumsum(steps)])
    assert abs(t[52] - t[0] - 0.5) < 1e-9
    assert _still_samples(t, 0.5, inclusive=True) == 53


def test_a_tie_goes_to_the_later_sample_and_the_end_is_clamped() -> None:
    t = np.arange(10) * 0.25                     # exact in binary, so the midpoint is an exact tie
    assert _still_samples(t, 0.6, inclusive=True) == 3        # nearest 0.5 s: sample 2
    assert _still_samples(t, 0.625, inclusive=True) == 4      # tie between 0.5 and 0.75 s: sample 3
    assert _still_samples(t, 0.375, inclusive=True) == 3      # tie between 0.25 and 0.5 s: sample 2
    assert _still_samples(t, 100.0, inclusive=True) == 10     # beyond the record: all of it
    assert _still_samples(t, 0.01, inclusive=True) == 1       # nearest is the first sample


def test_the_station_rule_takes_the_samples_before_t0_plus_s() -> None:
    t = 0.02984 + 0.01 * np.arange(200) + np.tile([0.0, 0.0004, -0.0003, 0.0001], 50)
    for s in (0.5, 0.777, 1.2345):
        assert _still_samples(t, s, inclusive=False) == int(np.count_nonzero(t - t[0] < s))
