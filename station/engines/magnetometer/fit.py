"""Magnetometer fits: the algebraic ellipsoid and sphere (starting points) and the joint
ellipsoid-and-alignment fit with the dip-angle constraint.

Model (``shared/specs/params-file.md``, section ``mag``): a raw reading m of the field h (in the
accelerometer's axes, |h| = F) is

    m = A h + b + n,        h = C (m - b),   C = A^-1                                       (1)

with b the hard iron and A the soft iron, scale and misalignment. Any rotation Q leaves
|Q C (m - b)| unchanged, so the magnitude alone gives C only up to a rotation on the left; the
angle between gravity and the field, the same at every pose (90 deg minus the dip), fixes it. At a
still pose the accelerometer gives the down direction d = -a / |a|, and

    r_F = |C u| - F,                     u = m - b   (every sample)                       (2)
    r_D = d . C u - F sin(delta)                         (still samples)                    (3)

(delta the dip, positive where the field points down, estimated with the rest). Both residuals are
in microtesla; each set is weighted by the inverse of its own scatter. The unknowns are b, the nine
entries of C and s = sin(delta). With u, h = C u and n = h / |h|, the Jacobian is

    dr_F/db = -n^T C,    dr_F/dC_jk = n_j u_k,    dr_F/ds = 0                             (4)
    dr_D/db = -d^T C,    dr_D/dC_jk = d_j u_k,    dr_D/ds = -F                            (5)

An accelerometer not calibrated first adds its intrinsics to the unknowns, its down directions
and its own residuals at the still poses (:mod:`station.engines.magnetometer.accel`).

Without a gravity reference only (2) is fitted and C is kept symmetric (six unknowns:
c = [C_xx, C_yy, C_zz, C_xy, C_xz, C_yz]), the field then in the magnetometer's own axes rotated by
no more than its soft iron: the ellipsoid fit of the autopilots (ArduPilot's offsets, diagonal and
off-diagonals), called the plain fit here.

The algebraic ellipsoid (the starting point when the directions cover enough of the sphere) is the
linear least squares of the quadric

    x^T Q x + 2 p^T x = 1,   centre c = -Q^-1 p,   (x - c)^T Q / (1 + c^T Q c) (x - c) = 1      (6)

(Q symmetric: nine unknowns), and the sphere |x - c|^2 = r^2 the linear least squares of

    |x|^2 = 2 c^T x + (r^2 - |c|^2)                                                         (7)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from station.engines.magnetometer.accel import PoseAccel
from station.engines.shared.levenberg_marquardt import least_squares_lm

# c of a symmetric C (plain fit): entries (j, k) of each of the six unknowns.
_SYM_INDEX = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def sym_matrix(c: np.ndarray) -> np.ndarray:
    """The symmetric C of the plain fit from its six unknowns ``[C_xx, C_yy, C_zz, C_xy, C_xz, C_yz]``."""
    out = np.empty((3, 3))
    for value, (j, k) in zip(c, _SYM_INDEX, strict=True):
        out[j, k] = out[k, j] = value
    return out


def sym_params(matrix: np.ndarray) -> np.ndarray:
    """The six unknowns of a symmetric matrix (its symmetric part), inverse of :func:`sym_matrix`."""
    m = 0.5 * (np.asarray(matrix, float) + np.asarray(matrix, float).T)
    return np.array([m[j, k] for j, k in _SYM_INDEX])


def sqrtm_spd(q: np.ndarray) -> np.ndarray:
    """The symmetric square root of a symmetric positive definite matrix (by its eigenvectors)."""
    w, v = np.linalg.eigh(0.5 * (q + q.T))
    return (v * np.sqrt(w)) @ v.T


def polar(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left polar decomposition A = P R: P = sqrt(A A^T) symmetric positive, R orthogonal.

    Parameters
    ----------
    matrix : ndarray, (3, 3)
        An invertible matrix.

    Returns
    -------
    tuple of ndarray
        (P, R).
    """
    u, sv, vt = np.linalg.svd(np.asarray(matrix, float))
    return (u * sv) @ u.T, u @ vt


@dataclass(frozen=True)
class Start:
    """A starting point: hard iron b and a symmetric C with |C (m - b)| about 1 (a unit sphere)."""

    bias: np.ndarray
    correction: np.ndarray
    kind: str                  # "ellipsoid" or "sphere"


def sphere_fit(m: np.ndarray) -> Start:
    """Eq. (7): the least-squares sphere through the readings.

    Parameters
    ----------
    m : ndarray, (n, 3)
        Raw readings.

    Returns
    -------
    Start
        Centre and C = I / r.
    """
    m = np.asarray(m, float)
    mean = m.mean(axis=0)
    x = m - mean                                   # centred: the normal equations stay well scaled
    design = np.column_stack([2.0 * x, np.ones(len(x))])
    sol, *_ = np.linalg.lstsq(design, np.sum(x * x, axis=1), rcond=None)
    centre = sol[:3]
    radius = float(np.sqrt(max(sol[3] + centre @ centre, 1e-300)))
    return Start(bias=centre + mean, correction=np.eye(3) / radius, kind="sphere")


def ellipsoid_fit(m: np.ndarray) -> Start | None:
    """Eq. (6): the algebraic least-squares ellipsoid, or None where the quadric is no ellipsoid.

    Parameters
    ----------
    m : ndarray, (n, 3)
        Raw readings.

    Returns
    -------
    Start or None
        Centre and C = sqrt(Q / (1 + c^T Q c)) (symmetric), or None when that matrix is not
        positive definite (a hyperboloid: the directions cover too little of the sphere).
    """
    m = np.asarray(m, float)
    mean = m.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((m - mean) ** 2, axis=1)))) or 1.0
    x = (m - mean) / scale                         # about unit size: the design's columns comparable
    design = np.column_stack([x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, 2 * x[:, 0] * x[:, 1],
                              2 * x[:, 0] * x[:, 2], 2 * x[:, 1] * x[:, 2], 2 * x])
    v, *_ = np.linalg.lstsq(design, np.ones(len(x)), rcond=None)
    q = sym_matrix(v[[0, 1, 2, 3, 4, 5]])
    try:
        centre = -np.linalg.solve(q, v[6:9])
    except np.linalg.LinAlgError:
        return None
    shape = q / (1.0 + centre @ q @ centre)
    if not np.all(np.linalg.eigvalsh(shape) > 0):
        return None
    return Start(bias=centre * scale + mean, correction=sqrtm_spd(shape) / scale, kind="ellipsoid")


def _column(weight: float | np.ndarray) -> float | np.ndarray:
    """A weight per residual as a column (it divides Jacobian rows); a single weight as it is."""
    return weight[:, None] if isinstance(weight, np.ndarray) else weight


@dataclass(frozen=True)
class JointProblem:
    """The data of eqs. (2)-(3): readings, the still ones with their down directions, weights.

    ``m`` are the readings of (2); ``m_still`` and ``down`` (unit vectors, accelerometer axes) those
    of (3), empty for the plain fit. ``w_norm`` and ``w_dip`` divide each set's residuals (their
    scatter, microtesla: one for the set or one per residual). ``field`` is F. With ``acc`` (an
    accelerometer not calibrated first, :mod:`station.engines.magnetometer.accel`), the down directions are
    those of its raw pose means under intrinsics estimated with the rest (``down`` is then only the
    start's), and its residuals r_A, divided by ``w_acc``, join the fit.
    """

    m: np.ndarray
    m_still: np.ndarray
    down: np.ndarray
    field: float
    w_norm: float | np.ndarray = 1.0
    w_dip: float | np.ndarray = 1.0
    acc: PoseAccel | None = None
    w_acc: float | np.ndarray = 1.0

    @property
    def joint(self) -> bool:
        """True when the dip residuals (3) take part: general C and s; else the plain fit."""
        return len(self.m_still) > 0

    def unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(b, C, s) from the parameter vector: [b, C row-major, s (, accelerometer)] (joint) or [b, c]."""
        if self.joint:
            return p[0:3], p[3:12].reshape(3, 3), float(p[12])
        return p[0:3], sym_matrix(p[3:9]), 0.0

    def pack(self, bias: np.ndarray, correction: np.ndarray, sin_dip: float,
             acc: np.ndarray | None = None) -> np.ndarray:
        """The parameter vector of (b, C, s) and the accelerometer's estimated intrinsics, inverse of
        :meth:`unpack` and :meth:`acc_params`."""
        if self.joint:
            tail = [] if self.acc is None else [np.asarray(acc, float)]
            return np.concatenate([bias, np.asarray(correction, float).ravel(), [sin_dip], *tail])
        return np.concatenate([bias, sym_params(correction)])

    def acc_params(self, p: np.ndarray) -> np.ndarray:
        """The accelerometer's estimated intrinsics (``accel``), empty without ``acc``."""
        return p[13:] if self.joint and self.acc is not None else np.zeros(0)

    def downs(self, p: np.ndarray) -> np.ndarray:
        """The down directions of (3) at ``p``: ``down``, or the estimated accelerometer's."""
        return self.down if self.acc is None else self.acc.down(self.acc_params(p))

    def poses(self, keep: np.ndarray) -> JointProblem:
        """The problem on the still poses ``keep`` (a boolean mask) only."""
        return replace(self, m_still=self.m_still[keep], down=self.down[keep],
                       acc=None if self.acc is None else self.acc.subset(keep))

    def residual_parts(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eqs. (2) and (3), each divided by its sensitivity to the reading (eq. (8)), microtesla, and
        the estimated accelerometer's r_A (``accel`` eq. (2), empty without ``acc``)."""
        b, c, s = self.unpack(p)
        h = (self.m - b) @ c.T
        rho = np.linalg.norm(h, axis=1)
        r_norm = (rho - self.field) / np.linalg.norm((h / rho[:, None]) @ c, axis=1)
        if not self.joint:
            return r_norm, np.zeros(0), np.zeros(0)
        down = self.downs(p)
        g = np.einsum("ij,ij->i", down, (self.m_still - b) @ c.T) - self.field * s
        r_acc = np.zeros(0) if self.acc is None else self.acc.residual(self.acc_params(p))
        return r_norm, g / np.linalg.norm(down @ c, axis=1), r_acc

    def residual(self, p: np.ndarray) -> np.ndarray:
        """Eqs. (2) and (3) (and r_A) as :meth:`residual_parts`, stacked, each set divided by its weight."""
        r_norm, r_dip, r_acc = self.residual_parts(p)
        return np.concatenate([r_norm / self.w_norm, r_dip / self.w_dip, r_acc / self.w_acc])

    def jacobian(self, p: np.ndarray) -> np.ndarray:
        """Eqs. (9)-(10), rows as :meth:`residual`'s (the plain fit's C columns by the chain rule; the
        accelerometer's columns by ``accel`` eq. (3))."""
        b, c, _ = self.unpack(p)
        u = self.m - b
        h = u @ c.T
        rho = np.linalg.norm(h, axis=1)
        n = h / rho[:, None]
        v = n @ c                                                             # C^T n
        sv = np.linalg.norm(v, axis=1)
        e = v / sv[:, None]
        g = rho - self.field
        ce = e @ c.T                                                          # C e
        proj = ce - n * np.einsum("ij,ij->i", n, ce)[:, None]                 # (I - n n^T) C e
        q = n / sv[:, None] - (g / (sv**2 * rho))[:, None] * proj
        k = (g / sv**2)[:, None, None]
        dc_norm = (q[:, :, None] * u[:, None, :] - k * n[:, :, None] * e[:, None, :]).reshape(len(u), 9)
        db_norm = -q @ c
        if not self.joint:
            # c_l enters C at (j, k) and, off the diagonal, at (k, j) too
            cols = [dc_norm[:, 3 * j + k] + (dc_norm[:, 3 * k + j] if j != k else 0.0) for j, k in _SYM_INDEX]
            return np.column_stack([db_norm, *cols]) / _column(self.w_norm)
        d = self.downs(p)
        us = self.m_still - b
        hs = us @ c.T                                                         # C u
        vd = d @ c                                                            # C^T d
        sd = np.linalg.norm(vd, axis=1)
        ed = vd / sd[:, None]
        gd = np.einsum("ij,ij->i", d, hs) - self.field * self.unpack(p)[2]
        kd = (gd / sd**2)[:, None, None]
        dc_dip = (d[:, :, None] * us[:, None, :] / sd[:, None, None] - kd * d[:, :, None] * ed[:, None, :])
        n_acc = len(self.acc_params(p))
        top = np.column_stack([db_norm, dc_norm, np.zeros((len(u), 1 + n_acc))]) / _column(self.w_norm)
        dip_cols = [-ed, dc_dip.reshape(len(us), 9), -self.field / sd]
        if self.acc is None:
            return np.vstack([top, np.column_stack(dip_cols) / _column(self.w_dip)])
        # dr_D/dd = C u / sigma - (g / sigma^2) C e, through d to the intrinsics (accel eq. (3))
        w = hs / sd[:, None] - (gd / sd**2)[:, None] * (ed @ c.T)
        q_acc = self.acc_params(p)
        dip_cols.append(self.acc.down_jacobian(q_acc, w))
        bottom = np.column_stack(dip_cols) / _column(self.w_dip)
        acc_rows = np.column_stack([np.zeros((len(self.acc.x), 13)), self.acc.jacobian(q_acc)])
        return np.vstack([top, bottom, acc_rows / _column(self.w_acc)])

    def solve(self, p0: np.ndarray) -> np.ndarray:
        """Levenberg-Marquardt (MINPACK's ``lmder``, :mod:`station.engines.shared.levenberg_marquardt`)
        from ``p0``.

        Parameters
        ----------
        p0 : ndarray
            Starting parameters (:meth:`pack`).

        Returns
        -------
        ndarray
            The parameters at the minimum.
        """
        return least_squares_lm(self.residual, p0, self.jacobian, ftol=1e-12, xtol=1e-12, gtol=1e-12,
                                max_nfev=200).x

    def reweighted(self, p: np.ndarray, scale_norm: float, scale_dip: float) -> JointProblem:
        """The problem with per-residual weights of the soft-L1 loss at ``p`` (one step of iteratively
        reweighted least squares): a residual r of scale f weighs f (1 + (r/f)^2)^(1/4), so r / weight
        grows like sqrt(|r|) beyond f and an outlier pulls the fit less.

        Parameters
        ----------
        p : ndarray
            The current parameters.
        scale_norm, scale_dip : float
            f for the residuals (2) and (3), microtesla.

        Returns
        -------
        JointProblem
        """
        r_norm, r_dip, _ = self.residual_parts(p)
        return replace(self, w_norm=scale_norm * (1.0 + (r_norm / scale_norm) ** 2) ** 0.25,
                       w_dip=scale_dip * (1.0 + (r_dip / scale_dip) ** 2) ** 0.25)


def initial_rotation(m_still: np.ndarray, down: np.ndarray, start: Start) -> tuple[np.ndarray, float]:
    """The rotation Q and sin(dip) that make (3) hold best for C = Q C_0, from eq. (3) made linear.

    With h_0 = C_0 (m - b) (the start's unit-sphere field), (3) reads d^T X h_0 = 1 for
    X = Q / sin(delta): nine unknowns by linear least squares; Q is the rotation nearest X
    (:func:`polar`; the sign taken that makes it proper), sin(delta) = the mean of d^T Q h_0.

    Parameters
    ----------
    m_still : ndarray, (k, 3)
        Raw readings at still samples.
    down : ndarray, (k, 3)
        Their down directions (unit, accelerometer axes).
    start : Start
        Hard iron and symmetric C_0 of the starting fit.

    Returns
    -------
    tuple
        Q (3, 3), a proper rotation, and sin(delta) on the unit sphere.
    """
    h0 = (m_still - start.bias) @ start.correction.T
    design = (down[:, :, None] * h0[:, None, :]).reshape(len(h0), 9)
    x, *_ = np.linalg.lstsq(design, np.ones(len(h0)), rcond=None)
    _, rot = polar(x.reshape(3, 3))
    if np.linalg.det(rot) < 0:
        rot = -rot                                  # X = Q / s with s < 0: south of the magnetic equator
    sin_dip = float(np.mean(np.einsum("ij,ij->i", down, h0 @ rot.T)))
    return rot, float(np.clip(sin_dip, -1.0, 1.0))
