"""Analytic Jacobians and the numerical building blocks of the calibration engine, each against an
independent reference: central finite differences, scipy's ODE solver and Rotation, published gravity."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from station.engines.calibration.common import (
    convert_convention,
    pose_vector,
    rotation_of,
    triangular_correction,
)
from station.engines.calibration.free_accel import acc_jacobian, acc_residual
from station.engines.calibration.free_gyro import (
    GyroBlocks,
    GyroModel,
    bias_sensitivity,
    gyro_blocks,
    gyro_jacobian,
    gyro_residual,
)
from station.engines.shared import quaternion as quat
from station.engines.shared.earth import normal_gravity
from station.engines.shared.static_detect import moving_variance_norm, static_intervals


def central_difference(fun, p: np.ndarray, rel: float = 1e-6) -> np.ndarray:
    f0 = fun(p)
    jac = np.empty((len(f0), len(p)))
    for k in range(len(p)):
        h = rel * max(abs(p[k]), 1e-3)
        dp = np.zeros_like(p)
        dp[k] = h
        jac[:, k] = (fun(p + dp) - fun(p - dp)) / (2 * h)
    return jac


@pytest.mark.parametrize("convention", ["lower", "upper"])
def test_accelerometer_jacobian_equals_finite_differences(convention: str) -> None:
    rng = np.random.default_rng(1)
    # raw counts around 32768, as the Xsens session: the Jacobian must hold in any unit
    x = 32768 + 400 * 9.81 * rng.normal(size=(50, 3)) / np.sqrt(3) + rng.normal(0, 3, (50, 3))
    p = np.array([0.004, -0.009, 0.02, 1 / 414.0, 1 / 412.0, 1 / 415.0, 33120.0, 33270.0, 32360.0])
    analytic = acc_jacobian(p, x, 9.81, convention)
    numeric = central_difference(lambda q: acc_residual(q, x, 9.81, convention), p)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-7 * np.abs(numeric).max())


def _synthetic_blocks(seed: int) -> tuple:
    """A few moves between random attitudes, with uneven sample times and gravity directions."""
    rng = np.random.default_rng(seed)
    n = 400
    t = np.cumsum(rng.uniform(0.008, 0.012, n))
    rates = np.cumsum(rng.normal(0, 0.3, (n, 3)), axis=0) * 0.2
    intervals = np.array([[0, 20], [150, 170], [290, 310], [n - 20, n - 1]])
    for a, b in intervals:
        rates[a:b + 1] = 0.0
    directions = rng.normal(size=(len(intervals), 3))
    return gyro_blocks(t, rates * 100.0, intervals, directions)


def test_gyroscope_jacobian_equals_finite_differences() -> None:
    blocks = _synthetic_blocks(3)
    c = np.array([[1.01, 0.02, -0.01], [0.005, 0.98, 0.03], [-0.02, 0.01, 1.02]]) / 100.0
    analytic = gyro_jacobian(c.ravel(), blocks)
    numeric = central_difference(lambda q: gyro_residual(q, blocks), c.ravel())
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-8 * np.abs(numeric).max())


def test_gyroscope_bias_sensitivity_equals_finite_differences() -> None:
    blocks = _synthetic_blocks(7)
    c = np.array([[1.01, 0.02, -0.01], [0.005, 0.98, 0.03], [-0.02, 0.01, 1.02]]) / 100.0
    moving = (blocks.dt > 0)[..., None]
    base = np.full(3, 1e-3)
    model = GyroModel(GyroBlocks(blocks.x0 - base * moving, blocks.x1 - base * moving, blocks.dt, blocks.u0,
                                 blocks.u1, blocks.spans))
    model.jacobian(c.ravel())
    analytic = bias_sensitivity(model, c.ravel())

    def residual_with_bias(b: np.ndarray) -> np.ndarray:
        shifted = GyroBlocks(blocks.x0 - b * moving, blocks.x1 - b * moving, blocks.dt, blocks.u0, blocks.u1,
                             blocks.spans)
        return gyro_residual(c.ravel(), shifted)

    numeric = central_difference(residual_with_bias, np.full(3, 1e-3), rel=1e-3)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-8 * np.abs(numeric).max())


def test_rotate_inverse_derivative_equals_finite_differences() -> None:
    rng = np.random.default_rng(4)
    q = rng.normal(size=4) * 1.7
    u = rng.normal(size=3)
    r, d = quat.rotate_inverse(q, u)
    numeric = central_difference(lambda p: quat.rotate_inverse(p, u)[0], q)
    np.testing.assert_allclose(d, numeric, rtol=1e-6, atol=1e-9)
    # and the value itself against scipy (scalar-last quaternions there)
    expected = Rotation.from_quat(np.r_[q[1:], q[0]]).inv().apply(u)
    np.testing.assert_allclose(r, expected, rtol=1e-12, atol=1e-12)


def test_rk4_step_matches_scipy_ode_and_exact_rotation() -> None:
    # A smoothly varying body rate over 1 s, integrated in 200 RK4 steps and by scipy (rtol 1e-12).
    def rate(t: float) -> np.ndarray:
        return np.array([1.0 + 0.5 * np.sin(3 * t), -0.7 * np.cos(2 * t), 0.4 + t])

    ts = np.linspace(0.0, 1.0, 201)
    w = np.array([rate(t) for t in ts])
    a = quat.rk4_step_matrices(w[:-1], w[1:], np.diff(ts))
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for step in a:
        q = step @ q
    q /= np.linalg.norm(q)
    ref = solve_ivp(lambda t, y: 0.5 * quat.omega_matrix(rate(t)) @ y, (0, 1), [1.0, 0, 0, 0],
                    rtol=1e-12, atol=1e-12).y[:, -1]
    ref /= np.linalg.norm(ref)
    # RK4 with the mean rate at the midpoint (imu_tk's scheme) is accurate to O(dt^2) there
    np.testing.assert_allclose(q, ref, atol=2e-6)
    # A constant rate is integrated to the exact rotation exp(w t)
    wc = np.array([0.3, -1.2, 2.0])
    a = quat.rk4_step_matrices(np.tile(wc, (100, 1)), np.tile(wc, (100, 1)), np.full(100, 0.01))
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for step in a:
        q = step @ q
    exact = Rotation.from_rotvec(wc * 1.0).as_matrix()
    np.testing.assert_allclose(quat.to_rotation(q), exact, atol=1e-9)


def test_normal_gravity_matches_wgs84_published_values() -> None:
    # NIMA TR8350.2 table 3.4: normal gravity at the equator and the poles
    assert normal_gravity(0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert normal_gravity(90.0) == pytest.approx(9.8321849378, abs=1e-9)
    # between them, the international gravity formula 1980 series (accurate to about 1e-6 m/s^2)
    for lat in (15.0, 45.0, 70.0):
        s2 = np.sin(np.radians(lat)) ** 2
        series = 9.780327 * (1 + 0.0053024 * s2 - 0.0000058 * np.sin(np.radians(2 * lat)) ** 2)
        assert normal_gravity(lat) == pytest.approx(series, abs=3e-6)
    # free-air gradient about -3.086e-6 s^-2 per metre
    assert (normal_gravity(45.0, 1000.0) - normal_gravity(45.0)) == pytest.approx(-3.086e-3, rel=2e-3)


def test_convention_conversion_is_an_exact_rotation() -> None:
    rng = np.random.default_rng(5)
    acc_c = np.eye(3) * 0.0024 + rng.normal(0, 2e-5, (3, 3))
    gyro_c = np.eye(3) / 4770 + rng.normal(0, 2e-6, (3, 3))
    low_a, low_g, q_low = convert_convention(acc_c, gyro_c, "lower")
    up_a, up_g, q_up = convert_convention(acc_c, gyro_c, "upper")
    assert np.allclose(np.triu(low_a, 1), 0) and np.allclose(np.tril(up_a, -1), 0)
    assert np.all(np.diag(low_a) > 0) and np.all(np.diag(up_a) > 0)
    for q in (q_low, q_up):
        np.testing.assert_allclose(q @ q.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(q) == pytest.approx(1.0)
    # same sensor: both corrections give the same magnitudes and gravity/rate geometry
    np.testing.assert_allclose(q_low @ acc_c, low_a, atol=1e-15)
    np.testing.assert_allclose(q_up.T @ up_a, acc_c, atol=1e-15)
    np.testing.assert_allclose(q_up @ q_low.T @ low_g, up_g, atol=1e-15)
    back, _ = triangular_correction(up_a, "upper")
    np.testing.assert_allclose(back, np.eye(3), atol=1e-12)


def test_labels_follow_the_capture_spec() -> None:
    np.testing.assert_allclose(pose_vector("+z"), [0, 0, 1])
    np.testing.assert_allclose(pose_vector("-x"), [-1, 0, 0])
    np.testing.assert_allclose(pose_vector("+x+y"), np.array([1, 1, 0]) / np.sqrt(2))
    assert pose_vector("rot+z") is None and pose_vector("+x+x") is None
    axis, angle = rotation_of("rot-z")
    np.testing.assert_allclose(axis, [0, 0, 1])
    assert angle == pytest.approx(-2 * np.pi)
    assert rotation_of("rot+x:180")[1] == pytest.approx(np.pi)


def test_moving_variance_equals_two_pass_variance_on_raw_counts() -> None:
    rng = np.random.default_rng(6)
    x = 32768 + np.cumsum(rng.normal(0, 5, (3000, 3)), axis=0)
    v = moving_variance_norm(x, 101)
    direct = np.array([np.linalg.norm(x[i:i + 101].var(axis=0, ddof=1)) for i in range(len(x) - 100)])
    np.testing.assert_allclose(v, direct, rtol=1e-9)


def test_static_intervals_follow_imu_tk_rules() -> None:
    v = np.array([5, 1, 1, 1, 5, 5, 1, 1], dtype=float)
    # starts at the first value below, ends on the last value below; an open one ends at the end
    np.testing.assert_array_equal(static_intervals(v, 2.0, half=10), [[11, 13], [16, 17]])
    assert static_intervals(np.full(4, 9.0), 2.0, 10).shape == (0, 2)
