"""The vectorised dT filter against the sample-by-sample recursion firmware runs, and scipy's lfilter."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from station.engines.thermal.model import DtempFilter, estimate_dtemp


def firmware_loop(t_s: np.ndarray, temp: np.ndarray, tau_s: float) -> np.ndarray:
    """The DtempFilter recursion written out sample by sample, as the C export runs it."""
    out = np.zeros_like(temp)
    tf, d = temp[0], 0.0
    for i in range(1, len(temp)):
        dt = t_s[i] - t_s[i - 1]
        if dt <= 0:
            out[i] = d
            continue
        alpha = dt / (tau_s + dt)
        tf_new = tf + alpha * (temp[i] - tf)
        d += alpha * ((tf_new - tf) / dt - d)
        tf = tf_new
        out[i] = d
    return out


@pytest.mark.parametrize("tau_s", [0.002, 0.3, 5.0, 40.0, 2000.0])
def test_matches_the_sample_loop_with_jittered_and_repeated_timestamps(tau_s: float) -> None:
    rng = np.random.default_rng(7)
    n = 30_000
    t = np.cumsum(rng.uniform(0.004, 0.006, n))
    t[1000] = t[999]  # a repeated timestamp: state kept, last dT repeated
    t[2000] = t[1999] - 0.001  # a step back in time: the same
    temp = 25 + 10 * np.sin(t / 40.0) + rng.normal(0, 0.01, n)
    fast = estimate_dtemp(t, temp, DtempFilter("ema", tau_s))
    slow = firmware_loop(t, temp, tau_s)
    # Rounding only: far below what a float32 firmware resolves.
    assert np.max(np.abs(fast - slow)) <= 1e-9 * np.max(np.abs(slow))
    assert fast[1000] == fast[999] and fast[2000] == fast[1999]


def test_constant_rate_equals_two_lfilter_stages() -> None:
    """An independent formulation: the same two first-order stages as scipy.signal.lfilter."""
    rng = np.random.default_rng(3)
    dt, tau = 0.01, 7.5
    t = np.arange(20_000) * dt
    temp = 20 + 0.05 * t + rng.normal(0, 0.02, len(t))
    alpha = dt / (tau + dt)
    tf, _ = lfilter([alpha], [1, -(1 - alpha)], temp[1:], zi=[(1 - alpha) * temp[0]])
    tf = np.concatenate([[temp[0]], tf])
    d, _ = lfilter([alpha], [1, -(1 - alpha)], np.diff(tf) / dt, zi=[0.0])
    ours = estimate_dtemp(t, temp, DtempFilter("ema", tau))
    np.testing.assert_allclose(ours[1:], d, rtol=0, atol=1e-12)


def test_settles_on_the_true_rate_of_a_ramp() -> None:
    t = np.arange(0, 600, 0.1)
    temp = 10 + 0.02 * t
    d = estimate_dtemp(t, temp, DtempFilter("ema", 10.0))
    assert d[0] == 0.0
    assert abs(d[-1] - 0.02) < 1e-9  # after 60 time constants
    assert np.max(d) <= 0.02 + 1e-12  # two first-order stages: no overshoot


def test_short_inputs() -> None:
    f = DtempFilter("ema", 5.0)
    assert estimate_dtemp(np.array([]), np.array([]), f).shape == (0,)
    np.testing.assert_array_equal(estimate_dtemp(np.array([1.0]), np.array([20.0]), f), [0.0])


def test_unknown_readings_count_as_the_last_known_one() -> None:
    """As the firmware filter: NaN holds the last reading; the filter starts at the first known one."""
    t = np.arange(10.0)
    with_gaps = np.array([np.nan, np.nan, 20, 21, np.nan, 23, 24, 25, np.nan, 27.0])
    held = np.array([20, 20, 20, 21, 21, 23, 24, 25, 25, 27.0])
    filt = DtempFilter("ema", 2.0)
    assert np.array_equal(estimate_dtemp(t, with_gaps, filt), estimate_dtemp(t, held, filt))
    assert not estimate_dtemp(t, np.full(10, np.nan), filt).any()
