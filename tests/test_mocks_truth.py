"""Truth model of the simulated unit: forward model and noise statistics against their formulas.

Noise terms are checked on synthetic records against the discrete-time formulas of
``mocks.truth.NoiseSpec`` and against the Allan deviation computed by allantools (an
independent implementation), with tolerances sized to the statistical error of each record.
"""

from __future__ import annotations

import allantools
import numpy as np
import pytest

from mocks.truth import (
    EARTH_RATE_RAD_S,
    FLICKER_FLOOR,
    NoiseGenerator,
    NoiseSpec,
    SensorTruth,
    ThermalTruth,
    UnitTruth,
)
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import ThermalBias, ThermalSegment


def noise(spec: NoiseSpec, n: int, rate_hz: float, seed: int) -> np.ndarray:
    return NoiseGenerator(spec, rate_hz, np.random.SeedSequence(seed)).next(n)


def adev(rate_series: np.ndarray, rate_hz: float, taus_s: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation of a rate signal (allantools, frequency data)."""
    taus, dev, _, _ = allantools.oadev(rate_series, rate=rate_hz, data_type="freq", taus=taus_s)
    assert np.allclose(taus, taus_s, rtol=1e-2)
    return dev


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_white_noise_std_is_N_sqrt_rate(seed: int) -> None:
    # 3 x 100k samples: the relative error of a std estimate is 1/sqrt(2 n) = 0.13 %; allow 1 %.
    rate = 400.0
    spec = NoiseSpec(N=[0.01, 0.002, 0.05])
    x = noise(spec, 100_000, rate, seed)
    assert np.allclose(x.std(axis=0), spec.N * np.sqrt(rate), rtol=0.01)
    assert np.allclose(x.mean(axis=0), 0.0, atol=4 * spec.N * np.sqrt(rate) / np.sqrt(100_000))


def test_white_noise_allan_deviation_is_N_over_sqrt_tau() -> None:
    rate = 100.0
    spec = NoiseSpec(N=0.003)
    x = noise(spec, 200_000, rate, seed=5)[:, 0]
    taus = np.array([0.1, 1.0, 10.0])
    # Overlapping ADEV at tau = 10 s over 2000 s has about 5 % error; allow 10 %.
    assert np.allclose(adev(x, rate, taus), 0.003 / np.sqrt(taus), rtol=0.10)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_walk_steps_and_growth_match_K(seed: int) -> None:
    rate, k = 200.0, 2e-3
    spec = NoiseSpec(K=k)
    x = noise(spec, 50_000, rate, seed)
    steps = np.diff(x, axis=0)
    assert np.allclose(steps.std(axis=0), k * np.sqrt(1.0 / rate), rtol=0.01)
    # Variance after T seconds over 300 independent walks (x 3 axes) is K^2 T: 900 values give
    # a relative standard error of sqrt(2/900) = 4.7 % on the variance; allow 15 %.
    seeds = np.random.SeedSequence(seed).spawn(300)
    ends = np.array([NoiseGenerator(spec, rate, s).next(2000)[-1] for s in seeds])
    duration = 2000 / rate
    assert np.mean(ends**2) == pytest.approx(k**2 * duration, rel=0.15)


def test_quantization_noise_allan_deviation_is_sqrt3_Q_over_tau() -> None:
    rate, q = 200.0, 1e-4
    x = noise(NoiseSpec(Q=q), 100_000, rate, seed=3)[:, 1]
    taus = np.array([0.02, 0.1, 0.5])
    assert np.allclose(adev(x, rate, taus), np.sqrt(3) * q / taus, rtol=0.05)


def test_gauss_markov_bias_instability_peaks_at_0664_B() -> None:
    rate, b, tc = 50.0, 1e-3, 2.0
    x = noise(NoiseSpec(B=b, b_corr_time_s=tc), 150_000, rate, seed=4)  # 3000 s
    taus = np.array([1.89 * tc])
    peak = np.array([adev(x[:, i], rate, taus)[0] for i in range(3)])
    # ~800 independent clusters per axis: ~3.5 % error per axis; allow 12 % on the mean of 3 axes.
    assert peak.mean() == pytest.approx(FLICKER_FLOOR * b, rel=0.12)
    # The process is stationary from the first sample, with the documented variance.
    s = FLICKER_FLOOR * b / 0.6174
    assert x.std() == pytest.approx(s, rel=0.15)


def test_flicker_bias_instability_has_a_flat_floor_at_0664_B() -> None:
    rate, b = 20.0, 5e-4
    spec = NoiseSpec(B=b, b_corr_time_s=100.0, bias_model="flicker")
    x = noise(spec, 80_000, rate, seed=6)  # 4000 s
    taus = np.array([1.0, 3.0, 10.0, 30.0])
    dev = np.mean([adev(x[:, i], rate, taus) for i in range(3)], axis=0)
    # Flat within the band 10 dt .. b_corr_time_s: statistical error at 30 s is ~5 % (3 axes).
    assert np.allclose(dev, FLICKER_FLOOR * b, rtol=0.12)


def test_noise_does_not_depend_on_block_sizes() -> None:
    spec = NoiseSpec(N=0.01, B=1e-3, K=1e-4, Q=1e-5, b_corr_time_s=10.0, bias_model="flicker")
    whole = noise(spec, 1000, 100.0, seed=9)
    gen = NoiseGenerator(spec, 100.0, np.random.SeedSequence(9))
    parts = np.vstack([gen.next(n) for n in (1, 7, 0, 300, 692)])
    np.testing.assert_allclose(parts, whole, rtol=0, atol=1e-15)


def test_forward_model_agrees_with_the_station_sensor_and_thermal_models() -> None:
    rng = np.random.default_rng(0)
    s = rng.normal(0, 0.01, (3, 3))
    np.fill_diagonal(s, 0)
    coeffs = rng.normal(0, 1e-3, (3, 7))
    truth = SensorTruth(scale=[1.01, 0.98, 1.003], misalignment=s, bias=[0.1, -0.2, 0.05],
                        thermal=ThermalTruth(coeffs=coeffs, t_ref=20.0))
    true = rng.normal(0, 9.81, (500, 3))
    temp = rng.uniform(-20, 60, 500)
    dtemp = rng.uniform(-0.5, 0.5, 500)
    raw = truth.measure(true, temp, dtemp)
    model = SensorCalibration.from_parts(truth.scale, truth.misalignment, truth.bias)
    thermal = ThermalBias([ThermalSegment(-100.0, 200.0, coeffs)], dt_min=-5.0, dt_max=5.0)
    expected = model.forward(true) + thermal.evaluate(temp, dtemp, reference_temp=20.0)
    np.testing.assert_allclose(raw, expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(truth.matrix, model.matrix, rtol=0, atol=1e-15)


def test_saturation_and_resolution() -> None:
    truth = SensorTruth(saturation=10.0, resolution=0.01)
    raw = truth.measure(np.array([[12.0, -15.0, 1.23456]]), np.array([25.0]), np.array([0.0]))
    np.testing.assert_allclose(raw, [[10.0, -10.0, 1.23]], atol=1e-12)


def test_misalignment_must_have_a_zero_diagonal() -> None:
    with pytest.raises(ValueError, match="zero diagonal"):
        SensorTruth(misalignment=np.eye(3) * 0.01)


def test_random_units_are_reproducible_and_realistic() -> None:
    a, b, c = UnitTruth.random(7), UnitTruth.random(7), UnitTruth.random(8)
    np.testing.assert_array_equal(a.accel.matrix, b.accel.matrix)
    np.testing.assert_array_equal(a.gyro.thermal.coeffs, b.gyro.thermal.coeffs)
    assert not np.array_equal(a.gyro.bias, c.gyro.bias)
    assert a.serial == "SIM-000007"
    for sensor in (a.accel, a.gyro):
        assert np.all(np.abs(sensor.scale - 1) < 0.05)
        assert np.all(np.diag(sensor.misalignment) == 0)
        assert np.all(np.abs(sensor.misalignment) < 0.03)
    assert np.all(np.abs(a.accel.bias) < 0.5)  # m/s^2: within 50 mg
    assert np.all(np.abs(a.gyro.bias) < np.radians(3))
    tactical = UnitTruth.random(7, grade="tactical")
    assert np.all(np.abs(tactical.gyro.bias) < np.abs(a.gyro.bias) / 10)
    assert tactical.gyro.resolution is None
    with pytest.raises(ValueError, match="grade"):
        UnitTruth.random(1, grade="navigation")


def test_ideal_unit_is_identity_without_noise() -> None:
    ideal = UnitTruth.ideal()
    for sensor in (ideal.accel, ideal.gyro):
        np.testing.assert_array_equal(sensor.matrix, np.eye(3))
        assert sensor.noise.is_zero
        assert sensor.resolution is None


def test_earth_rate_of_a_unit_lying_still() -> None:
    from mocks.rig import Static, simulate

    truth = UnitTruth(earth_rate=True, latitude_deg=52.0, heading_deg=30.0)
    rec = simulate(truth, [Static("+z", 1.0)], rate_hz=100)
    gyro = rec.gyro.mean(axis=0)
    lat, h = np.radians(52.0), np.radians(30.0)
    # In East-North-Up the Earth rate is Omega (0, cos lat, sin lat); world x points to azimuth h.
    omega_enu = EARTH_RATE_RAD_S * np.array([0.0, np.cos(lat), np.sin(lat)])
    x_world = np.array([np.sin(h), np.cos(h), 0.0])
    y_world = np.cross([0.0, 0.0, 1.0], x_world)
    expected = np.array([omega_enu @ x_world, omega_enu @ y_world, omega_enu[2]])
    np.testing.assert_allclose(gyro, expected, atol=1e-12)
    assert np.linalg.norm(gyro) == pytest.approx(7.2921159e-5, rel=1e-9)
    upside_down = simulate(truth, [Static("-z", 1.0)], rate_hz=100)
    assert upside_down.gyro[-1, 2] == pytest.approx(-expected[2], rel=1e-9)


def test_noise_spec_validates() -> None:
    with pytest.raises(ValueError, match="bias_model"):
        NoiseSpec(bias_model="pink")
    with pytest.raises(ValueError, match="b_corr_time_s"):
        NoiseSpec(b_corr_time_s=0)
