"""Calibration across temperature (``station.engines.thermal.intrinsics_fit``): recovery of a simulated
unit whose bias, scale factor and misalignment all move with T, at temperatures between the soaks,
against the truth, the reported 1-sigma and calibrating at the nearest single soak; the fit against
numpy's weighted polyfit, its covariance against a closed form and a Monte Carlo; the clear refusals.

The unit is ``UnitTruth.random(seed, thermal_intrinsics=True)``: realistic MEMS noise and quantization,
scale factor 50-300 ppm/degC with curvature, misalignment 1-5 urad/degC, the cubic thermal bias. Each
soak is the twelve-position sequence with its six turns, 20 s holds at 100 Hz, at a constant
temperature; soaks at -20, 0, 20, 40, 60 degC, checked at 10, 30 and 50 degC (10 degC from the nearest
soak).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import polynomial as P

from mocks.rig import constant, sequence_segments, simulate
from mocks.truth import SensorTruth, UnitTruth
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.engines.thermal.intrinsics import OFF_DIAGONAL, matrices_at, slope_weights
from station.engines.thermal.intrinsics_fit import (
    SoakCalibration,
    fit_across_temperature,
    fit_quantity,
    weighted_polyfit,
)
from station.errors import EngineInputError

RATE_HZ = 100.0
SOAKS_DEGC = (-20.0, 0.0, 20.0, 40.0, 60.0)
BETWEEN_DEGC = (10.0, 30.0, 50.0)
ROWS, COLS = np.array(OFF_DIAGONAL).T
# Stated tolerances at a temperature between soaks (the per-soak turntable precision with 20 s holds,
# a few times over): scale (unitless), misalignment (rad), bias (m/s^2, rad/s).
TOLERANCE = {
    ("accel", "scale"): 1e-4, ("accel", "misalignment"): 5e-5, ("accel", "bias"): 1e-3,
    ("gyro", "scale"): 3e-4, ("gyro", "misalignment"): 2e-4, ("gyro", "bias"): 1e-4,
}


def soak_captures(truth: UnitTruth, seed: int, temps=SOAKS_DEGC, hold_s: float = 20.0):
    """One simulated twelve-position capture per soak temperature, calibrated by the turntable method."""
    segments = sequence_segments("twelve-position", True, hold_s=hold_s)
    soaks = []
    for k, temp in enumerate(temps):
        rec = simulate(truth, segments, rate_hz=RATE_HZ, seed=1000 * seed + k, temperature=constant(temp))
        report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step, rate_hz=RATE_HZ),
                                     TurntableSettings(gravity=truth.gravity))
        soaks.append(SoakCalibration(float(np.mean(rec.temp)), report, f"soak {temp:g} degC"))
    return soaks


def truth_at(sensor: SensorTruth, temp: float) -> dict[str, np.ndarray]:
    """Scale, misalignment (off-diagonal) and static bias plus thermal bias of the truth at ``temp``."""
    t = np.array([temp])
    return {"scale": sensor.scale_at(t)[0], "misalignment": sensor.misalignment_at(t)[0][ROWS, COLS],
            "bias": sensor.bias + sensor.thermal.bias(t, np.zeros(1))[0]}


def single_soak(report, triad: str) -> dict[str, np.ndarray]:
    cal = getattr(report, triad)
    return {"scale": cal.scale, "misalignment": cal.misalignment[ROWS, COLS], "bias": cal.bias}


@pytest.fixture(scope="module")
def unit():
    truth = UnitTruth.random(5, thermal_intrinsics=True)
    soaks = soak_captures(truth, 5)
    return truth, soaks, fit_across_temperature(soaks)


def test_truth_matrix_moves_with_temperature() -> None:
    truth = UnitTruth.random(5, thermal_intrinsics=True)
    plain = UnitTruth.random(5)
    # the other intrinsics are the seed's own; only the coefficients are added
    assert np.array_equal(truth.gyro.scale, plain.gyro.scale)
    assert np.array_equal(truth.accel.thermal.coeffs, plain.accel.thermal.coeffs)
    assert 100e-6 <= np.abs(truth.gyro.scale_tc).min() and np.abs(truth.gyro.scale_tc).max() <= 300e-6
    assert 50e-6 <= np.abs(truth.accel.scale_tc).min() and np.abs(truth.accel.scale_tc).max() <= 200e-6
    off = truth.gyro.misalignment_tc[ROWS, COLS]
    assert 1e-6 <= np.abs(off).min() and np.abs(off).max() <= 5e-6
    # the measurement uses M(T): a still unit's raw reading scales with K(T) (no noise, no thermal bias)
    sensor = SensorTruth(scale=[1.0, 1.0, 1.0], scale_tc=[1e-4, 0, 0], misalignment_tc=np.diag([1e-6, 0], 1))
    raw = sensor.measure(np.tile([9.8, 1.0, 0.0], (2, 1)), np.array([25.0, 35.0]), np.zeros(2))
    assert raw[1, 0] == pytest.approx((9.8 + 1.0 * 10e-6) * (1 + 1e-3), rel=1e-12)
    assert raw[0, 0] == pytest.approx(9.8, rel=1e-12)
    # default: no coefficients, the matrix is the constant one
    assert not SensorTruth().matrix_depends_on_temp


def test_recovers_truth_between_soaks(unit) -> None:
    truth, soaks, result = unit
    assert result.thermal.reference_temp == pytest.approx(20.0, abs=0.05)
    assert "nearest 25" in result.reference_reason
    for temp in BETWEEN_DEGC:
        nearest = min(soaks, key=lambda s: abs(s.temp - temp)).report
        for triad in ("accel", "gyro"):
            true = truth_at(getattr(truth, triad), temp)
            alone = single_soak(nearest, triad)
            for q in ("scale", "misalignment", "bias"):
                fit = result.fits[f"{triad}.{q}"]
                err = fit.evaluate([temp])[0] - true[q]
                sd = fit.stddev([temp])[0]
                assert np.abs(err).max() < TOLERANCE[triad, q], (temp, triad, q, err)
                assert np.all(np.abs(err) < 3.5 * sd), (temp, triad, q, err / sd)
                err_alone = alone[q] - true[q]
                if q == "misalignment":
                    # 10 degC moves a misalignment by 10-50 urad, the soak's own noise: better, not 5x
                    assert np.sqrt(np.mean(err**2)) < np.sqrt(np.mean(err_alone**2)), (temp, triad)
                else:
                    assert np.abs(err).max() < np.abs(err_alone).max() / 5, (temp, triad, q)


def test_sections_reproduce_the_matrix_between_soaks(unit) -> None:
    """M(T) of the written sections (intrinsics.matrices_at, what apply uses) against the truth's M(T)."""
    truth, _, result = unit
    temps = np.array(BETWEEN_DEGC)
    for triad, tol in (("accel", 1.5e-4), ("gyro", 4e-4)):
        cal = getattr(result, triad)
        matrices = matrices_at(cal.matrix, temps, result.thermal.reference_temp,
                               result.thermal.scale.get(triad), result.thermal.misalignment.get(triad))
        true = getattr(truth, triad).matrix_at(temps)
        assert np.abs(matrices - true).max() < tol
        # and the constant matrix of a single calibration at T_ref is wrong by the drift
        assert np.abs(cal.matrix - true).max() > 3 * np.abs(matrices - true).max()
        thermal_bias = getattr(result.thermal, triad)
        bias = cal.bias + thermal_bias.evaluate(temps, np.zeros(3), result.thermal.reference_temp)
        true_bias = np.array([truth_at(getattr(truth, triad), t)["bias"] for t in temps])
        assert np.abs(bias - true_bias).max() < TOLERANCE[triad, "bias"]


def test_figures_people_quote(unit) -> None:
    truth, _, result = unit
    lo, hi = min(SOAKS_DEGC), max(SOAKS_DEGC)
    temp, w = slope_weights(lo, hi)
    for triad, tol_ppm in (("accel", 5.0), ("gyro", 15.0)):
        sensor = getattr(truth, triad)
        k_ref = sensor.scale_at(np.array([result.thermal.reference_temp]))
        true_tc = w @ (sensor.scale_at(temp) / k_ref) * 1e6
        tc, tc_sd = result.scale_tc_ppm(triad)
        assert np.abs(tc - true_tc).max() < tol_ppm
        assert np.all(np.abs(tc - true_tc) < 3.5 * tc_sd)
        # the same slope by numpy's own straight line through the fitted curve
        curve = result.fits[f"{triad}.scale"].evaluate(temp) / result.fits[f"{triad}.scale"].coeffs[:, 0]
        # (a curve near 1 in float64: agreement to 1e-5 of the slope, 1e-3 ppm/degC)
        assert np.allclose(tc, np.polyfit(temp, curve - 1.0, 1)[0] * 1e6, rtol=1e-5, atol=1e-3)
        mis = sensor.misalignment_at(temp)[:, ROWS, COLS]
        true_change = (mis.max(axis=0) - mis.min(axis=0)) * 1e6
        # the truth's drift is linear, so its change is |s(60) - s(-20)|; the fit's 1-sigma of that
        # difference (about 37 urad accel, 72 urad gyro here: a soak measures a gyro misalignment to
        # 50-120 urad) bounds the error
        fit = result.fits[f"{triad}.misalignment"]
        g = fit._basis([hi])[0] - fit._basis([lo])[0]
        change_sd = np.sqrt(np.einsum("p,cpq,q->c", g, fit.cov, g)) * 1e6
        change_err = np.abs(result.misalignment_change_urad(triad) - true_change)
        assert np.all(change_err < 3.5 * change_sd), change_err / change_sd
        assert np.all(change_sd < {"accel": 50.0, "gyro": 100.0}[triad])
    assert np.all(np.abs(result.bias_sensitivity("gyro")) > 0)


def test_fit_equals_numpy_weighted_polyfit(unit) -> None:
    _, _, result = unit
    temps = np.array([s.temp for s in result.soaks])
    for key, fit in result.fits.items():
        triad, q = key.split(".")
        y = np.array([s.values[triad][q] for s in result.soaks])
        sd = np.array([s.stddev[triad][q] for s in result.soaks])
        for c in range(y.shape[1]):
            ref = P.polyfit(temps - fit.reference_temp, y[:, c], fit.order, w=1.0 / sd[:, c])
            assert np.allclose(fit.coeffs[c], ref, rtol=1e-8, atol=1e-12 * np.abs(ref).max()), key


def test_covariance_closed_form_and_monte_carlo() -> None:
    rng = np.random.default_rng(7)
    t = np.array([-40.0, -20.0, 0.0, 20.0, 40.0])
    sd = np.array([[1.0, 2.0], [0.5, 1.0], [1.0, 1.0], [2.0, 0.5], [1.0, 1.5]]) * 1e-4
    true = np.array([[1.0, 2e-4], [0.99, -1e-4]])  # two components, straight lines
    # closed form of a weighted straight line: var(a0) = Sxx / D, var(a1) = S / D
    _, cov = weighted_polyfit(t, np.zeros((5, 2)), sd, 1)
    for c in range(2):
        w = 1.0 / sd[:, c] ** 2
        s, sx, sxx = w.sum(), (w * t).sum(), (w * t * t).sum()
        d = s * sxx - sx**2
        assert np.allclose(cov[c], [[sxx / d, -sx / d], [-sx / d, s / d]], rtol=1e-10)
    draws = 4000
    coeffs = np.empty((draws, 2, 2))
    inside = np.zeros((2, 2))
    for k in range(draws):
        y = true[:, 0] + np.outer(t, true[:, 1]) + sd * rng.standard_normal((5, 2))
        coeffs[k] = weighted_polyfit(t, y, sd, 1)[0]
        reported = fit_quantity("gyro", "scale", t, y, sd, 0.0, 1)  # order fixed at 1 by max_order
        if reported.order == 1:
            inside += np.abs(reported.coeffs - true) < np.sqrt(np.diagonal(reported.cov, axis1=1, axis2=2))
    for c in range(2):
        empirical = np.cov(coeffs[:, c].T)
        assert np.allclose(np.sqrt(np.diag(empirical)), np.sqrt(np.diag(cov[c])), rtol=0.05)
        assert np.allclose(coeffs[:, c].mean(axis=0), true[c], atol=3 * np.sqrt(np.diag(cov[c]) / draws))
    # the reported 1-sigma (Birge-scaled, never below the propagated one) cover about 68 % or a bit more
    share = inside / draws
    assert np.all(share > 0.64) and np.all(share < 0.82), share


@pytest.mark.parametrize(("curve", "order"), [
    (lambda t: 1e-3 + 0 * t, 0),
    (lambda t: 1e-3 + 2e-5 * t, 1),
    (lambda t: 1e-3 + 2e-5 * t + 3e-7 * t**2, 2),
])
def test_order_chosen_by_cross_validation(curve, order) -> None:
    rng = np.random.default_rng(3)
    t = np.linspace(-40.0, 40.0, 7)
    sd = np.full((7, 3), 1e-5)
    y = curve(t)[:, None] + sd * rng.standard_normal((7, 3))
    fit = fit_quantity("accel", "bias", t, y, sd, 0.0, 3)
    assert fit.order == order, fit.cv_scores
    assert set(fit.cv_scores) == {0, 1, 2, 3}
    # never above n - 2: three soaks allow a line at most
    assert fit_quantity("accel", "bias", t[:3], y[:3], sd[:3], 0.0, 3).order <= 1


def test_refuses_one_soak_and_a_narrow_span(unit) -> None:
    _, soaks, _ = unit
    with pytest.raises(EngineInputError, match="1 soak given.*2 or more temperatures"):
        fit_across_temperature(soaks[:1])
    narrow = [SoakCalibration(20.0, soaks[0].report, "a"), SoakCalibration(23.0, soaks[1].report, "b")]
    with pytest.raises(EngineInputError, match="span 3.0 degC.*at least 5 degC"):
        fit_across_temperature(narrow)
    with pytest.raises(EngineInputError, match="soak b has no temperature"):
        fit_across_temperature([narrow[0], SoakCalibration(float("nan"), soaks[1].report, "b")])


def test_thermal_section_round_trips(unit) -> None:
    from station.engines.thermal.model import ThermalModel

    _, _, result = unit
    again = ThermalModel.from_dict(result.thermal.to_dict())
    for triad in ("accel", "gyro"):
        assert np.allclose(again.scale[triad].coeffs, result.thermal.scale[triad].coeffs)
        assert np.allclose(again.misalignment[triad].coeffs, result.thermal.misalignment[triad].coeffs)
        assert getattr(again, triad).t_min == min(s.temp for s in result.soaks)
    assert result.orders == {k: f.order for k, f in result.fits.items()}


def test_apply_uses_m_of_t_where_the_temperature_is_known_and_the_section_elsewhere() -> None:
    from station.engines.shared.correction import apply_calibration
    from station.engines.shared.sensor_model import SensorCalibration
    from station.engines.thermal.intrinsics import TempPolynomial
    from station.engines.thermal.model import DtempFilter, ThermalModel

    rng = np.random.default_rng(11)
    k0, s0 = np.array([1.01, 0.99, 1.002]), np.array([[0, 1e-3, 0], [0, 0, 2e-3], [-1e-3, 0, 0]])
    cal = SensorCalibration.from_parts(k0, s0, np.array([0.01, -0.02, 0.0]))
    scale = TempPolynomial(-20.0, 60.0, (1,), [[2e-4], [1e-4], [-1e-4]])
    thermal = ThermalModel(25.0, DtempFilter(), scale={"gyro": scale})
    temp = rng.uniform(-30.0, 70.0, 60)
    temp[::4] = np.nan
    raw = rng.normal(0.0, 1.0, (60, 3))
    _, gyro = apply_calibration(raw, raw, temp, None, cal, cal, thermal)
    for i in range(60):
        if np.isfinite(temp[i]):  # K(T) = K + k(clamp(T) - T_ref), written out here
            k = k0 + np.array([2e-4, 1e-4, -1e-4]) * (np.clip(temp[i], -20.0, 60.0) - 25.0)
            matrix = np.diag(k) @ (np.eye(3) + s0)
        else:
            matrix = cal.matrix
        expected = np.linalg.solve(matrix, raw[i] - cal.bias)
        np.testing.assert_allclose(gyro[i], expected, rtol=1e-12, atol=1e-12)
