"""Noise identification: terms injected into simulated records are recovered within stated tolerances; the
exact likelihood of N and K is checked against a brute-force dense Gaussian likelihood and its own scatter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize, stats
from scipy.signal import lfilter

from mocks.rig import Static, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from station.engines.allan.deviation import allan_curve, integrate_rates
from station.engines.allan.fit import B_FACTOR, ML_METHOD, TERMS, fit_axis, identify_noise, model_avar
from station.engines.allan.likelihood import (
    autocovariance,
    block_length,
    negative_log_likelihood,
    white_walk_ml,
)
from station.export.params.noise import noise_section

ML = ML_METHOD


def analyse(y: np.ndarray, rate: float, axes: tuple[str, ...] = ("gx",)):
    """The command's pipeline: cumulative sums, curve, IEEE 952 fit, then the likelihood of K."""
    phase = integrate_rates(y, rate)
    return identify_noise(allan_curve(phase, rate, axes), phase)


def white_and_walk(rng: np.random.Generator, n: int, rate: float, n_density: float, k_density: float,
                   runs: int = 1) -> np.ndarray:
    """White noise N sqrt(rate) per sample plus a rate random walk of step K sqrt(dt)."""
    white = rng.standard_normal((n, runs)) * n_density * math.sqrt(rate)
    walk = np.cumsum(rng.standard_normal((n, runs)) * k_density / math.sqrt(rate), axis=0)
    return white + walk


# Both readings of "the white-noise and random-walk lines cross near 170 s" (2 h at 200 Hz, N = 1e-3). The
# Cramer-Rao bound on log K (exact Gaussian Fisher information of the record, see the README) leaves an
# efficient estimator within 25 % in 86.5 % of runs for the first, 74 % for the second: 90 % is out of
# reach for both. Over 100 seeds the likelihood alone gives 86 %, the reported K 84 % (median error 11 %
# against the Allan-curve fit's 15 %) for the first.
READINGS = {  # K / N, runs within 25 % at least, median |error| below
    # N^2 / tau = K^2 tau / 3 at 170 s: the IEEE 952 lines of the Allan variance
    "variance lines": (math.sqrt(3.0) / 170.0, 16, 0.18),
    # N / sqrt(tau) = K sqrt(tau) at 170 s: K read off the deviation without the 1/3
    "deviation without 1/3": (1.0 / 170.0, 9, 0.30),
}


@pytest.mark.parametrize("reading", READINGS)
def test_monte_carlo_white_noise_and_random_walk(reading):
    """20 records of 2 h at 200 Hz; N within 1 % in every run, K within 25 % in what the bound allows.

    Seeds 0..19 give 18/20, median 15 % (first reading) and 11/20, median 20 % (second: the crossing,
    294 s, is near T/20 = 360 s, and the fit's T/20 rule nulls K in some runs); the asserted counts are
    what the bound and the rule leave likely (86.5 % of 20 is 17.3 on average; 100 seeds of the second
    give 56 %), not what these seeds happen to give.
    """
    ratio, at_least, median = READINGS[reading]
    rate, n_density = 200.0, 1e-3
    k_density = ratio * n_density
    n = int(2 * 3600 * rate)
    n_err, k_err, by_likelihood = [], [], 0
    for seed in range(20):
        y = white_and_walk(np.random.default_rng(seed), n, rate, n_density, k_density)[:, 0]
        _, (noise,) = analyse(y, rate)
        n_err.append(noise.value("N") / n_density - 1.0)
        k = noise.value("K")
        k_err.append(math.inf if k is None else k / k_density - 1.0)
        by_likelihood += k is not None and ML in noise.terms["K"].method
    k_err = np.abs(k_err)
    # the likelihood gives K wherever the fit shows it, but for the few runs where the two differ by more
    # than 15 % (2 to 3 % of runs on this model)
    assert by_likelihood >= np.count_nonzero(np.isfinite(k_err)) - 2
    assert np.all(np.abs(n_err) < 0.01)
    assert np.count_nonzero(k_err < 0.25) >= at_least
    assert np.median(k_err) < median


def test_likelihood_recovers_n_and_k_from_a_long_record():
    """20 h at 10 Hz (one sample per block), lines crossing at 170 s: f_c T = 117, sd(log K) = 0.05."""
    rate, n_density = 10.0, 1e-3
    k_density = math.sqrt(3.0) * n_density / 170.0
    y = white_and_walk(np.random.default_rng(11), int(20 * 3600 * rate), rate, n_density, k_density)[:, 0]
    ml = white_walk_ml(integrate_rates(y, rate)[0], rate)
    assert ml.block == 1 and not ml.at_bound
    assert ml.n == pytest.approx(n_density, rel=0.005)
    assert ml.k == pytest.approx(k_density, rel=0.15)
    assert ml.k_stddev / ml.k == pytest.approx(0.05, rel=0.2)
    assert ml.crossing_tau_s == pytest.approx(170.0, rel=0.15)


def test_likelihood_one_sigma_agrees_with_its_monte_carlo_scatter():
    """60 records of 1 h at 20 Hz: the reported 1-sigma of log K (observed Fisher information) against the
    scatter of log K over the runs, within 30 % (the sample scatter itself is known to 9 %)."""
    rate, n_density, crossing = 20.0, 1e-3, 60.0
    k_density = math.sqrt(3.0) * n_density / crossing
    n = int(3600 * rate)
    block = block_length(n, rate, crossing)  # as the pipeline sizes them: a 200th of the crossing tau
    log_k, sd_log_k = [], []
    for seed in range(60):
        y = white_and_walk(np.random.default_rng(100 + seed), n, rate, n_density, k_density)[:, 0]
        ml = white_walk_ml(integrate_rates(y, rate)[0], rate, block)
        log_k.append(math.log(ml.k / k_density))
        sd_log_k.append(ml.k_stddev / ml.k)
    scatter = float(np.std(log_k, ddof=1))
    assert np.mean(sd_log_k) == pytest.approx(scatter, rel=0.3)
    assert abs(np.mean(log_k)) < 3.0 * scatter / math.sqrt(60)  # no bias beyond its own noise


def test_block_mean_increments_have_the_moving_average_covariance():
    """Eq. (1) of allan_ml against the covariance of the samples pushed through block means and a
    difference by brute force: white sigma^2 I plus random walk q min(i, j)."""
    block, blocks, sigma2, q = 5, 12, 0.7, 0.03
    n = block * blocks
    i = np.arange(n)
    cov_y = sigma2 * np.eye(n) + q * (np.minimum.outer(i, i) + 1.0)
    means = np.kron(np.eye(blocks), np.full(block, 1.0 / block))
    diff = np.eye(blocks - 1, blocks, 1) - np.eye(blocks - 1, blocks)
    m = diff @ means
    cov_z = m @ cov_y @ m.T
    gamma0, gamma1 = autocovariance(sigma2, q, block)
    expected = gamma0 * np.eye(blocks - 1) + gamma1 * (np.eye(blocks - 1, k=1) + np.eye(blocks - 1, k=-1))
    np.testing.assert_allclose(cov_z, expected, rtol=1e-12, atol=1e-12)


def test_likelihood_matches_a_brute_force_dense_gaussian_likelihood():
    """300 block means: scipy's multivariate normal on the dense covariance, minimised by Nelder-Mead,
    gives the same N and K to 1e-4 and the same curvature (1-sigma) to 2 %."""
    rate, n_density, block = 10.0, 1e-3, 1
    k_density = math.sqrt(3.0) * n_density / 10.0
    y = white_and_walk(np.random.default_rng(3), 300 * block + 1, rate, n_density, k_density)[:, 0]
    phase = integrate_rates(y, rate)[0]
    ml = white_walk_ml(phase, rate, block=block)
    z = np.diff(np.diff(phase[::block]) * rate / block)
    n = len(z)

    def dense_nll(p: np.ndarray) -> float:
        gamma0, gamma1 = autocovariance(math.exp(p[0]), math.exp(p[1]), block)
        cov = gamma0 * np.eye(n) + gamma1 * (np.eye(n, k=1) + np.eye(n, k=-1))
        return -float(stats.multivariate_normal(mean=np.zeros(n), cov=cov).logpdf(z))

    start = np.log([n_density**2 * rate * 2.0, k_density**2 / rate / 3.0])
    found = optimize.minimize(dense_nll, start, method="Nelder-Mead",
                              options={"xatol": 1e-7, "fatol": 1e-8, "maxiter": 1000})
    a, b = np.exp(found.x)
    assert ml.n == pytest.approx(math.sqrt(a / rate), rel=1e-4)
    assert ml.k == pytest.approx(math.sqrt(b * rate), rel=1e-4)
    # the engine's likelihood is the dense one, up to the constant n log(2 pi) / 2
    assert negative_log_likelihood(found.x[0], found.x[1], z, block) + 0.5 * n * math.log(2.0 * math.pi) \
        == pytest.approx(dense_nll(found.x), rel=1e-10)
    h = 5e-3
    hessian = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            ei, ej = np.eye(2)[i] * h, np.eye(2)[j] * h
            hessian[i, j] = (dense_nll(found.x + ei + ej) - dense_nll(found.x + ei - ej)
                             - dense_nll(found.x - ei + ej) + dense_nll(found.x - ei - ej)) / (4.0 * h * h)
    np.testing.assert_allclose(np.diag(ml.covariance), np.diag(np.linalg.inv(hessian)), rtol=0.02)


def _sim_truth(gyro: NoiseSpec, accel: NoiseSpec) -> UnitTruth:
    return UnitTruth(accel=SensorTruth(noise=accel), gyro=SensorTruth(noise=gyro))


def test_terms_of_a_simulated_unit_through_the_mocks():
    """mocks.rig.simulate, 1.5 h still at 100 Hz: N within 2 %, K within 35 %, other terms null."""
    gyro = NoiseSpec(N=[2e-4, 3e-4, 4e-4], K=[4e-6, 5e-6, 6e-6])
    accel = NoiseSpec(N=[2e-3, 1.5e-3, 1e-3], K=[5e-5, 4e-5, 3e-5])
    rec = simulate(_sim_truth(gyro, accel), [Static("+z", 5400.0)], rate_hz=100.0, seed=4)
    rates = np.column_stack([rec.gyro, rec.acc])
    curve, noise = analyse(rates, 100.0, ("gx", "gy", "gz", "ax", "ay", "az"))
    truth_n = np.concatenate([gyro.N, accel.N])
    truth_k = np.concatenate([gyro.K, accel.K])
    for j, axis in enumerate(noise):
        assert axis.value("N") == pytest.approx(truth_n[j], rel=0.02)
        assert axis.value("K") == pytest.approx(truth_k[j], rel=0.35)
        for term in ("Q", "B", "R"):
            assert axis.value(term) is None and axis.terms[term].reason
        # the slope-line reading at tau = 1 s is N itself: the two methods agree
        assert axis.terms["N"].slope_line_at_1s == pytest.approx(axis.value("N"), rel=0.03)
        stddev = axis.terms["N"].stddev
        assert 0 < stddev < 0.01 * axis.value("N")
    assert np.all(curve.ci_low <= curve.adev) and curve.alpha[0, 0] == 0 and curve.alpha[-1, 0] == -2
    # K came from the likelihood (only N and K show); the report keeps the curve fit's K beside it
    section = noise_section(noise, curve, {"source": "mocks"})
    for sensor in ("gyro", "accel"):
        assert all(ML in m for m in section[sensor]["methods"]["K"])
        fit_k = section[sensor]["adev_fit"]["K"]["value"]
        assert all(v == pytest.approx(k, rel=0.5) for v, k in zip(fit_k, section[sensor]["K"], strict=True))


def test_quantization_is_identified_where_it_dominates():
    """White phase noise Q (u_k - u_{k-1}) rate over white noise: Q within 10 %, N within 3 %."""
    rate, q, n_density = 200.0, 1e-4, 1e-3
    rng = np.random.default_rng(2)
    n = int(900 * rate)
    u = rng.standard_normal(n + 1) * q
    y = np.diff(u) * rate + rng.standard_normal(n) * n_density * math.sqrt(rate)
    _, (noise,) = analyse(y, rate)
    assert "Q" in noise.fitted
    assert noise.value("Q") == pytest.approx(q, rel=0.10)
    assert noise.value("N") == pytest.approx(n_density, rel=0.03)
    assert noise.terms["Q"].slope_value == pytest.approx(q, rel=0.15)  # slope -1 line read at sqrt(3) s
    assert noise.value("K") is None and noise.terms["K"].reason


def test_bias_instability_floor_from_the_mocks_flicker_model():
    """A flicker floor 0.66428 B over 10..1000 s (mocks 'flicker' bias model): B within 15 %."""
    b = 2e-4
    gyro = NoiseSpec(N=[2e-4] * 3, B=[b] * 3, b_corr_time_s=2000.0, bias_model="flicker")
    rec = simulate(_sim_truth(gyro, NoiseSpec()), [Static("+z", 3 * 3600.0)], rate_hz=20.0, seed=9)
    _, noise = analyse(rec.gyro, 20.0, ("gx", "gy", "gz"))
    for axis in noise:
        assert "B" in axis.fitted and axis.terms["K"].adev_value is None  # the fit alone: B shows
        assert axis.value("B") == pytest.approx(b, rel=0.15)
        assert axis.terms["B"].slope_value == pytest.approx(b, rel=0.25)  # the floor / 0.66428
        assert axis.value("N") == pytest.approx(2e-4, rel=0.05)


def test_rate_ramp_is_identified():
    rate, ramp, n_density = 50.0, 1e-5, 1e-3  # white and ramp lines cross at 27 s
    rng = np.random.default_rng(8)
    n = int(3600 * rate)
    t = np.arange(n) / rate
    y = ramp * t + rng.standard_normal(n) * n_density * math.sqrt(rate)
    _, (noise,) = analyse(y, rate)
    # a deterministic ramp has no scatter, the fit's EDF weights treat it as noise and share the
    # transition with K; the slope +1 line, read at sqrt(2) s, is exact
    assert noise.value("R") == pytest.approx(ramp, rel=0.25)
    assert noise.terms["R"].slope_value == pytest.approx(ramp, rel=0.02)
    assert noise.value("N") == pytest.approx(n_density, rel=0.03)


def test_random_walk_is_null_when_the_record_is_too_short():
    """Lines crossing at 600 s in a 30 min record (T/20 = 90 s): K is null, and the reason says so."""
    rate, n_density = 100.0, 1e-3
    k_density = math.sqrt(3.0) * n_density / 600.0
    y = white_and_walk(np.random.default_rng(1), int(1800 * rate), rate, n_density, k_density)[:, 0]
    _, (noise,) = analyse(y, rate)
    assert noise.value("K") is None
    assert "T/20" in noise.terms["K"].reason or "zero" in noise.terms["K"].reason
    assert noise.value("N") == pytest.approx(n_density, rel=0.02)


def test_fit_is_exact_on_an_exact_model_curve():
    """A noiseless model curve with high EDF gives back its own terms (all five)."""
    tau = np.geomspace(0.01, 1e8, 120)  # each term dominates somewhere: Q < 0.1 s < N < 200 s < B < ...
    truth = {"Q": 2e-4, "N": 1e-3, "B": 1e-4, "K": 2e-7, "R": 1e-10}
    adev = np.sqrt(model_avar(tau, truth))
    noise = fit_axis(tau, adev, np.full(len(tau), 1e6), duration_s=1e7, axis="gz")
    for term in TERMS:
        assert noise.value(term) == pytest.approx(truth[term], rel=1e-3), term
    assert B_FACTOR == pytest.approx(0.66428, abs=1e-5)


def test_gauss_markov_hump_gives_bias_instability_from_its_peak():
    """The mocks' default bias model: a Gauss-Markov process whose curve peaks at 0.664 B near 1.89 T_c
    and falls again. No IEEE 952 term draws a fall: a Gauss-Markov term is fitted, B is its peak / 0.664."""
    b = 3e-4
    gyro = NoiseSpec(N=[2e-4] * 3, B=[b] * 3, b_corr_time_s=20.0)
    rec = simulate(_sim_truth(gyro, NoiseSpec()), [Static("+z", 3600.0)], rate_hz=20.0, seed=5)
    _, noise = analyse(rec.gyro, 20.0, ("gx", "gy", "gz"))
    for axis in noise:
        assert axis.value("B") == pytest.approx(b, rel=0.3)
        assert "Gauss-Markov" in axis.terms["B"].method and axis.terms["K"].adev_value is None
        assert axis.gauss_markov[1] == pytest.approx(20.0, rel=0.5)  # the correlation time
        assert axis.value("N") == pytest.approx(2e-4, rel=0.05)


def test_likelihood_keeps_within_15_percent_of_the_fit_under_an_unresolved_gauss_markov_bias():
    """The mocks' 100 s Gauss-Markov bias (3 deg/h) under a random walk, 2 h at 20 Hz: the curve shows no
    hump. Where a Gauss-Markov term explains the whole rise (K no longer significant), B is its peak and K
    null with the reason (gx, gz: B 1.5x and 1.07x the truth, the walk's rise partly in it); elsewhere the
    curve shows N and K only, and the likelihood's K is used only within 15 % of the fit's, else the fit's
    value stands, the method saying why."""
    deg = math.pi / 180.0
    b = 3.0 * deg / 3600.0
    gyro = NoiseSpec(N=[0.01 * deg] * 3, B=[b] * 3, K=[10.0 * deg / 3600.0 / 60.0] * 3, b_corr_time_s=100.0)
    rec = simulate(_sim_truth(gyro, NoiseSpec()), [Static("+z", 7200.0)], rate_hz=20.0, seed=0)
    _, noise = analyse(rec.gyro, 20.0, ("gx", "gy", "gz"))
    for axis in noise:
        k = axis.terms["K"]
        if axis.gauss_markov is not None:
            assert axis.value("B") == pytest.approx(b, rel=0.6) and "Gauss-Markov" in axis.terms["B"].method
            assert k.value is None and "Gauss-Markov" in k.reason
            continue
        assert axis.fitted == ("N", "K")
        if k.method.startswith(ML_METHOD):
            assert 1.0 / 1.15 <= k.value / k.adev_value <= 1.15
        else:
            assert k.method.startswith("IEEE 952 fit; the likelihood") and k.adev_value is None
            assert k.value == pytest.approx(axis.coeffs["K"], rel=1e-12)
    assert any(axis.gauss_markov is not None for axis in noise)


def test_gauss_markov_bias_of_the_mocks_default_unit_without_a_visible_hump():
    """The mocks' default gyro (UnitTruth.random): 0.01 deg/s/sqrt(Hz), a 5 deg/h Gauss-Markov bias of
    100 s, 10 deg/h/sqrt(h), 2 h at 20 Hz, 4 records of 3 axes. The curve rises into a flat stretch and
    mostly never visibly falls; fitted as N and K, K came out 2.4x the truth and B null. Now the
    Gauss-Markov term takes the rise where it explains all of it (7 axes of 12: B 0.73x to 1.38x, K null
    with the reason), the IEEE fit's floor gives B on 3 (within 6 %), and 2 stay N + K (K ~3x)."""
    deg = math.pi / 180.0
    b = 5.0 * deg / 3600.0
    gyro = NoiseSpec(N=[0.01 * deg] * 3, B=[b] * 3, K=[10.0 * deg / 3600.0 / 60.0] * 3, b_corr_time_s=100.0)
    b_err, by_gauss_markov = [], 0
    for seed in range(4):
        rec = simulate(_sim_truth(gyro, NoiseSpec()), [Static("+z", 7200.0)], rate_hz=20.0, seed=seed)
        _, noise = analyse(rec.gyro, 20.0, ("gx", "gy", "gz"))
        for axis in noise:
            assert axis.value("N") == pytest.approx(0.01 * deg, rel=0.02)
            b_err.append(math.inf if axis.value("B") is None else abs(axis.value("B") / b - 1.0))
            if axis.gauss_markov is not None:
                by_gauss_markov += 1
                assert 20.0 < axis.gauss_markov[1] < 300.0
                assert axis.value("K") is None and "Gauss-Markov" in axis.terms["K"].reason
    assert by_gauss_markov >= 5
    assert np.count_nonzero(np.array(b_err) < 0.4) >= 9


def test_quantization_under_three_points_stays_in_the_model_and_n_stays_unbiased():
    """Q and N lines crossing at 1.5 samples: Q dominates the first point only, too few to report it, but
    left out of the model its excess went into N (+26 %). It stays modelled: N within 2 %, Q null with
    the modelled value in the reason (within 10 % of the injected one)."""
    rate, n_density = 200.0, 1e-3
    q = 0.05 * n_density  # 3 Q^2 / N^2 = 7.5 ms
    rng = np.random.default_rng(3)
    n = int(900 * rate)
    u = rng.standard_normal(n + 1) * q
    y = np.diff(u) * rate + rng.standard_normal(n) * n_density * math.sqrt(rate)
    _, (noise,) = analyse(y, rate)
    assert "Q" in noise.fitted and noise.value("Q") is None
    assert noise.terms["Q"].reason.startswith("modelled")
    assert noise.coeffs["Q"] == pytest.approx(q, rel=0.10)
    assert noise.value("N") == pytest.approx(n_density, rel=0.02)


def test_a_sensor_low_pass_filter_at_the_start_of_the_curve_is_left_out_of_the_fit():
    """White noise through a first-order filter (pole 0.9 at 200 Hz, T_f = 47 ms): the curve rises from
    tau0 to a hump at ~0.09 s before the white-noise line. Fitted from its first point, N came out null
    and a spurious B appeared; the fit now starts 3x after the slope reaches -0.45: N within 3 %, no B."""
    rate, n_density, pole = 200.0, 1e-3, 0.9
    rng = np.random.default_rng(5)
    white = rng.standard_normal(int(900 * rate)) * n_density * math.sqrt(rate)
    y = lfilter([1.0 - pole], [1.0, -pole], white)  # unity DC gain: N unchanged below the corner
    curve, (noise,) = analyse(y, rate)
    slope = np.gradient(np.log(curve.adev[:, 0]), np.log(curve.tau))
    assert slope[0] > 0  # the filtered start is there
    t_f = -1.0 / (rate * math.log(pole))
    assert 15 * t_f < noise.fitted_from_tau < 100 * t_f
    assert noise.value("N") == pytest.approx(n_density, rel=0.03)
    for term in ("Q", "B", "R"):
        assert noise.value(term) is None
