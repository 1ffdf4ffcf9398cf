"""The accelerometer of a magnetometer session, estimated from its still poses when it has not been
calibrated: the down direction of the dip constraint (``fit`` eq. (3)) with its own intrinsics.

The still poses of a magnetometer session are a multi-position accelerometer session. With the
model of ``calibration_free_accel`` (Tedaldi et al. 2014, eq. (8)), lower-triangular convention,

    a = T K (x - b_a),      T = [[1, 0, 0], [t_yx, 1, 0], [t_zx, t_zy, 1]]                (1)

x the raw mean of a pose, the accelerometer's residual and the down direction are

    r_A = |a| - g,          d = -a / |a|                                                (2)

g the poses' median raw |x| (the raw unit is free; a common scale of K does not move d). The
frame of (1) is the one ``calibrate --method free`` (default ``--convention lower``) reports: x
along the accelerometer's x axis, the xy plane its xy plane. Near level (z within 20-30 deg of
up) x_z stays near g, so k_z (x_z - b_z) = a_z leaves b_z and k_z one unknown: b_z = 0 is held
and k_z takes it in (``NO_Z_BIAS``); the direction d moves by the second order of the tilt only.
There the tilt of the z axis (t_zx, t_zy) trades against b_x, b_y to the second order of the tilt
too, and only the dip constraint, through the poses' headings, separates them: the fit's 1-sigma
of the alignment says how well.

The dip residual depends on the intrinsics through d. With n = a / |a|, w = dr_D/dd
(``fit`` eq. (6)), u = x - b_a, v = K u and p = -(I - n n^T) w / |a| (= dr_D/da):

    dr_D/dk_j = (p . T_:j) u_j,   dr_D/db_j = -(p . T_:j) k_j,   dr_D/dt_ij = p_i v_j          (3)

and those of r_A are eq. (11) of ``calibration_free_accel`` with the opposite sign.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from station.engines.calibration.free_accel import acc_correction, acc_jacobian, acc_residual

CONVENTION = "lower"
# Which of the nine intrinsics of (1) ([t_yx, t_zx, t_zy, k_x, k_y, k_z, b_x, b_y, b_z]) are
# estimated: all, or, where the poses stay near level, all but the z bias (see ``NO_Z_BIAS``).
ALL = tuple(range(9))
NO_Z_BIAS = tuple(range(8))


@dataclass(frozen=True)
class PoseAccel:
    """The raw accelerometer at the still poses and which of its intrinsics (1) are estimated.

    ``x`` (k, 3) are the poses' raw means, ``gravity`` is g of (2), ``free`` the indices of the
    estimated ones among the nine parameters of ``calibration_free_accel`` ([t_yx, t_zx, t_zy, K,
    b_a]); the others are held at ``fixed``'s values (zero misalignment and bias, unit scale).
    """

    x: np.ndarray
    gravity: float
    free: tuple[int, ...] = ALL

    def full(self, q: np.ndarray) -> np.ndarray:
        """The nine parameters of (1) from the estimated ones."""
        full = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
        full[list(self.free)] = q
        return full

    def reduced(self, full: np.ndarray) -> np.ndarray:
        """The estimated parameters of nine, inverse of :meth:`full` on them."""
        return np.asarray(full, float)[list(self.free)]

    def corrected(self, q: np.ndarray) -> np.ndarray:
        """a of (1) at every pose, (k, 3)."""
        full = self.full(q)
        return (self.x - full[6:9]) @ acc_correction(full, CONVENTION).T

    def down(self, q: np.ndarray) -> np.ndarray:
        """d of (2) at every pose, unit vectors (k, 3)."""
        a = self.corrected(q)
        return -a / np.linalg.norm(a, axis=1)[:, None]

    def residual(self, q: np.ndarray) -> np.ndarray:
        """r_A of (2), (k,)."""
        return -acc_residual(self.full(q), self.x, self.gravity, CONVENTION)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """dr_A/dq, (k, terms): eq. (11) of ``calibration_free_accel``, sign reversed."""
        return -acc_jacobian(self.full(q), self.x, self.gravity, CONVENTION)[:, list(self.free)]

    def down_jacobian(self, q: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Eq. (3): d(residual)/dq at every pose from w = d(residual)/dd, (k, 3) -> (k, len(free)).

        Parameters
        ----------
        q : ndarray
            The estimated parameters.
        w : ndarray, (k, 3)
            The derivative of each pose's residual by its down direction.

        Returns
        -------
        ndarray, (k, len(free))
        """
        full = self.full(q)
        t = acc_correction(np.concatenate([full[:3], np.ones(3), full[6:9]]), CONVENTION)
        u = self.x - full[6:9]
        v = u * full[3:6]
        a = v @ t.T
        size = np.linalg.norm(a, axis=1)
        n = a / size[:, None]
        p = -(w - n * np.einsum("ij,ij->i", n, w)[:, None]) / size[:, None]
        pt = p @ t                                                   # p . T_:j
        cols = [p[:, 1] * v[:, 0], p[:, 2] * v[:, 0], p[:, 2] * v[:, 1]]   # t_yx, t_zx, t_zy
        jac = np.column_stack([*cols, pt * u, -pt * full[3:6]])
        return jac[:, list(self.free)]

    def subset(self, keep: np.ndarray) -> PoseAccel:
        """The same estimate on the poses ``keep`` (a boolean mask)."""
        return replace(self, x=self.x[keep])

    def with_free(self, free: tuple[int, ...]) -> PoseAccel:
        """The same poses with the intrinsics ``free`` estimated."""
        return replace(self, free=free)
