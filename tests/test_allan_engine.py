"""The Allan deviation engine against allantools, published NBS14 values and its own statistics.

References: NBS14 data sets and deviations from W. J. Riley, "Handbook of Frequency Stability Analysis",
NIST SP 1065 (2008), pp. 107-108 (also Riley's "A test suite for the calculation of time domain frequency
stability", 1995); Greenhall & Riley, PTTI 2003 for the EDF; allantools 2024.6 as the independent code.
"""

from __future__ import annotations

import math
import mmap

import allantools
import numpy as np
import pytest
from allantools import ci as at_ci

from station.acquisition.allan_source import integrate_stream
from station.engines.allan import deviation as allan
from station.errors import EngineInputError

NBS14_10_FREQ = [892.0, 809.0, 823.0, 798.0, 671.0, 644.0, 883.0, 903.0, 677.0]
NBS14_10_PHASE = [0.00000, 103.11111, 123.22222, 157.33333, 166.44444, 48.55555, -96.33333, -2.22222,
                  111.88889, 0.00000]
# (tau = 1, tau = 2), SP 1065 table 31
NBS14_10_ADEV = (91.22945, 115.8082)
NBS14_10_OADEV = (91.22945, 85.95287)
# tau = 1, 10, 100, SP 1065 table 32
NBS14_1000_ADEV = (2.922319e-01, 9.965736e-02, 3.897804e-02)
NBS14_1000_OADEV = (2.922319e-01, 9.159953e-02, 3.241343e-02)


def nbs14_1000() -> np.ndarray:
    """The 1000-point set: the minimal-standard LCG n_{i+1} = 16807 n_i mod (2^31 - 1) from 1234567890."""
    n = [1234567890]
    for _ in range(999):
        n.append(16807 * n[-1] % 2147483647)
    assert n[1:4] == [395529916, 1209410747, 633705974]  # the first values the handbook prints
    return np.array(n, dtype=np.float64) / 2147483647.0


def imu_like(n: int, seed: int) -> np.ndarray:
    """Six axes: white noise + rate random walk, gyro near zero, accel with gravity on z."""
    rng = np.random.default_rng(seed)
    white = rng.standard_normal((n, 6)) * np.array([2e-3, 2e-3, 2e-3, 2e-2, 2e-2, 2e-2])
    walk = np.cumsum(rng.standard_normal((n, 6)), axis=0) * np.array([1e-6] * 3 + [1e-5] * 3)
    return white + walk + np.array([1e-3, -2e-3, 5e-4, 0.1, -0.2, 9.80665])


def test_agrees_with_allantools_oadev_to_1e12():
    rate = 200.0
    y = imu_like(60_000, seed=3)
    m = allan.cluster_sizes(len(y))
    ours = allan.overlapping_adev(y, rate, m)
    for j in range(6):
        taus, ref, _, ns = allantools.oadev(y[:, j], rate=rate, data_type="freq", taus=m / rate)
        assert np.array_equal(np.round(taus * rate).astype(int), m)
        np.testing.assert_allclose(ours[:, j], ref, rtol=1e-12, atol=0)


def test_nbs14_10_point_published_values():
    oadev = allan.overlapping_adev(np.array(NBS14_10_FREQ), 1.0, [1, 2])
    adev = allan.nonoverlapping_adev(np.array(NBS14_10_FREQ), 1.0, [1, 2])
    np.testing.assert_allclose(oadev, NBS14_10_OADEV, rtol=1e-6)
    np.testing.assert_allclose(adev, NBS14_10_ADEV, rtol=1e-6)
    # eq. (1) turns the frequency set into the published phase set (printed with 5 decimals)
    phase = allan.integrate_rates(np.array(NBS14_10_FREQ), 1.0)[0]
    np.testing.assert_allclose(phase, NBS14_10_PHASE, atol=6e-6)


def test_nbs14_1000_point_published_values():
    y = nbs14_1000()
    np.testing.assert_allclose(allan.overlapping_adev(y, 1.0, [1, 10, 100]), NBS14_1000_OADEV, rtol=1e-6)
    np.testing.assert_allclose(allan.nonoverlapping_adev(y, 1.0, [1, 10, 100]), NBS14_1000_ADEV, rtol=1e-6)


def test_cluster_sizes_log_spaced_unique_up_to_quarter():
    n = 1_234_567
    m = allan.cluster_sizes(n)
    assert m[0] == 1 and m[-1] <= n // 4 and np.all(np.diff(m) > 0)
    for decade in range(int(math.log10(n // 4))):
        inside = m[(m >= 10**decade) & (m < 10 ** (decade + 1))]
        assert len(inside) >= 9 if decade == 0 else len(inside) >= 10  # 1..9 are all the integers there
    assert len(allan.cluster_sizes(n, per_decade=20)) > 1.8 * len(m) - 20
    with pytest.raises(EngineInputError, match="too few"):
        allan.cluster_sizes(3)


def test_threads_blocks_and_memmap_give_the_same_numbers(tmp_path):
    y = imu_like(20_000, seed=5)
    m = allan.cluster_sizes(len(y))
    phase = allan.integrate_rates(y, 100.0)
    one = allan.overlapping_adev_phase(phase, 100.0, m, workers=1, block=1 << 20)
    many = allan.overlapping_adev_phase(phase, 100.0, m, workers=4, block=1000)
    np.testing.assert_allclose(many, one, rtol=1e-13)
    # streamed in uneven chunks through files on disk: the carried cumulative sum is the sequential one
    t = np.arange(len(y)) / 100.0
    cuts = [0, 1, 777, 5000, 12345, len(y)]
    chunks = [(t[a:b], y[a:b, 3:], y[a:b, :3]) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
    with integrate_stream(iter(chunks), "test", workdir=tmp_path) as rec:
        assert isinstance(rec.phase[0].base, mmap.mmap) and rec.n_samples == len(y) and rec.rate_hz == 100.0
        # the streamed mean is summed chunk by chunk: a rounding-size trend, which eq. (2) cancels
        np.testing.assert_allclose(np.array(rec.phase), phase, rtol=0, atol=1e-9 * np.abs(phase).max())
        streamed = allan.overlapping_adev_phase(rec.phase, rec.rate_hz, m)
    np.testing.assert_allclose(streamed, one, rtol=1e-11)
    assert list(tmp_path.iterdir()) == []  # temporary sums removed


def test_compiled_sums_match_long_double_sums():
    from station.engines.allan._kernel import add_block

    # a drifting rate: after the mean is removed the phase still spans far more than its second
    # differences, where forming 2 x_{i+m} or reassociating the terms would lose digits
    rng = np.random.default_rng(11)
    n = 200_000
    y = 0.3 + 1e-3 * rng.standard_normal(n) + 1e-2 * np.linspace(0.0, 1.0, n)
    x = allan.integrate_rates(y, 1000.0)[0]
    m = allan.cluster_sizes(n)
    totals = np.zeros(len(m))
    for a in range(0, len(x), 4096):  # blocks, as the engine runs them
        add_block(x, m, a, 4096, totals)
    xl = x.astype(np.longdouble)
    exact = np.array([np.sum(((xl[2 * k:] - xl[k:-k]) - (xl[k:-k] - xl[:-2 * k])) ** 2) for k in m])
    np.testing.assert_allclose(totals, exact.astype(np.float64), rtol=1e-14, atol=0)
    # a block past every cluster size's range adds nothing and says so
    before = totals.copy()
    assert add_block(x, m, len(x) - 2, 4096, totals) == 0
    np.testing.assert_array_equal(totals, before)


@pytest.mark.parametrize("alpha", [1, 0, -1, -2])
def test_greenhall_edf_matches_allantools(alpha):
    for n_phase in (50, 1001, 100_001, 3_000_001):
        for m in (1, 2, 5, 10, 20, 33, 34, 60, 300, 5000, n_phase // 5, n_phase // 4):
            if not 1 <= m or 2 * m >= n_phase:
                continue
            ref = at_ci.edf_greenhall(alpha, 2, m, n_phase, overlapping=True)
            assert allan.greenhall_edf(alpha, m, n_phase) == pytest.approx(ref, rel=1e-12)


def test_white_phase_edf_closed_form_equals_greenhall_sums():
    """alpha = 2: the closed form equals Greenhall's case 4 where that applies and his eq. (10) always."""
    for n_phase in (40, 101, 1000, 10_001):
        for m in (1, 2, 3, 7, 12, 20, n_phase // 5, n_phase // 4):
            if 2 * m >= n_phase:
                continue
            big_m = n_phase - 2 * m
            j = min(big_m, 3 * m)
            sz0 = float(allan._sz(np.array(0.0), m, 2))
            exact = 1.0 / (allan._basic_sum(j, big_m, m, m, 2) / (sz0**2 * big_m))
            assert allan.greenhall_edf(2, m, n_phase) == pytest.approx(exact, rel=1e-9)
            if math.ceil(big_m / m) > 2:
                ref = at_ci.edf_greenhall(2, 2, m, n_phase, overlapping=True)
                assert allan.greenhall_edf(2, m, n_phase) == pytest.approx(ref, rel=1e-12)


def test_edf_predicts_the_scatter_of_simulated_white_noise():
    """var(sigma_hat^2) = 2 sigma^4 / edf: 600 white-noise records, three cluster sizes, within 15 %."""
    rng = np.random.default_rng(11)
    n, runs = 3000, 600
    m = np.array([1, 30, 300])
    adev = allan.overlapping_adev(rng.standard_normal((n, runs)), 1.0, m)
    avar = adev**2
    measured = 2.0 * avar.mean(axis=1) ** 2 / avar.var(axis=1, ddof=1)
    predicted = np.array([allan.greenhall_edf(0, int(k), n + 1) for k in m])
    np.testing.assert_allclose(measured, predicted, rtol=0.15)
    np.testing.assert_allclose(avar.mean(axis=1), 1.0 / m, rtol=0.05)  # white: sigma^2 = 1 / tau


def test_confidence_interval_matches_allantools():
    adev = np.array([1.0, 2e-3, 5.0])
    edf = np.array([3.5, 120.0, 1e5])
    lo, hi = allan.confidence_interval(adev, edf)
    for i in range(3):
        ref_lo, ref_hi = at_ci.confidence_interval(adev[i], edf[i])
        assert lo[i] == pytest.approx(ref_lo, rel=1e-12) and hi[i] == pytest.approx(ref_hi, rel=1e-12)
        assert lo[i] < adev[i] < hi[i]


def test_alpha_from_slope_reads_power_laws():
    tau = np.geomspace(0.01, 1000, 51)
    sig = np.column_stack([tau**-1.0, tau**-0.5, tau**0.0, tau**0.5, tau**1.0])
    assert allan.alpha_from_slope(tau, sig)[10].tolist() == [2, 0, -1, -2, -2]


def test_curve_and_refusals():
    y = imu_like(5000, seed=1)
    curve = allan.allan_curve(allan.integrate_rates(y, 50.0), 50.0, ("gx", "gy", "gz", "ax", "ay", "az"))
    assert curve.adev.shape == curve.edf.shape == (len(curve.m), 6)
    assert np.all(curve.ci_low < curve.adev) and np.all(curve.adev < curve.ci_high)
    assert np.array_equal(curve.n, 5001 - 2 * curve.m) and curve.duration_s == 100.0
    with pytest.raises(EngineInputError, match="cluster sizes must lie"):
        allan.overlapping_adev(y, 50.0, [2600])
    with pytest.raises(EngineInputError, match="too few"):
        allan.allan_curve(allan.integrate_rates(y[:10], 50.0), 50.0, ["gx"] * 6)
    with pytest.raises(ValueError, match="alpha"):
        allan.greenhall_edf(-3, 10, 1000)


def test_non_finite_samples_are_refused_with_their_time(tmp_path):
    t = np.arange(2000) / 100.0
    gyro = np.zeros((2000, 3))
    gyro[1500, 1] = np.nan
    with pytest.raises(EngineInputError, match=r"t = 15\.000000 s has a non-finite gy"):
        integrate_stream(iter([(t, np.zeros((2000, 3)), gyro)]), "x.bag", workdir=tmp_path)
    assert list(tmp_path.iterdir()) == []
