"""Turntable-free calibration, accelerometer part (Tedaldi, Pretto, Menegatti, ICRA 2014, sec. IV-B).

The calibrated specific force of a static sample is

    a = T K (x - b)                                                                 (8)

with K diagonal and T unit triangular (3 misalignment parameters: the body frame is tied to
the sensor). Its magnitude must equal local gravity; the residual is

    r = g - |a|          (paper eq. 10; imu_tk's MultiPosAccResidual)                 (10)

minimised by Levenberg-Marquardt with the analytic Jacobian, n = a/|a|, u = x - b, v = K u:

    dr/dT_ij = -n_i v_j,   dr/dk_j = -(n . T_:j) u_j,   dr/db_j = (n . T_:j) k_j      (11)

``upper``: T = [[1, -m_yz, m_zy], [0, 1, -m_zx], [0, 0, 1]] (imu_tk's parameters and order);
``lower``: T = [[1, 0, 0], [t_yx, 1, 0], [t_zx, t_zy, 1]] (the lecture: body x = accel x,
body xy plane = accel xy plane). The two differ by a rotation of the body frame; see
``calibration_common.convert_convention``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.shared.levenberg_marquardt import least_squares_lm

_MIS_INDEX = {
    "upper": [(0, 1, -1.0), (0, 2, 1.0), (1, 2, -1.0)],   # m_yz, m_zy, m_zx (imu_tk)
    "lower": [(1, 0, 1.0), (2, 0, 1.0), (2, 1, 1.0)],     # t_yx, t_zx, t_zy
}
CONVENTIONS = tuple(_MIS_INDEX)
ACC_PARAM_NAMES = {
    "upper": ["m_yz", "m_zy", "m_zx", "k_x", "k_y", "k_z", "b_x", "b_y", "b_z"],
    "lower": ["t_yx", "t_zx", "t_zy", "k_x", "k_y", "k_z", "b_x", "b_y", "b_z"],
}


def _acc_matrix(p: np.ndarray, convention: str) -> np.ndarray:
    """T of eq. (8) from the three misalignment parameters ``p[:3]`` in ``convention``'s order."""
    t = np.eye(3)
    for (i, j, sign), m in zip(_MIS_INDEX[convention], p[:3], strict=True):
        t[i, j] = sign * m
    return t


def acc_residual(p: np.ndarray, x: np.ndarray, g: float, convention: str) -> np.ndarray:
    """Eq. (10): r = g - |T K (x - b)|.

    Parameters
    ----------
    p : ndarray, (9,)
        Misalignments (``ACC_PARAM_NAMES``), K, b.
    x : ndarray, (n, 3)
        Static samples.
    g : float
        Local gravity, m/s^2.
    convention : str
        "lower" or "upper".

    Returns
    -------
    ndarray, (n,)
    """
    t = _acc_matrix(p, convention)
    a = ((x - p[6:9]) * p[3:6]) @ t.T
    return g - np.linalg.norm(a, axis=1)


def acc_jacobian(p: np.ndarray, x: np.ndarray, g: float, convention: str) -> np.ndarray:
    """Eq. (11): the analytic Jacobian of :func:`acc_residual`.

    Parameters
    ----------
    p, x, g, convention
        As :func:`acc_residual`.

    Returns
    -------
    ndarray, (n, 9)
    """
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

    Parameters
    ----------
    x : ndarray, (n, 3)
        Static samples.
    g : float
        Local gravity, m/s^2.

    Returns
    -------
    ndarray, (9,)
        Parameters of eq. (8), misalignments zero.
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
    """Result of :func:`fit_accelerometer`: the parameters of eq. (8) and the fit behind them.

    ``params`` (9): the three misalignments (``ACC_PARAM_NAMES``), K, b; ``cost``: mean of r^2 or
    1/2 sum r^2 (Ceres) of eq. (10); ``residual`` and ``jacobian`` (eq. 11) at the optimum;
    ``n_intervals``: static intervals fitted.
    """

    params: np.ndarray
    cost: float
    residual: np.ndarray
    jacobian: np.ndarray
    n_intervals: int


def fit_accelerometer(x: np.ndarray, g: float, convention: str, cost: str = "mean",
                      start: np.ndarray | None = None) -> AccFit:
    """Levenberg-Marquardt on eq. (10) with the Jacobian of eq. (11).

    Parameters
    ----------
    x : ndarray, (n, 3)
        Static samples (or interval means), any unit.
    g : float
        Local gravity, m/s^2.
    convention : str
        "lower" or "upper" (the form of T).
    cost : str
        "mean" (mean of r^2) or "half_sum" (1/2 sum r^2, Ceres).
    start : ndarray, (9,), optional
        Start parameters; default :func:`acc_initial_guess`.

    Returns
    -------
    AccFit
    """
    p0 = acc_initial_guess(x, g) if start is None else np.asarray(start, float)
    sol = least_squares_lm(acc_residual, p0, acc_jacobian, args=(x, g, convention), ftol=1e-14, xtol=1e-14,
                           gtol=1e-14, max_nfev=2000)
    r = sol.fun
    value = float(np.mean(r**2)) if cost == "mean" else float(0.5 * r @ r)
    return AccFit(sol.x, value, r, acc_jacobian(sol.x, x, g, convention), 0)


def acc_correction(p: np.ndarray, convention: str) -> np.ndarray:
    """C = T K of eq. (8).

    Parameters
    ----------
    p : ndarray, (9,)
        Parameters of eq. (8).
    convention : str
        "lower" or "upper".

    Returns
    -------
    ndarray, (3, 3)
    """
    return _acc_matrix(p, convention) * p[3:6]
