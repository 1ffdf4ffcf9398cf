"""The rotation of each IMU of a board relative to the first, from the same poses and turns.

Each IMU's own calibration brings its samples into its own axes: the frame its accelerometer defines
under the calibration's triangular convention (``common.triangular_correction``; lower: x along the
accelerometer's x, the xy plane its xy plane), the gyroscope re-expressed in the same frame
(``common.convert_convention``). Every IMU of the board feels the same specific force in each still pose
and turns by the same rotation in each move, so with v_k,i the i-th corrected vector of IMU k::

    v_k,i = R_k v_0,i + e_i                                                               (1)

R_k is the solution of Wahba's problem (Wahba 1965), minimising
L(R) = 1/2 sum_i w_i |v_k,i - R v_0,i|^2 with w_i = 1 / var_i, the inverse noise variance of one component
of the difference, by the SVD of the attitude profile matrix (Markley 1988, eqs. 3-11)::

    B = sum_i w_i v_k,i v_0,i^T = U S V^T,   R_k = U diag(1, 1, det U det V) V^T          (2)

The integral of a rate over a move transforms as the rate does (R_k is constant), whatever the move,
so the gyroscope's vectors are the corrected rates integrated between two still instants (eq. 1 holds
for them exactly). The error is the small rotation dtheta about the first IMU's axes,
R_k = R_k,hat exp([dtheta]x); to first order v_k,i - R_k,hat v_0,i = -R_k,hat [v_0,i]x dtheta, so the
Gauss-Newton covariance (Shuster & Oh 1981, eq. 62, with the scale from the residuals)::

    P = s^2 H^-1,   H = sum_i w_i (|v_0,i|^2 I - v_0,i v_0,i^T),
    s^2 = sum_i w_i |r_i|^2 / d * d / (d - 2),   d = 3 n - 3 - a                           (3)

``a`` the parameters the calibrations already fitted to the same vectors beyond the rotation (a turntable
fit's residuals have 3 P - 12 degrees of freedom, not 3 P - 3); the factor d / (d - 2) as
``common.covariance``. Each IMU's own axes are known only as well as its calibration: a misalignment error
turns the axes the convention builds on, which no residual of eq. (1) shows, so the covariance of that
turn (eq. 4, :func:`frame_covariance`) of both IMUs is added (``imu_board.board_rotations``). Gravity
alone fixes R_k only from two or more non-parallel poses (a rotation about the one direction seen is
free): refused otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from station.engines.calibration.common import convert_convention
from station.errors import EngineInputError

MIN_SPREAD = 0.01
"""The smallest second eigenvalue of the weighted direction scatter sum w u u^T / sum w that counts as two
directions (two poses 6 deg apart give 0.01): below it, a rotation about the common direction is free."""


@dataclass(frozen=True)
class AlignmentVectors:
    """What one IMU saw, in its own axes: per still pose the mean specific force (m/s^2) and per move
    the integrated rate (rad), each with the noise variance of one component.

    Attributes
    ----------
    accel : ndarray, (P, 3)
    accel_var : ndarray, (P,)
    gyro : ndarray, (Q, 3)
        Empty (0, 3) without turns.
    gyro_var : ndarray, (Q,)
    """

    accel: np.ndarray
    accel_var: np.ndarray
    gyro: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    gyro_var: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass
class RelativeRotation:
    """R_k of eq. (1) with its small-angle covariance (eq. 3) and what it rests on.

    Attributes
    ----------
    matrix : ndarray, (3, 3)
        R_k: v_k = R_k v_0 (the first IMU's vectors into this IMU's axes).
    covariance : ndarray, (3, 3)
        Of the small angles about the first IMU's x, y, z axes, rad^2.
    residual_rms : dict
        ``accel`` (m/s^2) and ``gyro`` (rad) RMS of |v_k - R_k v_0|, None where not used.
    poses, turns : int
        Vectors used.
    scale2 : float
        s^2 of eq. (3): near 1 when the stated noise explains the residuals.
    """

    matrix: np.ndarray
    covariance: np.ndarray
    residual_rms: dict[str, float | None]
    poses: int
    turns: int
    scale2: float

    @property
    def to_first(self) -> np.ndarray:
        """R_k^T: this IMU's vectors into the first IMU's axes."""
        return self.matrix.T

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of the small angles about the first IMU's x, y, z axes, rad (3,)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def angle(self) -> float:
        """The rotation angle of R_k, rad."""
        return float(np.arccos(np.clip((np.trace(self.matrix) - 1.0) / 2.0, -1.0, 1.0)))

    @property
    def rotation_vector(self) -> np.ndarray:
        """R_k as axis times angle (rad) about the first IMU's axes (3,)."""
        return rotation_vector(self.matrix)


def rotation_vector(matrix: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle, rad) of a rotation matrix (angles below 180 deg).

    Parameters
    ----------
    matrix : ndarray, (3, 3)

    Returns
    -------
    ndarray, (3,)
    """
    m = np.asarray(matrix, float)
    angle = float(np.arccos(np.clip((np.trace(m) - 1.0) / 2.0, -1.0, 1.0)))
    axis = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    norm = np.linalg.norm(axis)
    if norm < 1e-15:
        return np.zeros(3)
    return axis / norm * angle


def wahba(first: np.ndarray, other: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The rotation R minimising sum_i w_i |other_i - R first_i|^2: eq. (2) (Markley 1988).

    Parameters
    ----------
    first, other : ndarray, (n, 3)
        The same vectors in the first IMU's axes and in the other's.
    weights : ndarray, (n,)

    Returns
    -------
    ndarray, (3, 3)
        A proper rotation (det +1).
    """
    b = np.einsum("i,ij,ik->jk", np.asarray(weights, float), np.asarray(other, float),
                  np.asarray(first, float))
    u, _, vt = np.linalg.svd(b)
    d = np.diag([1.0, 1.0, np.linalg.det(u) * np.linalg.det(vt)])
    return u @ d @ vt


def own_axes(accel_correction: np.ndarray, gyro_correction: np.ndarray | None,
             convention: str = "lower") -> tuple[np.ndarray, np.ndarray | None]:
    """Both corrections re-expressed in the IMU's own axes (triangular accelerometer correction).

    A turntable calibration's correction brings the samples into the fixture's axes, which takes the
    IMU's mounting rotation out; the triangular form keeps it, so that eq. (1) can see it.

    Parameters
    ----------
    accel_correction : ndarray, (3, 3)
        M_a^-1 of the calibration.
    gyro_correction : ndarray, (3, 3) or None
        M_g^-1.
    convention : str
        ``lower`` or ``upper`` (``common.triangular_correction``).

    Returns
    -------
    tuple
        The accelerometer's and the gyroscope's corrections in the own axes.
    """
    acc_c, gyro_c, _ = convert_convention(accel_correction, gyro_correction, convention)
    return acc_c, gyro_c


def frame_covariance(matrix: np.ndarray, matrix_sd: np.ndarray, convention: str = "lower") -> np.ndarray:
    """Covariance of the small rotation between an IMU's own axes as calibrated and its true ones: eq. (4).

    The calibrated vectors are v_hat = C'_hat M Q v (v in the true own axes, M = Q C'^-1 the true matrix,
    C'_hat the triangular correction of the estimate M_hat), so they are turned from the true own axes by
    the antisymmetric part of A = C'_hat M Q - I; a misalignment error moves the axes the convention
    builds on (x along the accelerometer's x axis), which no residual of eq. (1) shows::

        theta = (A_21 - A_12, A_02 - A_20, A_10 - A_01) / 2,   P_frame = J diag(sd^2) J^T        (4)

    J the derivative of theta by the elements of M at M_hat (central differences), sd their 1-sigma
    (taken independent: the calibrations give one per element).

    Parameters
    ----------
    matrix : ndarray, (3, 3)
        M_hat of the accelerometer's calibration.
    matrix_sd : ndarray, (3, 3)
        Its 1-sigma per element (zero for the elements a triangular fit holds fixed).
    convention : str

    Returns
    -------
    ndarray, (3, 3)
        rad^2, about the IMU's own x, y, z axes.
    """
    from station.engines.calibration.common import triangular_correction

    m_hat = np.asarray(matrix, float)
    q_hat, own_hat = triangular_correction(np.linalg.inv(m_hat), convention)

    def theta(m: np.ndarray) -> np.ndarray:
        q, _ = triangular_correction(np.linalg.inv(m), convention)
        a = own_hat @ m @ q
        return 0.5 * np.array([a[2, 1] - a[1, 2], a[0, 2] - a[2, 0], a[1, 0] - a[0, 1]])

    sd = np.nan_to_num(np.asarray(matrix_sd, float).reshape(3, 3))
    jac = np.zeros((3, 9))
    for k in range(9):
        h = 1e-6 * max(abs(m_hat.flat[k]), 1.0)
        step = np.zeros(9)
        step[k] = h
        jac[:, k] = (theta(m_hat + step.reshape(3, 3)) - theta(m_hat - step.reshape(3, 3))) / (2 * h)
    return jac @ np.diag(sd.ravel() ** 2) @ jac.T


def select_span(t: np.ndarray, t0: float, t1: float) -> slice:
    """The samples of ``t`` (increasing) within [t0, t1], as a slice."""
    a, b = np.searchsorted(t, [t0, t1], side="left")
    b = max(b, np.searchsorted(t, t1, side="right"))
    return slice(int(a), int(b))


def pose_means(t: np.ndarray, raw: np.ndarray, correction: np.ndarray, bias: np.ndarray,
               spans: Sequence[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Each span's mean corrected vector, C (mean raw - b), and the variance of one of its components.

    The spans are times (s) on the board's one time base, so that IMUs sampled at other rates or
    instants average the same stretch.

    Parameters
    ----------
    t : ndarray, (N,)
    raw : ndarray, (N, 3)
    correction : ndarray, (3, 3)
    bias : ndarray, (3,)
    spans : sequence of (t0, t1)

    Returns
    -------
    tuple of ndarray
        Means (P, 3) and the white-noise variance of one component of each mean (P,).

    Raises
    ------
    EngineInputError
        A span with fewer than two samples of this IMU.
    """
    t = np.asarray(t, float)
    means, var = [], []
    for t0, t1 in spans:
        sl = select_span(t, t0, t1)
        n = sl.stop - sl.start
        if n < 2:
            raise EngineInputError(f"the still stretch t = {t0:.2f}..{t1:.2f} s holds {n} sample(s) of this "
                                   "IMU: its log does not cover the first IMU's time span")
        corrected = (np.asarray(raw[sl], float) - bias) @ np.asarray(correction, float).T
        means.append(corrected.mean(axis=0))
        var.append(float(np.mean(corrected.var(axis=0, ddof=1))) / n)
    return np.array(means).reshape(-1, 3), np.array(var)


def turn_integrals(t: np.ndarray, raw: np.ndarray, correction: np.ndarray, bias: np.ndarray,
                   spans: Sequence[tuple[float, float]], rate_var: float,
                   bias_var: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The corrected rate integrated over each span, and the variance of one component of it.

    The trapezoidal integral of C (raw - b) up to every sample is interpolated at t0 and t1, so the
    span is the same stretch of time whatever this IMU's rate; its white noise grows as
    rate_var * dt * T, a bias error as bias_var * T^2.

    Parameters
    ----------
    t : ndarray, (N,)
    raw : ndarray, (N, 3)
    correction : ndarray, (3, 3)
    bias : ndarray, (3,)
    spans : sequence of (t0, t1)
    rate_var : float
        Variance of one corrected rate sample (a still stretch's), (rad/s)^2.
    bias_var : float
        Variance of the bias estimate, (rad/s)^2.

    Returns
    -------
    tuple of ndarray
        Integrals (Q, 3) in rad and variances (Q,).
    """
    t = np.asarray(t, float)
    rate = (np.asarray(raw, float) - bias) @ np.asarray(correction, float).T
    steps = np.diff(t)
    cumulative = np.vstack([np.zeros(3), np.cumsum(0.5 * (rate[1:] + rate[:-1]) * steps[:, None], axis=0)])
    dt = float(np.median(steps)) if len(steps) else 0.0
    out, var = [], []
    for t0, t1 in spans:
        ends = np.array([[np.interp(x, t, cumulative[:, j]) for j in range(3)] for x in (t0, t1)])
        out.append(ends[1] - ends[0])
        length = t1 - t0
        var.append(rate_var * dt * length + bias_var * length**2)
    return np.array(out).reshape(-1, 3), np.array(var)


def _spread(vectors: np.ndarray, weights: np.ndarray) -> float:
    """The second eigenvalue of the weighted scatter of the vectors' directions (MIN_SPREAD)."""
    norm = np.linalg.norm(vectors, axis=1)
    keep = norm > 0
    u = vectors[keep] / norm[keep, None]
    w = weights[keep]
    if w.sum() <= 0:
        return 0.0
    scatter = np.einsum("i,ij,ik->jk", w, u, u) / w.sum()
    return float(np.sort(np.linalg.eigvalsh(scatter))[-2])


def relative_rotation(first: AlignmentVectors, other: AlignmentVectors,
                      absorbed: int = 0) -> RelativeRotation:
    """R_k of eq. (1) from both IMUs' poses and turns (eq. 2), with its covariance (eq. 3).

    Parameters
    ----------
    first, other : AlignmentVectors
        The same poses and moves seen by the first IMU and by IMU k, each in its own axes.
    absorbed : int
        Parameters the two calibrations fitted to these same vectors beyond the rotation (the
        ``a`` of eq. 3).

    Returns
    -------
    RelativeRotation

    Raises
    ------
    EngineInputError
        The two IMUs' vector counts differ, or the poses and turns are all (nearly) parallel (gravity
        alone: fewer than two non-parallel poses).
    """
    if len(first.accel) != len(other.accel) or len(first.gyro) != len(other.gyro):
        raise EngineInputError(f"the IMUs saw {len(first.accel)} and {len(other.accel)} still poses, "
                               f"{len(first.gyro)} and {len(other.gyro)} turns: they must be the same ones")
    v0 = np.vstack([first.accel, first.gyro])
    vk = np.vstack([other.accel, other.gyro])
    var = np.concatenate([first.accel_var + other.accel_var, first.gyro_var + other.gyro_var])
    if len(v0) == 0:
        raise EngineInputError("no still pose and no turn: nothing fixes the rotation between the IMUs")
    floor = np.finfo(float).tiny
    weights = 1.0 / np.maximum(var, floor)
    # the noise-free case (a simulated board without noise) has zero variances: equal weights per kind
    if not np.all(np.isfinite(weights)) or np.any(var <= 0):
        size = max(float(np.mean(np.linalg.norm(first.accel, axis=1))) if len(first.accel) else 1.0, 1e-9)
        weights = np.concatenate([np.full(len(first.accel), size**-2), np.full(len(first.gyro), 1.0)])
    if _spread(v0, weights) < MIN_SPREAD:
        what = ("the still poses" if len(first.gyro) == 0 else "the still poses and the turns")
        raise EngineInputError(f"{what} all point (nearly) one way: gravity in one pose leaves a rotation "
                               "about it free; hold the board still in two or more orientations at least "
                               "10 deg apart (flat and on a side), or add turns about two axes")
    r = wahba(v0, vk, weights)
    residual = vk - v0 @ r.T
    norms2 = np.einsum("ij,ij->i", v0, v0)
    h = np.einsum("i,jk->jk", weights * norms2, np.eye(3)) - np.einsum("i,ij,ik->jk", weights, v0, v0)
    dof = 3 * len(v0) - 3 - int(absorbed)
    chi2 = float(np.sum(weights * np.einsum("ij,ij->i", residual, residual)))
    if dof > 2:
        scale2 = chi2 / dof * dof / (dof - 2)
    else:
        scale2 = 1.0  # no spare residuals: the stated noise alone
    cov = scale2 * np.linalg.pinv(h)
    p = len(first.accel)

    def rms(part: np.ndarray) -> float | None:
        return float(np.sqrt(np.mean(np.einsum("ij,ij->i", part, part)))) if len(part) else None

    return RelativeRotation(r, cov, {"accel": rms(residual[:p]), "gyro": rms(residual[p:])}, p,
                            len(first.gyro), scale2)

