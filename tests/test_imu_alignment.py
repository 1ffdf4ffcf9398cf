"""The relative rotation between IMUs (station.engines.calibration.imu_alignment): eq. (2) against scipy's
Rotation.align_vectors and a closed-form Kabsch solution, the 1-sigma of eq. (3) against a Monte Carlo,
turns combined with poses, parallel poses refused, time spans read at two sample rates."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from station.engines.calibration.imu_alignment import (
    AlignmentVectors,
    own_axes,
    pose_means,
    relative_rotation,
    rotation_vector,
    turn_integrals,
    wahba,
)
from station.errors import EngineInputError

G = 9.80665
TWELVE = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                   [1, 1, 0], [-1, -1, 0], [0, 1, 1], [0, -1, -1], [1, 0, 1], [-1, 0, -1]], float)
TWELVE = G * TWELVE / np.linalg.norm(TWELVE, axis=1, keepdims=True)


def _kabsch(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Kabsch (1976): the rotation taking rows of a onto rows of b, from the weighted covariance's SVD."""
    h = (a * w[:, None]).T @ b
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1, 1, d]) @ u.T


def test_wahba_is_scipys_align_vectors_and_kabsch() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        truth = Rotation.random(random_state=rng)
        v0 = rng.normal(size=(8, 3))
        vk = truth.apply(v0) + rng.normal(scale=0.05, size=(8, 3))
        w = rng.uniform(0.5, 2.0, 8)
        ours = wahba(v0, vk, w)
        theirs, _ = Rotation.align_vectors(vk, v0, weights=w)
        assert np.allclose(ours, theirs.as_matrix(), atol=1e-10)
        assert np.allclose(ours, _kabsch(v0, vk, w), atol=1e-10)
        assert np.isclose(np.linalg.det(ours), 1.0)


def test_sigma_matches_a_monte_carlo_of_twelve_poses_and_six_turns() -> None:
    rng = np.random.default_rng(11)
    truth = Rotation.from_euler("xyz", [2.0, -1.5, 3.0], degrees=True).as_matrix()
    turns = np.repeat(np.eye(3), 2, axis=0) * np.tile([2 * np.pi, -2 * np.pi], 3)[:, None]
    acc_sd, gyro_sd = 2e-3, 3e-4  # per component of each vector, each IMU
    error_list, sigma_list = [], []
    for _ in range(400):
        v0 = TWELVE + rng.normal(scale=acc_sd, size=TWELVE.shape)
        vk = TWELVE @ truth.T + rng.normal(scale=acc_sd, size=TWELVE.shape)
        w0 = turns + rng.normal(scale=gyro_sd, size=turns.shape)
        wk = turns @ truth.T + rng.normal(scale=gyro_sd, size=turns.shape)
        first = AlignmentVectors(v0, np.full(12, acc_sd**2), w0, np.full(6, gyro_sd**2))
        other = AlignmentVectors(vk, np.full(12, acc_sd**2), wk, np.full(6, gyro_sd**2))
        rot = relative_rotation(first, other)
        error_list.append(rotation_vector(truth.T @ rot.matrix))
        sigma_list.append(rot.sigma)
    errors, sigmas = np.array(error_list), np.array(sigma_list)
    empirical = errors.std(axis=0)
    stated = np.median(sigmas, axis=0)
    # 400 draws: the empirical standard deviation is within ~7 % (1-sigma) of the true one
    assert np.all(np.abs(stated / empirical - 1.0) < 0.2), (stated, empirical)
    z = errors / sigmas
    assert 0.85 < z.std() < 1.15


def test_two_poses_suffice_and_one_direction_is_refused() -> None:
    truth = Rotation.from_rotvec([0.02, -0.03, 0.05]).as_matrix()
    two = TWELVE[[4, 0]]
    rot = relative_rotation(AlignmentVectors(two, np.full(2, 1e-6)),
                            AlignmentVectors(two @ truth.T, np.full(2, 1e-6)))
    assert np.allclose(rot.matrix, truth, atol=1e-9)
    parallel = TWELVE[[4, 5]]  # +z and -z: one axis
    with pytest.raises(EngineInputError, match="one way"):
        relative_rotation(AlignmentVectors(parallel, np.full(2, 1e-6)),
                          AlignmentVectors(parallel @ truth.T, np.full(2, 1e-6)))
    # a turn about another axis fixes the free rotation
    turn = np.array([[2 * np.pi, 0.0, 0.0]])
    rot = relative_rotation(AlignmentVectors(parallel, np.full(2, 1e-6), turn, np.full(1, 1e-8)),
                            AlignmentVectors(parallel @ truth.T, np.full(2, 1e-6), turn @ truth.T,
                                             np.full(1, 1e-8)))
    assert np.allclose(rot.matrix, truth, atol=1e-9)


def test_spans_average_the_same_stretch_at_two_rates() -> None:
    truth = Rotation.from_euler("z", 4.0, degrees=True).as_matrix()
    t0 = np.arange(0, 20, 1 / 200)
    t1 = np.arange(0.0013, 20, 1 / 250)

    def rate(t: np.ndarray) -> np.ndarray:  # a move between 5 and 7 s about (1, 1, 0), still elsewhere
        s = np.clip((t - 5.0) / 2.0, 0, 1)
        amp = np.where((s > 0) & (s < 1), 30.0 * s**2 * (1 - s) ** 2, 0.0) * np.pi / 2 / 2.0
        return amp[:, None] * np.array([1.0, 1.0, 0.0]) / np.sqrt(2)

    spans = [(2.0, 4.0), (8.0, 10.0)]
    move = [(3.0, 9.0)]
    force = np.tile([0, 0, G], (len(t0), 1))
    m0, _ = pose_means(t0, force, np.eye(3), np.zeros(3), spans)
    m1, _ = pose_means(t1, np.tile(truth @ [0, 0, G], (len(t1), 1)), np.eye(3), np.zeros(3), spans)
    assert np.allclose(m1, m0 @ truth.T)
    i0, _ = turn_integrals(t0, rate(t0), np.eye(3), np.zeros(3), move, 1e-6)
    i1, _ = turn_integrals(t1, rate(t1) @ truth.T, np.eye(3), np.zeros(3), move, 1e-6)
    assert np.allclose(np.linalg.norm(i0), np.pi / 2, rtol=1e-4)
    assert np.allclose(i1, i0 @ truth.T, atol=1e-5)


def test_own_axes_keep_the_mounting_rotation() -> None:
    mount = Rotation.from_euler("xyz", [1.0, 2.0, -3.0], degrees=True).as_matrix()
    m = np.array([[1.01, 0.0, 0.0], [0.002, 0.99, 0.0], [-0.001, 0.003, 1.02]])  # lower triangular
    fixture = np.linalg.inv(m @ mount)  # a turntable's correction takes the mounting out
    acc_c, gyro_c = own_axes(fixture, fixture, "lower")
    assert np.allclose(acc_c, np.linalg.inv(m), atol=1e-12)
    assert gyro_c is not None and np.allclose(gyro_c, np.linalg.inv(m), atol=1e-12)


def test_frame_covariance_matches_a_monte_carlo_of_the_matrix_error() -> None:
    """Eq. (4) against perturbed matrices: the own axes of M_hat + dM turned from those of M_hat."""
    from station.engines.calibration.common import triangular_correction
    from station.engines.calibration.imu_alignment import frame_covariance

    rng = np.random.default_rng(5)
    mount = Rotation.from_euler("xyz", [1.0, -2.0, 3.0], degrees=True).as_matrix()
    m_hat = np.array([[1.01, 0.003, -0.002], [0.001, 0.99, 0.004], [-0.003, 0.002, 1.02]]) @ mount
    sd = np.full((3, 3), 2e-4)
    q_hat, own_hat = triangular_correction(np.linalg.inv(m_hat), "lower")
    angles = []
    for _ in range(2000):
        m = m_hat + rng.normal(size=(3, 3)) * sd
        q, _ = triangular_correction(np.linalg.inv(m), "lower")
        a = own_hat @ m @ q
        angles.append(0.5 * np.array([a[2, 1] - a[1, 2], a[0, 2] - a[2, 0], a[1, 0] - a[0, 1]]))
    empirical = np.cov(np.array(angles).T)
    stated = frame_covariance(m_hat, sd, "lower")
    assert np.allclose(np.sqrt(np.diag(stated)), np.sqrt(np.diag(empirical)), rtol=0.08)
    # a lower-triangular fit holds the upper elements fixed: only the lower ones turn its axes
    lower = np.tril(np.full((3, 3), 2e-4))
    assert np.all(np.diag(frame_covariance(np.tril(m_hat), lower, "lower")) > 0)
