"""Turntable-free calibration, gyroscope part (Tedaldi, Pretto, Menegatti, ICRA 2014, sec. IV-C).

The correction is a full 3x3 C = T K (9 parameters: 6 misalignments and 3 scales). Between
consecutive static intervals k and k+1 the calibrated rates w = C (x - b_g) are integrated with
an RK4 quaternion step (``quaternion.rk4_step_matrices``) to R_k, and with u the unit gravity
directions of the calibrated accelerometer (interval means)

    r_k = R_k^T u_k - u_{k+1}          (paper eq. 15)                                (15)

The Jacobian is analytic: each step is q <- A(w_n, w_{n+1}) q, linear in q, so
dq = sum_n A_N..A_{n+1} dA_n A_{n-1}..A_1 q_0; it is evaluated in adjoint form for all
intervals at once (see :class:`GyroModel`) and chained through R^T u (``quaternion.rotate_inverse``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.calibration.free_accel import acc_correction
from station.engines.shared import quaternion as quat
from station.engines.shared.levenberg_marquardt import LsqResult, least_squares_lm

GYRO_PARAM_NAMES = [f"C_{i}{j}" for i in "xyz" for j in "xyz"]


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
    """The moves as imu_tk integrates them: from the last sample of static interval k (t >= its end
    time) to the last sample before the start of interval k+1.

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    gyro_unbiased : ndarray, (N, 3)
        Raw rates minus the bias.
    intervals : ndarray, (K, 2)
        Static intervals [start, end].
    directions : ndarray, (K, 3)
        Gravity direction of each interval (any length).

    Returns
    -------
    GyroBlocks
    """
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


SCAN_CHUNK = 32  # steps scanned one after another in every chunk at once (measured best: 25 to 40)


def _scan(a: np.ndarray) -> np.ndarray:
    """Inclusive products along axis 1, element n = a[:, 0] (x) .. (x) a[:, n], in chunks of
    SCAN_CHUNK steps: a sequential pass through every chunk of every block at once, then a
    Hillis-Steele scan of the chunks' products (log2 of their number passes), then every chunk
    times the product of the chunks before it. About 3 L products per block, where a Hillis-Steele
    scan of all L steps makes L log2(L)."""
    nb, length = a.shape[:2]
    chunks = -(-length // SCAN_CHUNK)
    x = np.zeros((nb, chunks * SCAN_CHUNK, 4))
    x[..., 0] = 1.0  # identity padding
    x[:, :length] = a
    x = x.reshape(nb, chunks, SCAN_CHUNK, 4)
    p = np.empty_like(x)
    p[:, :, 0] = x[:, :, 0]
    for k in range(1, SCAN_CHUNK):
        p[:, :, k] = quat.qmul(p[:, :, k - 1], x[:, :, k])
    totals = p[:, :, -1].copy()
    shift = 1
    while shift < chunks:
        totals[:, shift:] = quat.qmul(totals[:, :-shift], totals[:, shift:])
        shift *= 2
    p[:, 1:] = quat.qmul(totals[:, :-1, None], p[:, 1:])
    return p.reshape(nb, chunks * SCAN_CHUNK, 4)[:, :length]


class GyroModel:
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
        """Eq. (15) for every block, stacked (3B,), at C = ``cflat`` (row-major 3x3).

        Parameters
        ----------
        cflat : ndarray, (9,)

        Returns
        -------
        ndarray, (3B,)
        """
        self._forward(cflat)
        return (self.r - self.blocks.u1).ravel()

    def jacobian(self, cflat: np.ndarray) -> np.ndarray:
        """d(eq. 15)/dC (3B, 9) by the adjoint pass of the class docstring; also keeps the per-block
        rate gradient ``rate_gradient`` (B, 3, 3) that :func:`bias_sensitivity` reads.

        Parameters
        ----------
        cflat : ndarray, (9,)

        Returns
        -------
        ndarray, (3B, 9)
        """
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
        # lambda_n = dr/dq R(after), then lambda_n L(s_n), as products (quaternion.conjugate)
        lam = quat.qmul(self.dr_dq[self.block_of], quat.conjugate(after)[:, None, :])   # (S, 3, 4)
        u = quat.qmul(quat.conjugate(states[self.mask])[:, None, :], lam)
        g0, g1 = quat.rk4_step_gradients(u, self.dt, self.stages)                   # (S, 3 res, 3 w)
        # dr/dw summed over each block: a constant rate offset d (a bias error) moves r by this @ d
        self.rate_gradient = self._block_sums(g0 + g1)
        # sum_n g0_n (x) x0_n + g1_n (x) x1_n per block: a (9 x n) (n x 3) product for each block
        jac = np.zeros((nb, 9, 3))
        g0, g1 = g0.reshape(-1, 9), g1.reshape(-1, 9)
        bounds = np.append(self.first, len(self.dt))
        for b in np.flatnonzero(~self.empty):
            steps = slice(bounds[b], bounds[b + 1])
            jac[b] = g0[steps].T @ self.x0[steps] + g1[steps].T @ self.x1[steps]
        return jac.reshape(-1, 9)


def gyro_residual(cflat: np.ndarray, blocks: GyroBlocks) -> np.ndarray:
    """Eq. (15) for every block.

    Parameters
    ----------
    cflat : ndarray, (9,)
        C, row-major.
    blocks : GyroBlocks

    Returns
    -------
    ndarray, (3B,)
    """
    return GyroModel(blocks).residual(cflat)


def gyro_jacobian(cflat: np.ndarray, blocks: GyroBlocks) -> np.ndarray:
    """The analytic Jacobian of :func:`gyro_residual` with respect to C (row-major).

    Parameters
    ----------
    cflat : ndarray, (9,)
    blocks : GyroBlocks

    Returns
    -------
    ndarray, (3B, 9)
    """
    return GyroModel(blocks).jacobian(cflat)


def gyro_initial_guess(blocks: GyroBlocks) -> np.ndarray:
    """Data-driven start C = diag(+-s): s from the angles between consecutive gravity directions
    over the integrated raw rate magnitude, signs and s refined on coarse grids of the residual.

    Parameters
    ----------
    blocks : GyroBlocks

    Returns
    -------
    ndarray, (9,)
        C, row-major.
    """
    angle = np.arccos(np.clip(np.sum(blocks.u0 * blocks.u1, axis=1), -1, 1)).sum()
    rate = np.sum(0.5 * (np.linalg.norm(blocks.x0, axis=2) + np.linalg.norm(blocks.x1, axis=2)) * blocks.dt)
    s0 = angle / rate if rate > 0 and angle > 0 else 1.0
    # the angle between gravity directions underestimates each move's rotation: search upwards
    model = GyroModel(blocks)

    def cost(diagonal: np.ndarray) -> float:
        return float(np.sum(model.residual(np.diag(diagonal).ravel()) ** 2))

    # a gyro axis may be mounted reversed relative to the accelerometer's: pick the sign pattern
    # first (at a typical scale), then the scale with those signs
    signs = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], float)
    sign = signs[int(np.argmin([cost(1.7 * s0 * sg) for sg in signs]))]
    grid = s0 * np.geomspace(1.0, 3.0, 5)
    scale = grid[int(np.argmin([cost(s * sign) for s in grid]))]
    return np.diag(scale * sign).ravel()


def direction_covariance(model: GyroModel, cflat: np.ndarray, jac: np.ndarray, acc: np.ndarray,
                         intervals: np.ndarray, acc_params: np.ndarray, acc_cov: np.ndarray,
                         convention: str) -> np.ndarray:
    """Covariance the gyroscope's C inherits from the accelerometer fit through the gravity
    directions u_k (implicit-function theorem at the optimum of eq. 15):

        dC/dp_a = -(J^T J)^-1 J^T dr/dp_a,  dr/dp_a = R_k^T du_k/dp_a - du_{k+1}/dp_a,

    with du/dp_a by central differences of u = normalise(T K (mean - b)); cov = D cov_a D^T.

    Parameters
    ----------
    model : GyroModel
    cflat : ndarray, (9,)
        The fitted C, row-major.
    jac : ndarray, (3B, 9)
        Jacobian of eq. (15) at ``cflat``.
    acc : ndarray, (N, 3)
        Raw accelerometer samples.
    intervals : ndarray, (K, 2)
        Static intervals.
    acc_params, acc_cov : ndarray
        The accelerometer's parameters (9,) and covariance (9, 9).
    convention : str
        Their convention.

    Returns
    -------
    ndarray, (9, 9)
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


def bias_sensitivity(model: GyroModel, cflat: np.ndarray) -> np.ndarray:
    """dr/db of eq. (15) for the bias subtracted before integration: a bias error d shifts every
    rate by -C d, so dr/db = -(sum over the block's steps of dr/dw) C.

    Parameters
    ----------
    model : GyroModel
        Whose :meth:`GyroModel.jacobian` has run at ``cflat``.
    cflat : ndarray, (9,)

    Returns
    -------
    ndarray, (3B, 3)
    """
    return -(model.rate_gradient @ np.asarray(cflat, float).reshape(3, 3)).reshape(-1, 3)


def bias_covariance(model: GyroModel, cflat: np.ndarray, jac: np.ndarray,
                    bias_sd: np.ndarray) -> np.ndarray:
    """Covariance C inherits from the bias subtracted before integration (implicit-function theorem,
    as in :func:`direction_covariance`).

    Parameters
    ----------
    model : GyroModel
    cflat : ndarray, (9,)
    jac : ndarray, (3B, 9)
    bias_sd : ndarray, (3,)
        1-sigma of the bias.

    Returns
    -------
    ndarray, (9, 9)
    """
    dr = bias_sensitivity(model, cflat)
    d = -np.linalg.pinv(jac.T @ jac) @ jac.T @ dr
    return d @ np.diag(np.asarray(bias_sd, float) ** 2) @ d.T


# A converged gyro fit leaves unit-vector residuals of a few hundredths at most.
GYRO_CONVERGED_RMS = 0.05


def fit_gyroscope(blocks: GyroBlocks, start: np.ndarray | None = None) -> LsqResult:
    """Levenberg-Marquardt on eq. (15) with its analytic Jacobian.

    Should the data-driven start lead to a poor minimum, every sign pattern of the start's
    diagonal is tried and the best solution kept.

    Parameters
    ----------
    blocks : GyroBlocks
        The moves between static intervals.
    start : ndarray, (9,), optional
        Start C, row-major; default :func:`gyro_initial_guess`.

    Returns
    -------
    LsqResult
        ``x`` is C (row-major), ``fun`` the residuals of eq. (15).
    """
    c0 = gyro_initial_guess(blocks) if start is None else np.asarray(start, float).ravel()
    model = GyroModel(blocks)

    def solve(c: np.ndarray) -> LsqResult:
        return least_squares_lm(model.residual, c, model.jacobian, ftol=1e-9, xtol=1e-9, gtol=1e-10,
                                max_nfev=200)

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
