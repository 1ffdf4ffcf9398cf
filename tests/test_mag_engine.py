"""Magnetometer engine: coverage of the sphere of field directions, the joint fit against the
simulated unit's truth (full sphere and desk-bound), its Jacobian, an independent reference
(Li & Griffiths' ellipsoid fit, as Magneto), bad input and disturbances."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from mag_helpers import calibrated_acc, errors, lower_frame, magneto, polar

from mocks.mag_sessions import mag_capture, nine_axis_unit
from mocks.magnetometer import EarthField
from mocks.truth import UnitTruth
from station.engines.magnetometer.accel import ALL, NO_Z_BIAS, PoseAccel
from station.engines.magnetometer.calibration import MagCalibration, MagCapture, MagSettings, calibrate_mag
from station.engines.magnetometer.coverage import CELLS, cell_bounds, cell_centres, cell_index, field_coverage
from station.engines.magnetometer.fit import JointProblem, ellipsoid_fit
from station.errors import EngineInputError


def _uniform(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_cells_have_equal_area() -> None:
    # uniform directions fill every cell alike: counts within 5 sigma of the binomial spread
    n = 124_000
    counts = np.bincount(cell_index(_uniform(n)), minlength=CELLS)
    mean = n / CELLS
    assert np.all(np.abs(counts - mean) < 5 * np.sqrt(mean))
    # and each centre lies in its own cell
    assert np.array_equal(cell_index(cell_centres()), np.arange(CELLS))
    # the cells are rectangles of one area in Lambert's map (longitude, z): 4 pi / CELLS each
    bounds = cell_bounds()
    area = (bounds[:, 1] - bounds[:, 0]) * (bounds[:, 3] - bounds[:, 2])
    np.testing.assert_allclose(area, 4 * np.pi / CELLS)
    lon = np.mod(np.arctan2(cell_centres()[:, 1], cell_centres()[:, 0]), 2 * np.pi)
    assert np.all((bounds[1:-1, 0] <= lon[1:-1]) & (lon[1:-1] <= bounds[1:-1, 1]))


def test_full_sphere_is_covered_and_half_names_the_missing_side() -> None:
    u = _uniform(20_000)
    assert field_coverage(u * 48.0).share == 1.0
    assert field_coverage(u).missing == ()
    half = field_coverage(u[u[:, 2] > 0])
    assert half.share == 0.5
    assert half.missing[0] == "-z"
    assert abs(sum(half.missing_share) - 0.5) < 1e-12
    assert "roughly +z up" in half.advice(1)[0]


def test_no_usable_direction_covers_nothing() -> None:
    cov = field_coverage(np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 0.0]]))
    assert cov.share == 0.0
    assert not cov.hit.any()
    assert set(cov.missing) >= {"+x", "-x", "+y", "-y", "+z", "-z"}


def test_min_count_leaves_out_sparse_cells() -> None:
    u = _uniform(200, seed=1)
    assert field_coverage(u, min_count=1).share > field_coverage(u, min_count=5).share


# --- the fit -------------------------------------------------------------------------------------

# Targets of issue 15 on simulated sessions (mocks.mag_sessions: 0.15 uT noise, 0.1 uT resolution,
# a unit whose accelerometer was calibrated first).
FULL = {"hard_ut": 0.05, "shape_pct": 0.2, "align_deg": 0.1}
DESK = {"hard_ut": 0.4, "shape_pct": 1.0, "align_deg": 0.2}


@functools.lru_cache(maxsize=8)
def _session(kind: str, seed: int, **options: float) -> tuple[MagCapture, UnitTruth]:
    cap, truth = mag_capture(kind, seed, **options)
    return MagCapture(cap.t, cap.mag, calibrated_acc(cap.acc, truth), cap.gyro), truth


@pytest.mark.parametrize(("kind", "seed", "target"), [("sphere", 0, FULL), ("sphere", 1, FULL),
                                                      ("desk", 0, DESK), ("desk", 1, DESK)])
def test_joint_fit_recovers_the_truth(kind: str, seed: int, target: dict[str, float]) -> None:
    data, truth = _session(kind, seed)
    result = calibrate_mag(data)
    err = errors(result.matrix, result.bias, truth)
    assert all(err[k] < target[k] for k in target), err
    assert result.frame == "accel"
    assert result.dip_deg == pytest.approx(truth.mag.field.dip_deg, abs=0.1)
    # the data's own field: det C = 1, so F is the raw ellipsoid's geometric mean radius
    assert np.linalg.det(result.correction) == pytest.approx(1.0, rel=1e-9)
    np.testing.assert_allclose(result.correction @ result.matrix, np.eye(3), atol=1e-12)
    # the errors are those the reported 1-sigma lead one to expect (within 5 sigma per axis)
    assert np.all(np.abs(result.bias - truth.mag.hard_iron) < 5 * result.stddev["bias"] + 1e-3)
    assert result.residual_rms < 0.3
    assert not result.disturbances


def test_south_of_the_magnetic_equator_with_permuted_axes() -> None:
    """Negative dip and a magnetometer mounted with x and y swapped and z reversed: the linear start
    finds the rotation and the sign of the dip."""
    unit = nine_axis_unit(5, EarthField(55.0, -50.0, 10.0))
    unit.mag.rotation = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    cap, truth = mag_capture("sphere", 5, truth=unit)
    result = calibrate_mag(MagCapture(cap.t, cap.mag, calibrated_acc(cap.acc, truth), cap.gyro))
    err = errors(result.matrix, result.bias, truth)
    assert all(err[k] < FULL[k] for k in FULL), err
    assert result.dip_deg == pytest.approx(-50.0, abs=0.1)


def test_magnetometer_slower_than_the_accelerometer() -> None:
    # a magnetometer read at a quarter of the rate: the rows between hold NaN
    data, truth = _session("desk", 1)
    mag = data.mag.copy()
    mag[np.arange(len(mag)) % 4 != 0] = np.nan
    result = calibrate_mag(MagCapture(data.t, mag, data.acc, data.gyro))
    err = errors(result.matrix, result.bias, truth)
    assert all(err[k] < DESK[k] for k in DESK), err
    assert result.samples == np.isfinite(mag).all(axis=1).sum()


def test_desk_session_warns_with_the_missing_directions() -> None:
    data, _ = _session("desk", 0)
    result = calibrate_mag(data)
    assert result.coverage.share < 0.5
    [warning] = [w for w in result.warnings if "cover" in w]
    assert "field along +z" in warning and "roughly -z up" in warning


def test_a_given_field_scales_the_result() -> None:
    data, truth = _session("sphere", 0)
    result = calibrate_mag(data, MagSettings(field_ut=50.0))
    own = calibrate_mag(data)
    assert result.field_norm == 50.0 and result.field_given and "field_norm" not in result.stddev
    # the same fit, scaled: F / |det C|^(1/3) is the data's own radius both ways
    assert np.median(np.linalg.norm((data.mag - result.bias) @ result.correction.T, axis=1)) == pytest.approx(
        50.0, rel=2e-3)
    np.testing.assert_allclose(result.bias, own.bias, atol=1e-6)
    np.testing.assert_allclose(result.matrix / np.linalg.det(result.matrix) ** (1 / 3), own.matrix, atol=1e-9)
    assert own.stddev["field_norm"] > 0


def test_plain_ellipsoid_fails_the_desk_alignment_and_loses_hard_iron_near_level() -> None:
    """The autopilots' fit (ellipsoid only, magnetometer assumed aligned) cannot see the rotation
    and, on a near-level desk session, leaves the hard iron several times worse than the joint fit;
    Magneto misses the desk targets on hard iron and shape too."""
    data, truth = _session("desk", 0, max_tilt_deg=20.0)
    joint = errors(*_fit(calibrate_mag(data)), truth)
    plain = calibrate_mag(data, MagSettings(joint=False))
    assert plain.frame == "sensor"
    np.testing.assert_allclose(plain.matrix, plain.matrix.T, atol=1e-12)     # symmetric: no rotation
    algebraic = ellipsoid_fit(data.mag)
    assert algebraic is not None
    assert joint["align_deg"] < DESK["align_deg"] and joint["hard_ut"] < DESK["hard_ut"]
    algebraic_fit = (np.linalg.inv(algebraic.correction), algebraic.bias)
    hard, correction = magneto(data.mag, 50.0)
    magneto_err = errors(np.linalg.inv(correction), hard, truth)
    assert magneto_err["hard_ut"] > DESK["hard_ut"] and magneto_err["shape_pct"] > DESK["shape_pct"]
    for other in (errors(*_fit(plain), truth), errors(*algebraic_fit, truth), magneto_err):
        assert other["align_deg"] > 5 * DESK["align_deg"]
        assert other["hard_ut"] > 5 * joint["hard_ut"]


def _fit(result: MagCalibration) -> tuple[np.ndarray, np.ndarray]:
    return result.matrix, result.bias


def test_without_accelerometer_the_fit_is_symmetric_in_the_sensor_frame() -> None:
    data, truth = _session("sphere", 0)
    result = calibrate_mag(MagCapture(data.t, data.mag))
    assert result.frame == "sensor" and result.dip_deg is None
    assert any("no accelerometer" in w for w in result.warnings)
    err = errors(result.matrix, result.bias, truth)
    assert err["hard_ut"] < FULL["hard_ut"] and err["shape_pct"] < FULL["shape_pct"]


def test_still_only_when_level_gives_the_plain_fit_and_says_why() -> None:
    # the desk session's tilted holds cut to 0.1 s: the unit rests only when level
    cap, truth = mag_capture("desk", 7, hold_s=0.1)
    result = calibrate_mag(MagCapture(cap.t, cap.mag, calibrated_acc(cap.acc, truth), cap.gyro))
    assert result.frame == "sensor"
    assert any("within 10 deg of one tilt" in w and "several tilts" in w for w in result.warnings)


@pytest.mark.parametrize(("kind", "seed", "target"), [("sphere", 1, FULL), ("desk", 1, DESK)])
def test_raw_accelerometer_is_estimated_from_the_still_poses(kind: str, seed: int,
                                                              target: dict[str, float]) -> None:
    """No accelerometer calibration: its intrinsics estimated with the fit bring the alignment, measured
    in the accelerometer's lower-triangular frame (calibrate --method free's), within the targets; the
    raw accelerometer taken as it is misses them several times (0.21 deg on this sphere, 1.2 deg on
    this desk)."""
    cap, truth = mag_capture(kind, seed)
    data = MagCapture(cap.t, cap.mag, cap.acc, cap.gyro)
    result = calibrate_mag(data, MagSettings(estimate_accel=True))
    frame = lower_frame(truth)
    err = errors(result.matrix, result.bias, truth, frame)
    assert all(err[k] < target[k] for k in target), err
    assert result.accel_estimated and "accelerometer estimated" in result.method
    assert any("bias, scale and misalignment were estimated" in w for w in result.warnings)
    assert not any("looks uncalibrated" in w or "near level" in w for w in result.warnings)
    raw = errors(*_fit(calibrate_mag(data)), truth, frame)
    assert raw["align_deg"] > 2 * target["align_deg"]


def test_raw_accelerometer_near_level_holds_the_z_bias_and_says_so() -> None:
    """Within 20 deg of level the poses leave the z bias to the z scale and the z axis's tilt loose:
    the fit says so, its hard iron stays within the desk target and the alignment's error within
    3 times its 1-sigma (0.5 deg about x and y); the hard iron's z 1-sigma includes the held z bias
    (0.4 uT, against 0.1 with a calibrated accelerometer) and holds its error."""
    cap, truth = mag_capture("desk", 0, max_tilt_deg=20.0)
    result = calibrate_mag(MagCapture(cap.t, cap.mag, cap.acc, cap.gyro), MagSettings(estimate_accel=True))
    err = errors(result.matrix, result.bias, truth, lower_frame(truth))
    assert err["hard_ut"] < DESK["hard_ut"] and err["shape_pct"] < DESK["shape_pct"], err
    assert any("near level" in w and "z bias is not determined" in w for w in result.warnings)
    sigma = np.linalg.norm(result.stddev["alignment_deg"])
    assert 0.2 < sigma < 1.5 and err["align_deg"] < 3 * sigma
    assert 0.3 < result.stddev["bias"][2] < 0.6
    assert np.all(np.abs(result.bias - truth.mag.hard_iron) < 3 * result.stddev["bias"])


def test_uncalibrated_accelerometer_is_warned_about() -> None:
    cap, _ = mag_capture("sphere", 0)
    result = calibrate_mag(MagCapture(cap.t, cap.mag, cap.acc, cap.gyro))
    assert any("accelerometer looks uncalibrated" in w for w in result.warnings)


def _central_difference(residual, p: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """The Jacobian of ``residual`` at ``p`` by central differences of one absolute step (the fit's
    parameters are all of order one; test_calib_jacobians' relative steps suit raw counts instead)."""
    numeric = np.empty((len(residual(p)), len(p)))
    for k in range(len(p)):
        dp = np.zeros_like(p)
        dp[k] = step
        numeric[:, k] = (residual(p + dp) - residual(p - dp)) / (2 * step)
    return numeric


def test_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(3)
    m = rng.normal(size=(60, 3)) * 40 + 5
    down = rng.normal(size=(25, 3))
    down /= np.linalg.norm(down, axis=1)[:, None]
    correction = np.eye(3) * 1.1 + 0.05 * rng.normal(size=(3, 3))
    for still, d in ((m[:25], down), (np.zeros((0, 3)), np.zeros((0, 3)))):
        problem = JointProblem(m, still, d, 50.0, rng.uniform(0.5, 2, 60), 1.3)
        p = problem.pack(rng.normal(size=3), correction, 0.8)
        np.testing.assert_allclose(problem.jacobian(p), _central_difference(problem.residual, p), rtol=0,
                                   atol=1e-6)
    # with the accelerometer's intrinsics estimated (mag_accel eq. (3)), all nine or all but the z bias
    x = rng.normal(size=(25, 3))
    x = 9.8 * x / np.linalg.norm(x, axis=1)[:, None] + 0.1
    for free in (ALL, NO_Z_BIAS):
        acc = PoseAccel(x, 9.8, free)
        problem = JointProblem(m, m[:25], down, 50.0, rng.uniform(0.5, 2, 60), 1.3, acc,
                               rng.uniform(0.5, 2, 25))
        intrinsics = np.concatenate([rng.normal(0, 0.01, 3), 1 + rng.normal(0, 0.01, 3),
                                     rng.normal(0, 0.1, 3)])
        p = problem.pack(rng.normal(size=3), correction, 0.8, acc.reduced(intrinsics))
        np.testing.assert_allclose(problem.jacobian(p), _central_difference(problem.residual, p), rtol=0,
                                   atol=1e-6)


def test_plain_fit_agrees_with_magneto_on_a_full_sphere() -> None:
    data, truth = _session("sphere", 1)
    hard, correction = magneto(data.mag, 50.0)
    plain = calibrate_mag(MagCapture(data.t, data.mag), MagSettings(field_ut=50.0))
    assert np.linalg.norm(plain.bias - hard) < 0.02                      # uT
    # both symmetric corrections to 50 uT: the same matrix
    np.testing.assert_allclose(plain.correction, correction, atol=2e-4)
    # and the joint fit's symmetric part is the same ellipsoid
    joint = calibrate_mag(data, MagSettings(field_ut=50.0))
    np.testing.assert_allclose(polar(joint.correction.T)[0], correction, atol=2e-4)
    assert errors(np.linalg.inv(correction), hard, truth)["hard_ut"] < FULL["hard_ut"]


# --- bad input and disturbances --------------------------------------------------------------------

def test_no_magnetometer_sample_is_refused() -> None:
    with pytest.raises(EngineInputError, match="no magnetometer sample"):
        calibrate_mag(MagCapture(np.arange(10.0), np.full((10, 3), np.nan)))


def test_constant_readings_are_refused() -> None:
    data, _ = _session("sphere", 0)
    mag = data.mag.copy()
    mag[:, 1] = 0.0
    with pytest.raises(EngineInputError, match=r"constant value .*my = 0 uT.*capture again while turning"):
        calibrate_mag(MagCapture(data.t, mag, data.acc))


def test_saturated_readings_are_refused() -> None:
    data, _ = _session("sphere", 0)
    mag = data.mag.copy()
    mag[:, 0] = np.minimum(mag[:, 0], np.percentile(mag[:, 0], 80))
    with pytest.raises(EngineInputError, match=r"x axis is pinned at .* saturated.*larger range"):
        calibrate_mag(MagCapture(data.t, mag, data.acc))


def test_too_few_directions_are_refused() -> None:
    # turned about the vertical only: the directions lie on a cone's rim, a plane of the sphere
    t = np.arange(2000) / 100.0
    yaw = t * 0.6
    field = 50 * np.column_stack([0.5 * np.cos(yaw), -0.5 * np.sin(yaw), np.full_like(t, -0.866)])
    rng = np.random.default_rng(0)
    with pytest.raises(EngineInputError, match="one plane.*about all its axes"):
        calibrate_mag(MagCapture(t, field + 10 + rng.normal(0, 0.15, field.shape)))
    # a little more: a narrow cap
    tilt = 0.15 * np.sin(t * 0.37)
    polar_angle = tilt + 0.2
    cap = np.column_stack([np.sin(polar_angle) * np.cos(yaw), np.sin(polar_angle) * np.sin(yaw),
                           -np.cos(polar_angle)])
    with pytest.raises(EngineInputError, match=r"cover \d+% of the sphere, too few.*field along"):
        calibrate_mag(MagCapture(t, 50 * cap + rng.normal(0, 0.15, cap.shape)))


def test_disturbed_stretch_is_left_out_and_named() -> None:
    data, truth = _session("sphere", 0)
    mag = data.mag.copy()
    hit = (data.t > 20.0) & (data.t < 23.0)
    mag[hit] += np.array([6.0, -4.0, 3.0]) * np.sin(np.pi * (data.t[hit] - 20.0) / 3.0)[:, None]
    result = calibrate_mag(MagCapture(data.t, mag, data.acc, data.gyro))
    [stretch] = result.disturbances
    assert 19.5 < stretch.t0 < 20.6 and 22.4 < stretch.t1 < 23.5
    assert any("left out 1 disturbed stretch" in w and "20." in w for w in result.warnings)
    err = errors(result.matrix, result.bias, truth)
    assert all(err[k] < FULL[k] for k in FULL), err
    # without detection the same stretch would cost accuracy: it is really in the data
    assert np.max(np.abs(np.linalg.norm((mag[hit] - result.bias) @ result.correction.T, axis=1)
                         - result.field_norm)) > 3.0


def test_capture_disturbed_throughout_is_refused() -> None:
    data, truth = _session("sphere", 0)
    # the field 10 % stronger for 2.5 s of every 4: whichever level is taken for the Earth's, the
    # other covers more than a quarter of the capture
    mag = data.mag.copy()
    near = data.t % 4.0 < 2.5
    mag[near] = truth.mag.hard_iron + 1.1 * (mag[near] - truth.mag.hard_iron)
    with pytest.raises(EngineInputError, match="(magnitude jumps|times the magnetometer's noise).*away from"):
        calibrate_mag(MagCapture(data.t, mag, data.acc, data.gyro))
    # jumps in stretches covering more than a quarter of the capture, detected as such
    mag = data.mag.copy()
    near = data.t % 4.0 < 1.2
    mag[near] = truth.mag.hard_iron + 1.1 * (mag[near] - truth.mag.hard_iron)
    with pytest.raises(EngineInputError, match="magnitude jumps in .* stretches covering .*away from"):
        calibrate_mag(MagCapture(data.t, mag, data.acc, data.gyro))


def test_residual_far_above_the_noise_is_warned_about() -> None:
    data, truth = _session("sphere", 0)
    # a hard iron that changes by 1.5 uT every other 2 s (a magnet carried with the unit, on and off)
    mag = data.mag + np.where((data.t % 4.0 < 2.0)[:, None], np.array([1.5, 1.5, 1.5]), 0.0)
    result = calibrate_mag(MagCapture(data.t, mag, data.acc, data.gyro))
    assert any("times the magnetometer's noise" in w for w in result.warnings)
    assert not any("noise" in w for w in calibrate_mag(data).warnings)
