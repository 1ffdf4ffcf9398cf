"""Turntable-free (Tedaldi / imu_tk) method: simulated hand-held sessions against the truth, the
exact convention conversion, imu_tk's published result on its own Xsens session, and refusals.

The simulated session: 30 s still, then 36 random attitudes held 8 s each, joined by 2 s moves,
100 Hz, realistic MEMS noise (``UnitTruth.random``)."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from mocks.rig import handheld_session, simulate
from mocks.truth import UnitTruth
from station.engines.calibration.common import convert_convention
from station.engines.calibration.free import FreeCapture, FreeSettings, calibrate_free
from station.errors import EngineInputError


@pytest.fixture(scope="module")
def session():
    truth = UnitTruth.random(4)
    segments = handheld_session(n_poses=36, seed=4, hold_s=8.0, initial_still_s=30.0)
    rec = simulate(truth, segments, rate_hz=100.0, seed=4)
    return truth, rec


@pytest.fixture(scope="module")
def lower(session):
    truth, rec = session
    return calibrate_free(FreeCapture(rec.t, rec.acc, rec.gyro),
                          FreeSettings(gravity=truth.gravity, convention="lower"))


def test_handheld_session_recovers_truth_in_the_lecture_body_frame(session, lower) -> None:
    truth, rec = session
    # the truth is in the sensor frame; the lower-triangular body frame is a rotation of it
    acc_c, gyro_c, _ = convert_convention(np.linalg.inv(truth.accel.matrix), np.linalg.inv(truth.gyro.matrix),
                                          "lower")
    assert 20 <= lower.details["initial_still_s"] <= 32
    for cal, c_true, b_true, bias_tol in ((lower.accel, acc_c, truth.accel.bias, 1e-3),
                                          (lower.gyro, gyro_c, truth.gyro.bias, 1e-4)):
        dm = cal.matrix - np.linalg.inv(c_true)
        db = cal.bias - b_true
        assert np.abs(dm).max() < 2e-4
        assert np.abs(db).max() < bias_tol
        free = cal.stddev["matrix"] > 0          # the lower triangle's zeros are fixed, not estimated
        assert np.all(np.abs(dm[free]) < 3 * cal.stddev["matrix"][free])
        assert np.all(np.abs(dm[~free]) < 1e-12)
        assert np.all(np.abs(db) < 3 * cal.stddev["bias"])
    assert np.allclose(np.triu(lower.accel.matrix, 1), 0, atol=1e-12)
    assert lower.warnings == []


def test_upper_convention_is_the_exact_rotation_of_the_lower_one(session, lower) -> None:
    truth, rec = session
    still = lower.details["initial_still_s"]
    upper = calibrate_free(FreeCapture(rec.t, rec.acc, rec.gyro, initial_still_s=still),
                           FreeSettings(gravity=truth.gravity, convention="upper"))
    acc_c, gyro_c, _ = convert_convention(lower.details["accel_correction"], lower.details["gyro_correction"],
                                          "upper")
    np.testing.assert_allclose(upper.details["accel_correction"], acc_c, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(upper.details["gyro_correction"], gyro_c, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(upper.accel.bias, lower.accel.bias, rtol=1e-7)
    assert upper.details["acc_cost"] == pytest.approx(lower.details["acc_cost"], rel=1e-8)


def test_reversed_gyro_axes_and_per_interval_bias() -> None:
    truth = UnitTruth.random(14)
    truth.gyro.scale = truth.gyro.scale * np.array([-1.0, 1.0, -1.0])   # x and z gyro mounted reversed
    segments = handheld_session(n_poses=30, seed=14, hold_s=6.0, initial_still_s=20.0)
    rec = simulate(truth, segments, rate_hz=100.0, seed=14)
    report = calibrate_free(FreeCapture(rec.t, rec.acc, rec.gyro),
                            FreeSettings(gravity=truth.gravity, convention="lower", gyro_bias="intervals"))
    _, gyro_c, _ = convert_convention(np.linalg.inv(truth.accel.matrix), np.linalg.inv(truth.gyro.matrix),
                                      "lower")
    assert np.abs(report.gyro.matrix - np.linalg.inv(gyro_c)).max() < 2e-4
    assert np.abs(report.gyro.bias - truth.gyro.bias).max() < 1e-4
    assert np.all(np.sign(np.diag(report.gyro.matrix)) == [-1, 1, -1])


def test_refuses_saturated_moves(session) -> None:
    truth, rec = session
    limit = 0.6 * np.abs(rec.gyro).max()
    with pytest.raises(EngineInputError, match=r"gyroscope . axis is saturated at t = "):
        calibrate_free(FreeCapture(rec.t, rec.acc, np.clip(rec.gyro, -limit, limit)),
                       FreeSettings(gravity=truth.gravity))


def _read_imu_tk(path) -> np.ndarray:
    """imu_tk's ASCII data: ``t x y z`` per line, spaces, gzipped here."""
    with gzip.open(path, "rt") as fh:
        return np.loadtxt(fh)


@pytest.fixture(scope="module")
def xsens(reference_data):
    folder = reference_data / "xsens-imu_tk"
    acc = _read_imu_tk(folder / "xsens_acc.txt.gz")
    gyro = _read_imu_tk(folder / "xsens_gyro.txt.gz")
    assert acc.shape == (51175, 4) and np.array_equal(acc[:, 0], gyro[:, 0])
    return acc, gyro


def test_reproduces_imu_tk_on_its_xsens_session(xsens) -> None:
    acc, gyro = xsens
    report = calibrate_free(FreeCapture(acc[:, 0], acc[:, 1:], gyro[:, 1:], initial_still_s=50.0),
                            FreeSettings.imu_tk(gravity=9.81744, convention="upper"))
    # imu_tk's still period ends at the sample nearest t0 + 50 s: t0 = 0.02984 s and the timestamps are
    # irregular, so that is sample 5001 (t = 50.0346 s), not 5000; the gyro bias is their mean
    assert report.details["still_samples"] == 5002
    published_counts = [42, 40, 39, 38, 38, 38, 38, 38, 38]
    published_costs = [0.134724, 0.131345, 0.126126, 0.120558, 0.120131, 0.120586, 0.121338, 0.121422,
                       0.138240]
    trials = report.details["trials"]
    assert [tr["intervals"] for tr in trials] == published_counts
    # published to 6 digits: half a unit of the last one is at most 4.2e-6 relative here
    np.testing.assert_allclose([tr["cost"] for tr in trials], published_costs, rtol=5e-6)
    assert report.details["chosen_multiplier"] == 6

    c = report.details["accel_correction"]
    k = np.diag(c)
    t = c / k[None, :]
    np.testing.assert_allclose(t, [[1, -0.0033593, -0.00890639], [0, 1, -0.0213341], [0, 0, 1]], rtol=2e-5,
                               atol=1e-12)
    np.testing.assert_allclose(k, [0.00241278, 0.00242712, 0.00241168], rtol=3e-6)
    np.testing.assert_allclose(report.accel.bias, [33124.2, 33275.2, 32364.4], atol=0.05)

    g = report.details["gyro_correction"]
    assert report.gyro.extra["blocks"] == 37
    assert report.details["gyro_cost"] == pytest.approx(0.00150696, rel=5e-6)
    np.testing.assert_allclose(1 / np.diag(g), [4777.96, 4764.21, 4773.66], rtol=2e-6)
    published_t = np.array([[1, 0.00593634, 0.00111101], [0.00808812, 1, -0.0535569],
                            [0.0253067, -0.0025513, 1]])
    # Every term within half a unit of its last published digit (<= 4.5e-6 relative) except T_xz, which
    # is 1.1e-5 off: imu_tk's Ceres run stops at its function tolerance (1e-6) before the minimum we reach,
    # and that stop moves T_xz by 1.0e-5 relative (a Ceres build of the same problem gives 0.00111100949 at
    # its default stop and 0.00111099816 converged; ours is the latter).
    np.testing.assert_allclose(g / np.diag(g)[None, :], published_t, rtol=2e-5)
    np.testing.assert_allclose(report.gyro.bias, [32777.1, 32459.8, 32511.8], atol=0.05)


def test_default_settings_give_xsens_factory_gains(xsens) -> None:
    acc, gyro = xsens
    report = calibrate_free(FreeCapture(acc[:, 0], acc[:, 1:], gyro[:, 1:]), FreeSettings(gravity=9.81744))
    # the initial still period (about 50 s) is found without being told
    assert 45 <= report.details["initial_still_s"] <= 55
    np.testing.assert_allclose(report.accel.scale, [415, 413, 415], rtol=3e-3)   # counts per m/s^2
    np.testing.assert_allclose(report.accel.bias, [33123, 33276, 32360], atol=6)
    np.testing.assert_allclose(np.abs(report.gyro.scale), [4778, 4758, 4766], rtol=3e-3)


def test_refuses_too_few_static_intervals_and_a_moving_start() -> None:
    truth = UnitTruth.random(9)
    segments = handheld_session(n_poses=6, seed=9, hold_s=3.0, initial_still_s=15.0)
    rec = simulate(truth, segments, rate_hz=100.0, seed=9)
    with pytest.raises(EngineInputError, match="too few static intervals"):
        calibrate_free(FreeCapture(rec.t, rec.acc, rec.gyro), FreeSettings(gravity=truth.gravity))
    start = int(16.0 * 100)  # cut the still period: the data start with a move
    with pytest.raises(EngineInputError, match="no initial still period"):
        calibrate_free(FreeCapture(rec.t[start:], rec.acc[start:], rec.gyro[start:]),
                       FreeSettings(gravity=truth.gravity))


def _interval_mean(values: np.ndarray, t: np.ndarray, poses: list[dict]) -> np.ndarray:
    """Mean over the static intervals of each interval's mean (the free method weighs intervals alike)."""
    return np.mean([values[(t >= p["t0"]) & (t <= p["t1"])].mean(axis=0) for p in poses], axis=0)


def test_monte_carlo_over_fresh_handheld_sessions() -> None:
    """Seeds 100..105, fixed before any run: a new UnitTruth.random(seed) each, the module's session.

    The issue's tolerances apply to the bias the unit really had over the static intervals
    (``Recording.acc_bias``/``gyro_bias``); the reported sigma, which carries the drift budget, must
    cover the static truth.bias as well. Matrices in the lower-triangular body frame."""
    for seed in range(100, 106):
        truth = UnitTruth.random(seed)
        segments = handheld_session(n_poses=36, seed=seed, hold_s=8.0, initial_still_s=30.0)
        rec = simulate(truth, segments, rate_hz=100.0, seed=seed)
        report = calibrate_free(FreeCapture(rec.t, rec.acc, rec.gyro), FreeSettings(gravity=truth.gravity))
        acc_c, gyro_c, _ = convert_convention(np.linalg.inv(truth.accel.matrix),
                                              np.linalg.inv(truth.gyro.matrix), "lower")
        for cal, c_true, tr, realized, tol in (
                (report.accel, acc_c, truth.accel, rec.acc_bias, 1e-3),
                (report.gyro, gyro_c, truth.gyro, rec.gyro_bias, 1e-4)):
            dm = cal.matrix - np.linalg.inv(c_true)
            free = cal.stddev["matrix"] > 0
            assert np.abs(dm).max() < 2e-4, seed
            assert np.all(np.abs(dm[free]) < 3 * cal.stddev["matrix"][free]), seed
            real = _interval_mean(realized, rec.t, report.poses)
            assert np.abs(cal.bias - real).max() < tol, (seed, cal.bias - real)
            assert np.all(np.abs(cal.bias - tr.bias) < 3 * cal.stddev["bias"]), seed
