"""Turntable-free multi-position calibration (Tedaldi, Pretto, Menegatti, ICRA 2014).

The unit is held still in many arbitrary orientations, joined by hand-held moves, after an
initial still period. Static intervals are found by moving variance (``static_detect``).

Accelerometer (paper sec. IV-B): the calibrated specific force of a static sample is

    a = T K (x - b)                                                                 (8)

with K diagonal and T unit triangular (3 misalignment parameters: the body frame is tied to
the sensor). Its magnitude must equal local gravity; the residual is

    r = g - |a|          (paper eq. 10; imu_tk's MultiPosAccResidual)                 (10)

minimised by Levenberg-Marquardt with the analytic Jacobian, n = a/|a|, u = x - b, v = K u:

    dr/dT_ij = -n_i v_j,   dr/dk_j = -(n . T_:j) u_j,   dr/db_j = (n . T_:j) k_j      (11)

``upper``: T = [[1, -m_yz, m_zy], [0, 1, -m_zx], [0, 0, 1]] (imu_tk's parameters and order);
``lower``: T = [[1, 0, 0], [t_yx, 1, 0], [t_zx, t_zy, 1]] (the lecture: body x = accel x,
body xy plane = accel xy plane). The two differ by a rotation of the body frame; see
``calibration_common.convert_convention``. The detector is run for several threshold
multipliers and the result with the lowest cost kept.

Gyroscope (paper sec. IV-C): bias b_g = mean over the initial still period; the correction is
a full 3x3 C = T K (9 parameters: 6 misalignments and 3 scales). Between consecutive static
intervals k and k+1 the calibrated rates w = C (x - b_g) are integrated with an RK4 quaternion
step (``quaternion.rk4_step_matrices``) to R_k, and with u the unit gravity directions of the
calibrated accelerometer (interval means)

    r_k = R_k^T u_k - u_{k+1}          (paper eq. 15)                                (15)

The Jacobian is analytic: each step is q <- A(w_n, w_{n+1}) q, linear in q, so
dq = sum_n A_N..A_{n+1} dA_n A_{n-1}..A_1 q_0; it is evaluated in adjoint form for all
intervals at once (see ``_GyroModel``) and chained through R^T u (``quaternion.rotate_inverse``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from station.engines import quaternion as quat
from station.engines.calibration_common import (
    CalibrationReport,
    covariance,
    describe_null,
    dithers,
    drift_budget,
    lost_samples,
    pinned_run,
    stddev_from,
)
from station.engines.sensor_model import SensorCalibration
from station.engines.static_detect import moving_variance_norm, static_intervals, variance_norm
from station.errors import EngineInputError

_MIS_INDEX = {
    "upper": [(0, 1, -1.0), (0, 2, 1.0), (1, 2, -1.0)],   # m_yz, m_zy, m_zx (imu_tk)
    "lower": [(1, 0, 1.0), (2, 0, 1.0), (2, 1, 1.0)],     # t_yx, t_zx, t_zy
}
ACC_PARAM_NAMES = {
    "upper": ["m_yz", "m_zy", "m_zx", "k_x", "k_y", "k_z", "b_x", "b_y", "b_z"],
    "lower": ["t_yx", "t_zx", "t_zy", "k_x", "k_y", "k_z", "b_x", "b_y", "b_z"],
}
GYRO_PARAM_NAMES = [f"C_{i}{j}" for i in "xyz" for j in "xyz"]
# Fewest consecutive samples, and shortest time, pinned at an axis's extreme that count as saturation:
# a quantized rate reads one value for a few samples at the smooth peak of a move (about 30 ms at
# 1 LSB of a 16-bit +-2000 deg/s gyro, 2 rad/s peak); a clipped move stays pinned far longer.
SATURATION_RUN = 5
SATURATION_S = 0.1


@dataclass(frozen=True)
class FreeSettings:
    """Detector and fit settings. The defaults are the station's; :meth:`imu_tk` gives imu_tk's.

    window_s / window_samples: moving-variance window (odd number of samples; samples win).
    multipliers: threshold multipliers tried, threshold = k * variance norm of the still period.
    interval_samples: None: fit the mean of each static interval (one residual per pose); an
        integer n: fit the first n samples of each interval (imu_tk), intervals with
        end - start >= n only.
    min_interval_s: shortest static interval used when fitting means.
    cost: "mean" (mean of r^2, comparable across thresholds) or "half_sum" (1/2 sum r^2, Ceres).
    min_intervals: fewest static intervals a fit accepts (imu_tk: 12).
    inclusive_still_end: the still period ends at the sample nearest t0 + S, inclusive (imu_tk's
        initialInterval), rather than before t0 + S.
    gyro_bias: "intervals" (the station's default): each move between static intervals k and k+1
        subtracts the mean of the gyro over those two intervals, following a bias that drifts during
        the session, and the reported bias is the mean over all static intervals (the rate is zero
        in each, so they all measure it); "still": the mean of the initial still period (imu_tk).
    """

    window_s: float = 1.0
    window_samples: int | None = None
    multipliers: tuple[float, ...] = (2, 3, 4, 5, 6, 7, 8, 9, 10)
    interval_samples: int | None = None
    min_interval_s: float = 1.0
    cost: str = "mean"
    min_intervals: int = 12
    inclusive_still_end: bool = False
    gyro_bias: str = "intervals"

    @classmethod
    def imu_tk(cls) -> FreeSettings:
        """imu_tk's demo settings: 101-sample window, first 100 samples per interval, Ceres cost,
        gyro bias from the still period."""
        return cls(window_samples=101, interval_samples=100, cost="half_sum", inclusive_still_end=True,
                   gyro_bias="still")

    def window(self, rate_hz: float) -> int:
        w = self.window_samples if self.window_samples else int(round(self.window_s * rate_hz))
        return max(11, w + (1 - w % 2))


# ----------------------------------------------------------------------------------- accelerometer

def _acc_matrix(p: np.ndarray, convention: str) -> np.ndarray:
    t = np.eye(3)
    for (i, j, sign), m in zip(_MIS_INDEX[convention], p[:3], strict=True):
        t[i, j] = sign * m
    return t


def acc_residual(p: np.ndarray, x: np.ndarray, g: float, convention: str) -> np.ndarray:
    """Eq. (10): r = g - |T K (x - b)| for samples ``x`` (n, 3) and parameters ``p`` (9)."""
    t = _acc_matrix(p, convention)
    a = ((x - p[6:9]) * p[3:6]) @ t.T
    return g - np.linalg.norm(a, axis=1)


def acc_jacobian(p: np.ndarray, x: np.ndarray, g: float, convention: str) -> np.ndarray:
    """Eq. (11): the analytic Jacobian (n, 9) of :func:`acc_residual`."""
    t = _acc_matrix(p, convention)
    u = x - p[6:9]
    v = u * p[3:6]
    a = v @ t.T
    n = a / np.linalg.norm(a, axis=1, keepdims=True)
    nt = n @ t                                   # (n . T_:j)
    jac = np.empty((len(x), 9))
    for col, (i, j, sign) in enumerate(_MIS_INDEX[convention]):
        jac[:, col] = -sign * n[:, i] * v[:, j]
    jac[:, 3:6] = -nt * u
    jac[:, 6:9] = nt * p[3:6]
    return jac


def acc_initial_guess(x: np.ndarray, g: float) -> np.ndarray:
    """Data-driven start: an axis-aligned ellipsoid through the static samples (any raw unit).

    Solves sum_i a_i x_i^2 + c_i x_i = 1 by linear least squares; the centre is the bias and
    g / semi-axis the scale. Falls back to the mean and the spread where that is degenerate.
    """
    x = np.asarray(x, float)
    centre = x.mean(axis=0)
    spread = np.median(np.linalg.norm(x - centre, axis=1))
    span = spread if spread > 0 else 1.0
    z = (x - centre) / span
    design = np.hstack([z**2, z])
    coef, *_ = np.linalg.lstsq(design, np.ones(len(z)), rcond=None)
    a, c = coef[:3], coef[3:]
    if np.all(a > 0):
        b = -c / (2 * a)
        level = 1 + np.sum(c**2 / (4 * a))
        radius = np.sqrt(level / a)
        if level > 0 and np.all(np.isfinite(radius)) and np.all(np.abs(b) < 2 * radius):
            return np.concatenate([np.zeros(3), g / (radius * span), centre + b * span])
    return np.concatenate([np.zeros(3), np.full(3, g / span), centre])


@dataclass
class AccFit:
    params: np.ndarray
    cost: float
    residual: np.ndarray
    jacobian: np.ndarray
    n_intervals: int


def fit_accelerometer(x: np.ndarray, g: float, convention: str, cost: str = "mean",
                      start: np.ndarray | None = None) -> AccFit:
    """Levenberg-Marquardt on eq. (10) with the Jacobian of eq. (11); samples (n, 3) in any unit."""
    p0 = acc_initial_guess(x, g) if start is None else np.asarray(start, float)
    sol = least_squares(acc_residual, p0, jac=acc_jacobian, args=(x, g, convention), method="lm",
                        x_scale="jac", ftol=1e-14, xtol=1e-14, gtol=1e-14, max_nfev=2000)
    r = sol.fun
    value = float(np.mean(r**2)) if cost == "mean" else float(0.5 * r @ r)
    return AccFit(sol.x, value, r, acc_jacobian(sol.x, x, g, convention), 0)


def acc_correction(p: np.ndarray, convention: str) -> np.ndarray:
    """C = T K of eq. (8)."""
    return _acc_matrix(p, convention) * p[3:6]


# ---------------------------------------------------------------------------------------- gyroscope

@dataclass
class GyroBlocks:
    """Motion between consecutive static intervals, padded to one length for batch integration.

    ``x0``/``x1`` (B, L, 3): de-biased raw rates at each step's start and end; ``dt`` (B, L);
    padding steps have dt = 0 (an identity step). ``u0``/``u1`` (B, 3): gravity directions.
    """

    x0: np.ndarray
    x1: np.ndarray
    dt: np.ndarray
    u0: np.ndarray
    u1: np.ndarray
    spans: list[tuple[int, int]]


def gyro_blocks(t: np.ndarray, gyro_unbiased: np.ndarray, intervals: np.ndarray,
                directions: np.ndarray) -> GyroBlocks:
    """Integration ranges as imu_tk takes them: from the last sample of static interval k
    (t >= its end time) to the last sample before the start of interval k+1."""
    spans = []
    for k in range(len(intervals) - 1):
        i0 = int(np.searchsorted(t, t[intervals[k, 1]], side="left"))
        i1 = int(np.searchsorted(t, t[intervals[k + 1, 0]], side="left")) - 1
        spans.append((i0, max(i1, i0)))
    n_steps = [b - a for a, b in spans]
    length = max(1, max(n_steps, default=1))
    nb = len(spans)
    x0 = np.zeros((nb, length, 3))
    x1 = np.zeros((nb, length, 3))
    dt = np.zeros((nb, length))
    for k, (a, b) in enumerate(spans):
        m = b - a
        x0[k, :m] = gyro_unbiased[a:b]
        x1[k, :m] = gyro_unbiased[a + 1:b + 1]
        dt[k, :m] = np.diff(t[a:b + 1])
    u = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return GyroBlocks(x0, x1, dt, u[:-1], u[1:], spans)


def _product(a: np.ndarray) -> np.ndarray:
    """a[:, 0] (x) a[:, 1] (x) ... (x) a[:, L-1] for every row, by pairwise reduction over L."""
    while a.shape[1] > 1:
        if a.shape[1] % 2:
            identity = np.zeros((a.shape[0], 1, 4))
            identity[..., 0] = 1.0
            a = np.concatenate([a, identity], axis=1)
        a = quat.qmul(a[:, 0::2], a[:, 1::2])
    return a[:, 0]


def _scan(a: np.ndarray) -> np.ndarray:
    """Inclusive products along axis 1, element n = a[:, 0] (x) .. (x) a[:, n], by a Hillis-Steele
    scan: log2(L) vectorised passes instead of L sequential ones."""
    p = a.copy()
    shift = 1
    while shift < p.shape[1]:
        p[:, shift:] = quat.qmul(p[:, :-shift], p[:, shift:])
        shift *= 2
    return p


class _GyroModel:
    """Eq. (15) over all blocks for one C, and its Jacobian.

    Forward: s_{n+1} = s_n (x) a_n from s_0 = (1, 0, 0, 0) (``quaternion.rk4_step``), i.e.
    s_{n+1} = A_n s_n with A_n = R(a_n); the end quaternion by pairwise products. Jacobian: the adjoint rows
    lambda_n = (dr/dq) A_{N-1} .. A_{n+1} run backwards, and since dA_n s_n = s_n (x) da_n,

        dr/dC_ij = sum_n lambda_n L(s_n) (da_n/dw0_i x0_j + da_n/dw1_i x1_j)

    (w = C x, L the left-multiplication matrix). Padding steps (dt = 0, x = 0) are identities
    and add nothing.
    """

    def __init__(self, blocks: GyroBlocks):
        self.blocks = blocks
        self._key: bytes | None = None
        # Real steps only (padding has dt = 0), in block order, for the per-step algebra.
        self.mask = blocks.dt > 0
        self.x0 = blocks.x0[self.mask]
        self.x1 = blocks.x1[self.mask]
        self.dt = blocks.dt[self.mask]
        self.block_of = np.nonzero(self.mask)[0]
        self.first = np.searchsorted(self.block_of, np.arange(len(blocks.dt)))   # each block's first step
        self.empty = self.mask.sum(axis=1) == 0

    def _block_sums(self, per_step: np.ndarray) -> np.ndarray:
        """Sums of ``per_step`` (S, ...) over each block's steps (zero for a block without steps)."""
        sums = np.add.reduceat(per_step, np.minimum(self.first, len(per_step) - 1), axis=0)
        sums[self.empty] = 0.0
        return sums

    def _forward(self, cflat: np.ndarray) -> None:
        key = np.asarray(cflat, float).tobytes()
        if key == self._key:
            return
        c = np.asarray(cflat, float).reshape(3, 3)
        step, self.stages = quat.rk4_step(self.x0 @ c.T, self.x1 @ c.T, self.dt)
        nb, length = self.mask.shape
        a = np.zeros((nb, length, 4))
        a[..., 0] = 1.0
        a[self.mask] = step
        self.a = a
        self.final = _product(a)
        self.r, self.dr_dq = quat.rotate_inverse(self.final, self.blocks.u0)
        self._key = key

    def residual(self, cflat: np.ndarray) -> np.ndarray:
        self._forward(cflat)
        return (self.r - self.blocks.u1).ravel()

    def jacobian(self, cflat: np.ndarray) -> np.ndarray:
        self._forward(cflat)
        nb, length = self.mask.shape
        # s_n = P_{n-1} with P_n = a_0 (x) .. (x) a_n (a log-depth scan), and as A_{L-1} .. A_{n+1} =
        # R(a_{n+1} (x) .. (x) a_{L-1}) = R(P_n^-1 (x) q_final), lambda_n = (dr/dq) R(P_n^-1 (x) q_final)
        prefix = _scan(self.a)
        states = np.empty((nb, length, 4))
        states[:, 0] = (1.0, 0.0, 0.0, 0.0)
        states[:, 1:] = prefix[:, :-1]
        inverse = prefix * (np.array([1.0, -1.0, -1.0, -1.0]) / np.sum(prefix**2, axis=-1, keepdims=True))
        after = quat.qmul(inverse[self.mask], self.final[self.block_of])
        lam = self.dr_dq[self.block_of] @ quat.right_matrix(after)                   # (S, 3, 4)
        u = lam @ quat.left_matrix(states[self.mask])
        g0, g1 = quat.rk4_step_gradients(u, self.dt, self.stages)                   # (S, 3 res, 3 w)
        # dr/dw summed over each block: a constant rate offset d (a bias error) moves r by this @ d
        self.rate_gradient = self._block_sums(g0 + g1)
        per_step = g0[..., None] * self.x0[:, None, None, :] + g1[..., None] * self.x1[:, None, None, :]
        return self._block_sums(per_step).reshape(-1, 9)


def gyro_residual(cflat: np.ndarray, blocks: GyroBlocks) -> np.ndarray:
    """Eq. (15) for every block, stacked (3B,)."""
    return _GyroModel(blocks).residual(cflat)


def gyro_jacobian(cflat: np.ndarray, blocks: GyroBlocks) -> np.ndarray:
    """The analytic Jacobian (3B, 9) of :func:`gyro_residual` with respect to C (row-major)."""
    return _GyroModel(blocks).jacobian(cflat)


def gyro_initial_guess(blocks: GyroBlocks) -> np.ndarray:
    """Data-driven start C = diag(+-s): s from the angles between consecutive gravity directions
    over the integrated raw rate magnitude, signs and s refined on coarse grids of the residual."""
    angle = np.arccos(np.clip(np.sum(blocks.u0 * blocks.u1, axis=1), -1, 1)).sum()
    rate = np.sum(0.5 * (np.linalg.norm(blocks.x0, axis=2) + np.linalg.norm(blocks.x1, axis=2)) * blocks.dt)
    s0 = angle / rate if rate > 0 and angle > 0 else 1.0
    # the angle between gravity directions underestimates each move's rotation: search upwards
    model = _GyroModel(blocks)

    def cost(diagonal: np.ndarray) -> float:
        return float(np.sum(model.residual(np.diag(diagonal).ravel()) ** 2))

    # a gyro axis may be mounted reversed relative to the accelerometer's: pick the sign pattern
    # first (at a typical scale), then the scale with those signs
    signs = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], float)
    sign = signs[int(np.argmin([cost(1.7 * s0 * sg) for sg in signs]))]
    grid = s0 * np.geomspace(1.0, 3.0, 5)
    scale = grid[int(np.argmin([cost(s * sign) for s in grid]))]
    return np.diag(scale * sign).ravel()


def _direction_covariance(model: _GyroModel, cflat: np.ndarray, jac: np.ndarray, acc: np.ndarray,
                          intervals: np.ndarray, acc_params: np.ndarray, acc_cov: np.ndarray,
                          convention: str) -> np.ndarray:
    """Covariance the gyroscope's C inherits from the accelerometer fit through the gravity
    directions u_k (implicit-function theorem at the optimum of eq. 15):

        dC/dp_a = -(J^T J)^-1 J^T dr/dp_a,  dr/dp_a = R_k^T du_k/dp_a - du_{k+1}/dp_a,

    with du/dp_a by central differences of u = normalise(T K (mean - b)); cov = D cov_a D^T.
    """
    means = np.array([acc[a:b + 1].mean(axis=0) for a, b in intervals])

    def directions(p: np.ndarray) -> np.ndarray:
        u = (means - p[6:9]) @ acc_correction(p, convention).T
        return u / np.linalg.norm(u, axis=1, keepdims=True)

    du = np.empty((len(means), 3, len(acc_params)))
    for k in range(len(acc_params)):
        h = 1e-6 * max(abs(acc_params[k]), 1e-9) + 1e-3 * np.sqrt(max(acc_cov[k, k], 0.0))
        dp = np.zeros(len(acc_params))
        dp[k] = h
        du[:, :, k] = (directions(acc_params + dp) - directions(acc_params - dp)) / (2 * h)
    model.residual(cflat)
    rot = quat.to_rotation(model.final)
    dr = np.einsum("bji,bjk->bik", rot, du[:-1]) - du[1:]
    d = -np.linalg.pinv(jac.T @ jac) @ jac.T @ dr.reshape(-1, len(acc_params))
    return d @ acc_cov @ d.T


def bias_sensitivity(model: _GyroModel, cflat: np.ndarray) -> np.ndarray:
    """dr/db (3B, 3) of eq. (15) for the bias subtracted before integration: a bias error d shifts
    every rate by -C d, so dr/db = -(sum over the block's steps of dr/dw) C, from the adjoint pass
    of ``model.jacobian`` (which must have run at ``cflat``)."""
    return -(model.rate_gradient @ np.asarray(cflat, float).reshape(3, 3)).reshape(-1, 3)


def _bias_covariance(model: _GyroModel, cflat: np.ndarray, jac: np.ndarray,
                     bias_sd: np.ndarray) -> np.ndarray:
    """Covariance C inherits from the bias subtracted before integration (implicit-function theorem,
    as in :func:`_direction_covariance`)."""
    dr = bias_sensitivity(model, cflat)
    d = -np.linalg.pinv(jac.T @ jac) @ jac.T @ dr
    return d @ np.diag(np.asarray(bias_sd, float) ** 2) @ d.T


# A converged gyro fit leaves unit-vector residuals of a few hundredths at most.
GYRO_CONVERGED_RMS = 0.05


def fit_gyroscope(blocks: GyroBlocks, start: np.ndarray | None = None):
    """Levenberg-Marquardt on eq. (15) with its analytic Jacobian; returns scipy's solution.

    Should the data-driven start lead to a poor minimum, every sign pattern of the start's
    diagonal is tried and the best solution kept.
    """
    c0 = gyro_initial_guess(blocks) if start is None else np.asarray(start, float).ravel()
    model = _GyroModel(blocks)

    def solve(c: np.ndarray):
        return least_squares(model.residual, c, jac=model.jacobian, method="lm",
                             x_scale="jac", ftol=1e-9, xtol=1e-9, gtol=1e-10, max_nfev=200)

    best = solve(c0)
    if start is None and np.sqrt(np.mean(best.fun**2)) > GYRO_CONVERGED_RMS:
        diagonal = np.abs(np.diag(c0.reshape(3, 3)))
        for sx in (1, -1):
            for sy in (1, -1):
                for sz in (1, -1):
                    trial = solve(np.diag(diagonal * [sx, sy, sz]).ravel())
                    if trial.cost < best.cost:
                        best = trial
    return best


# ------------------------------------------------------------------------------------ the method

@dataclass
class ThresholdTrial:
    multiplier: float
    threshold: float
    n_intervals: int
    cost: float | None
    params: np.ndarray | None = field(default=None, repr=False)
    intervals: np.ndarray | None = field(default=None, repr=False)


def _still_samples(t: np.ndarray, initial_still_s: float, inclusive: bool) -> int:
    """Samples of the still period: those with t - t0 < S, or imu_tk's samples 0..i inclusive with
    i the sample whose timestamp is nearest t0 + S (ties to the later one). On irregular
    timestamps the two differ by a sample, which moves the gyro bias enough to matter."""
    if not inclusive:
        return min(len(t), int(np.searchsorted(t - t[0], initial_still_s, side="left")))
    end_ts = t[0] + initial_still_s
    after = min(len(t) - 1, max(1, int(np.searchsorted(t, end_ts, side="left"))))
    nearest = after - 1 if end_ts - t[after - 1] < t[after] - end_ts else after
    return nearest + 1


def detect_initial_still(t: np.ndarray, acc: np.ndarray, window: int) -> float:
    """Length (s) of the still period at the start: until the moving variance first exceeds ten
    times its level over the first second."""
    vnorm = moving_variance_norm(acc, window)
    rate = 1.0 / np.median(np.diff(t))
    head = vnorm[: max(1, int(rate))]
    level = float(np.median(head))
    above = np.flatnonzero(vnorm > 10 * max(level, np.finfo(float).tiny))
    end = int(above[0]) if len(above) else len(vnorm)
    return float(t[min(end, len(t) - 1)] - t[0])


def _interval_samples(acc: np.ndarray, intervals: np.ndarray, settings: FreeSettings,
                      min_len: int, half: int) -> tuple[np.ndarray, np.ndarray]:
    """The fit's samples and the intervals they come from (imu_tk: first n samples; else means).

    For means, each interval loses ``half // 2`` samples at either end (at most an eighth of it;
    ``half`` the detector's half window), counted once it passes ``min_len``: a move that starts
    or ends smoothly stays below the variance threshold for part of a window, most at high rates
    where the per-sample noise is large (1000 Hz: turning at up to 0.1 rad/s inside the detected
    intervals); those samples then belong to the move, whose integration they complete, and no
    longer bias the interval's means.
    """
    if settings.interval_samples:
        n = settings.interval_samples
        valid = intervals[(intervals[:, 1] - intervals[:, 0]) >= n]
        idx = (valid[:, :1] + np.arange(n)).ravel()
        return acc[idx], valid
    long_enough = intervals[(intervals[:, 1] - intervals[:, 0]) >= min_len]
    # at most an eighth of a short interval each end: its means need the samples
    trim = np.minimum(half // 2, (long_enough[:, 1] - long_enough[:, 0]) // 8)
    valid = long_enough + np.column_stack([trim, -trim])
    means = np.array([acc[a:b + 1].mean(axis=0) for a, b in valid]).reshape(-1, 3)
    return means, valid


def _check_gyro_saturation(t: np.ndarray, gyro: np.ndarray, n_still: int) -> None:
    """Refuse a session where a gyro axis sits at its extreme for several samples: the moves were
    too fast for the range and their integrated rotation is wrong. A still period whose noise does
    not exceed the output's resolution means the check cannot tell clipping from a steady signal, so
    it is skipped then (``calibration_common.dithers``)."""
    noisy = dithers(gyro[:n_still].std(axis=0), gyro[:n_still])
    shortest = max(SATURATION_RUN, int(round(SATURATION_S / float(np.median(np.diff(t))))))
    for i, axis in enumerate("xyz"):
        if not noisy[i]:
            continue
        for extreme in (gyro[:, i].max(), gyro[:, i].min()):
            start, run = pinned_run(gyro[:, i], extreme)
            if run >= shortest:
                raise EngineInputError(
                    f"the gyroscope {axis} axis is saturated at t = {t[start]:.2f} s (held at {extreme:g} "
                    f"for {run} samples): the moves were too fast for its range; move more slowly and "
                    "record again")


def _check_gaps(t: np.ndarray, spans: list[tuple[int, int]]) -> None:
    """Refuse lost samples inside a move: its integrated rotation (eq. 15) would be short. Gaps
    inside static intervals are harmless (nothing turns there)."""
    step = float(np.median(np.diff(t)))
    for a, b in spans:
        lost = lost_samples(t[a:b + 1], step)
        if lost is not None:
            k, size = lost
            raise EngineInputError(
                f"the move at t = {t[a]:.2f}..{t[b]:.2f} s has a gap of {size:.3f} s in its timestamps "
                f"(lost samples after t = {t[a + k]:.3f} s): the rotation integrated over it would be wrong; "
                "record the session again without losing samples")


def _check_rank(jac: np.ndarray, names: list[str], what: str) -> None:
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    # the tall Jacobian's singular values and directions are those of its QR factor R (p x p)
    sv, vt = np.linalg.svd(np.linalg.qr(jac / scale, mode="r"))[1:]
    if sv[-1] < 1e-9 * sv[0]:
        raise EngineInputError(
            f"the {what} poses cannot determine all parameters (rank deficient); the combination "
            f"{describe_null(vt[-1], names)} is free: hold the unit in more varied orientations "
            "(every axis up and down, and tilted between)")


def _coverage_warnings(u: np.ndarray, what: str) -> list[str]:
    """Warn when the static gravity directions do not spread over the sphere."""
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    warnings = []
    for i, axis in enumerate("xyz"):
        if u[:, i].max() < 0.5 or u[:, i].min() > -0.5:
            warnings.append(f"{what}: the {axis} axis was never held near both up and down "
                            f"(its gravity component spans {u[:, i].min():+.2f}..{u[:, i].max():+.2f} g); "
                            "its bias and scale are less certain")
    return warnings


def calibrate_free(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray, gravity: float,
                   initial_still_s: float | None = None, convention: str = "lower",
                   settings: FreeSettings | None = None) -> CalibrationReport:
    """Turntable-free calibration of both triads (module docstring, eqs. 8-15).

    Parameters
    ----------
    t : (N,) s, increasing.  acc, gyro : (N, 3) raw samples in any unit (counts, m/s^2, rad/s).
    gravity : local gravity magnitude g of eq. (10), m/s^2.
    initial_still_s : length of the initial still period; detected when None.
    convention : "lower" (lecture) or "upper" (imu_tk) triangular accelerometer misalignment.
    settings : detector and cost settings (:class:`FreeSettings`; ``FreeSettings.imu_tk()``).

    Returns
    -------
    CalibrationReport with accel and gyro :class:`SensorCalibration` (forward model
    raw = M true + b, M = C^-1), per-threshold trials, per-pose residuals and warnings.
    """
    settings = settings or FreeSettings()
    t = np.asarray(t, float)
    acc = np.asarray(acc, float)
    gyro = np.asarray(gyro, float)
    if convention not in _MIS_INDEX:
        raise ValueError(f"convention must be 'lower' or 'upper', got {convention!r}")
    if len(t) < 100:
        raise EngineInputError(f"only {len(t)} samples: a turntable-free calibration needs minutes of data")
    rate = 1.0 / float(np.median(np.diff(t)))
    window = settings.window(rate)
    half = window // 2
    warnings: list[str] = []
    if initial_still_s is None:
        initial_still_s = detect_initial_still(t, acc, window)
        # two detector windows: enough samples for the threshold's variance (imu_tk asks for more)
        if initial_still_s < 2 * window / rate:
            raise EngineInputError(
                f"no initial still period found (the unit moved after {initial_still_s:.1f} s): keep it "
                "still for the first 10 s or more, or give its length with --initial-still S")
    n_still = _still_samples(t, initial_still_s, settings.inclusive_still_end)
    if n_still < window:
        raise EngineInputError(f"the initial still period ({initial_still_s:g} s, {n_still} samples) is "
                               f"shorter than the detector window ({window} samples); record a longer one")
    base = variance_norm(acc[:n_still])
    if base <= 0:
        raise EngineInputError("the accelerometer does not vary at all during the still period (constant "
                               "values): the variance threshold needs sensor noise; is the stream frozen?")
    vnorm = moving_variance_norm(acc, window)
    min_len = max(2, int(round(settings.min_interval_s * rate)))

    trials: list[ThresholdTrial] = []
    best: tuple[ThresholdTrial, AccFit, np.ndarray, np.ndarray] | None = None
    for k in settings.multipliers:
        intervals = static_intervals(vnorm, k * base, half)
        samples, valid = _interval_samples(acc, intervals, settings, min_len, half)
        trial = ThresholdTrial(float(k), float(k * base), len(valid), None, intervals=valid)
        trials.append(trial)
        if len(valid) < settings.min_intervals:
            continue
        # thresholds close to each other find nearly the same intervals: start from the best fit so far
        fit = fit_accelerometer(samples, gravity, convention, settings.cost,
                                start=None if best is None else best[1].params)
        fit.n_intervals = len(valid)
        trial.cost, trial.params = fit.cost, fit.params
        if best is None or fit.cost < best[1].cost:
            best = (trial, fit, samples, valid)
    if best is None:
        found = ", ".join(f"k={tr.multiplier:g}: {tr.n_intervals}" for tr in trials)
        raise EngineInputError(
            f"too few static intervals ({found}; at least {settings.min_intervals} needed): hold the unit "
            f"still for {max(settings.interval_samples or 0, min_len) / rate:.1f} s or more in each of "
            f"{settings.min_intervals}+ orientations")
    trial, fit, samples, intervals = best
    _check_rank(fit.jacobian, ACC_PARAM_NAMES[convention], "accelerometer")
    acc_c = acc_correction(fit.params, convention)
    acc_b = fit.params[6:9]
    cov_a, _ = covariance(fit.jacobian, fit.residual)

    def acc_forward(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.linalg.inv(acc_correction(p, convention)), p[6:9]

    calibrated = (acc - acc_b) @ acc_c.T
    # Gravity directions: means over each whole interval (imu_tk).
    directions = np.array([calibrated[a:b + 1].mean(axis=0) for a, b in intervals])
    warnings += _coverage_warnings(directions, "accelerometer")
    pose_res = [float(g) for g in gravity - np.linalg.norm(directions, axis=1)]

    # Gyroscope
    _check_gyro_saturation(t, gyro, n_still)
    gyro_bias = gyro[:n_still].mean(axis=0)
    blocks = gyro_blocks(t, gyro - gyro_bias, intervals, directions)
    _check_gaps(t, blocks.spans)
    if settings.gyro_bias == "intervals":
        means = np.array([gyro[a:b + 1].mean(axis=0) for a, b in intervals]) - gyro_bias
        drift = 0.5 * (means[:-1] + means[1:])[:, None, :] * (blocks.dt > 0)[..., None]
        blocks = GyroBlocks(blocks.x0 - drift, blocks.x1 - drift, blocks.dt, blocks.u0, blocks.u1,
                            blocks.spans)
        gyro_bias = gyro_bias + means.mean(axis=0)
    elif settings.gyro_bias != "still":
        raise ValueError(f"gyro_bias must be 'still' or 'intervals', got {settings.gyro_bias!r}")
    sol = fit_gyroscope(blocks)
    model = _GyroModel(blocks)
    jac_g = model.jacobian(sol.x)
    _check_rank(jac_g, GYRO_PARAM_NAMES, "gyroscope")
    # eq. (15) compares unit vectors: two of each block's three residual components carry noise
    cov_g, _ = covariance(jac_g, sol.fun, observations=2 * len(blocks.spans))
    cov_g += _direction_covariance(model, sol.x, jac_g, acc, intervals, fit.params, cov_a, convention)
    gyro_c = sol.x.reshape(3, 3)
    # The rate is zero in every static interval, so the scatter of their gyro means shows how far
    # the bias wanders during the session (white noise alone would understate it). Drift budget as
    # in ``calibration_turntable``: the session-common offset is budgeted as the drift between intervals.
    interval_means = np.array([gyro[a:b + 1].mean(axis=0) for a, b in intervals])
    if settings.gyro_bias == "intervals":
        one_white = np.mean([gyro[a:b + 1].var(axis=0, ddof=1) / (b + 1 - a) for a, b in intervals], axis=0)
        drift = drift_budget(interval_means - interval_means.mean(axis=0), 1, one_white)
        bias_sd = np.sqrt(one_white / len(intervals) + drift)
    else:
        wander = interval_means.std(axis=0, ddof=1)
        bias_sd = np.sqrt(gyro[:n_still].var(axis=0, ddof=1) / n_still + wander**2)
    cov_g += _bias_covariance(model, sol.x, jac_g, bias_sd)

    def gyro_forward(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.linalg.inv(p.reshape(3, 3)), gyro_bias

    block_norm = np.linalg.norm(sol.fun.reshape(-1, 3), axis=1)
    if np.max(block_norm) > 0.2:
        worst = int(np.argmax(block_norm))
        a, b = blocks.spans[worst]
        warnings.append(f"gyroscope: the move between static intervals {worst} and {worst + 1} "
                        f"(t = {t[a]:.2f}..{t[b]:.2f} s) disagrees with the gravity directions by "
                        f"{np.degrees(2 * np.arcsin(min(1.0, block_norm[worst] / 2))):.1f} deg: "
                        "check for saturation or missed samples there")

    acc_sd = stddev_from(acc_forward, fit.params, cov_a)
    # Bias drift during the session is correlated in time, so the pose-to-pose scatter of the
    # residuals is added to the bias uncertainty without dividing it by the number of poses.
    # (pose_res is in m/s^2: an offset of that size in the true frame is M times it in raw units)
    acc_sd["bias"] = np.sqrt(acc_sd["bias"] ** 2
                             + np.mean(np.asarray(pose_res) ** 2) * np.sum(np.linalg.inv(acc_c) ** 2, axis=1))
    gyro_sd = stddev_from(gyro_forward, sol.x, cov_g)
    gyro_sd["bias"] = bias_sd
    method = f"free (Tedaldi 2014), {convention}-triangular accel misalignment"
    accel = SensorCalibration(np.linalg.inv(acc_c), acc_b, method=method,
                              residual_rms=float(np.sqrt(np.mean(fit.residual**2))), stddev=acc_sd,
                              extra={"convention": convention, "residual": "g - |a| (m/s^2)",
                                     "threshold_multiplier": trial.multiplier,
                                     "static_intervals": len(intervals)})
    gyro_cal = SensorCalibration(np.linalg.inv(gyro_c), gyro_bias, method=method,
                                 residual_rms=float(np.sqrt(np.mean(sol.fun**2))), stddev=gyro_sd,
                                 extra={"residual": "R^T u_k - u_k+1 (unit vectors)",
                                        "blocks": len(blocks.spans)})
    poses = [{"label": f"static {i}", "t0": float(t[a]), "t1": float(t[b]), "residual": pose_res[i],
              "gyro_residual": float(block_norm[i - 1]) if i > 0 else None}
             for i, (a, b) in enumerate(intervals)]
    details: dict[str, Any] = {
        "trials": [{"multiplier": tr.multiplier, "threshold": tr.threshold, "intervals": tr.n_intervals,
                    "cost": tr.cost} for tr in trials],
        "chosen_multiplier": trial.multiplier,
        "acc_params": dict(zip(ACC_PARAM_NAMES[convention], fit.params.tolist(), strict=True)),
        "acc_cost": fit.cost,
        "gyro_cost": float(0.5 * sol.fun @ sol.fun),
        "initial_still_s": float(initial_still_s),
        "still_samples": n_still,
        "window_samples": window,
        "accel_correction": acc_c,
        "gyro_correction": gyro_c,
    }
    return CalibrationReport(accel, gyro_cal, "free", gravity, poses, warnings, details)

