"""Accelerometer from known static poses: least squares over any set, and the six-position solution.

In a pose whose up direction is the unit vector u (sensor frame), the accelerometer reads the
specific force g u, so the mean raw reading of pose p is

    y_p = M g u_p + b                                                              (1)

Stacked over P poses, Y = X Theta with X = [g u_p^T, 1] (P x 4), Theta = [M^T; b^T] (4 x 3):
twelve unknowns, solved by linear least squares

    Theta = (X^T X)^-1 X^T Y                                                       (2)

(the lecture's y = x theta). The six-position analytic solution of the up/down pairs is the
special case, except for the bias: Ferraris et al. 1995 (eqs. 19-23; imucal's
FerrarisCalibration) take each bias component from the pair along that axis only,

    b_i = (y_{+i} + y_{-i})_i / 2,     M[:, i] = (y_{+i} - y_{-i}) / (2 g)                  (3)

which a tilted fixture disturbs only at second order (cos of the tilt), where the mean of
all six poses picks it up at first order through the cross-axis components.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.calibration.common import pooled_scatter
from station.errors import EngineInputError

_UNKNOWNS = ["M[:,x] (x-axis sensitivity)", "M[:,y] (y-axis sensitivity)", "M[:,z] (z-axis sensitivity)",
             "b (bias)"]


@dataclass
class PoseFit:
    """Result of eq. (2): M, b, their covariance and the per-pose residuals (raw units)."""

    matrix: np.ndarray
    bias: np.ndarray
    cov: np.ndarray           # (12, 12) over [M.ravel() (row-major), b]
    residual: np.ndarray      # (P, 3) y_p - (M g u_p + b)
    condition: float
    sigma2: np.ndarray        # (3,) variance of one pose mean about the model, per axis


def _design(up: np.ndarray, g: float) -> np.ndarray:
    return np.hstack([g * np.asarray(up, float), np.ones((len(up), 1))])


def _unit_columns(x: np.ndarray) -> np.ndarray:
    """Columns scaled to unit norm (all-zero columns left as they are), for rank and conditioning."""
    norm = np.linalg.norm(x, axis=0)
    return x / np.where(norm > 0, norm, 1.0)


def explain_rank_deficiency(up: np.ndarray, labels: list[str]) -> str:
    """Name what a set of poses fails to excite in eq. (2).

    Parameters
    ----------
    up : ndarray, (P, 3)
        Up vectors of the poses.
    labels : list of str

    Returns
    -------
    str
        The error message.
    """
    up = np.asarray(up, float)
    reasons = []
    for i, axis in enumerate("xyz"):
        comp = up[:, i]
        if np.all(np.abs(comp) < 1e-9):
            reasons.append(f"no pose has gravity along the {axis} axis "
                           f"(hold {axis} up and down: +{axis}, -{axis})")
        elif np.ptp(comp) < 1e-9:
            side = "up" if comp[0] > 0 else "down"
            reasons.append(f"the {axis} axis is only ever {side} by the same amount, so its bias and scale "
                           f"cannot be told apart (add the opposite pose)")
    if not reasons:
        x = _design(up, 1.0)
        vt = np.linalg.svd(_unit_columns(x))[2]
        v = vt[-1] / np.max(np.abs(vt[-1]))
        free = " + ".join(f"{c:+.2f}*{_UNKNOWNS[k]}" for k, c in enumerate(v) if abs(c) > 0.05)
        reasons.append(f"the poses are linearly dependent; the combination {free} is free")
    return (f"the static poses {', '.join(labels)} cannot determine the accelerometer's 12 parameters: "
            + "; ".join(reasons))


def fit_poses(means: np.ndarray, up: np.ndarray, g: float, mean_var: np.ndarray,
              labels: list[str]) -> PoseFit:
    """Eq. (2): M and b by least squares over static poses.

    The covariance of Theta is sigma_j^2 (X^T X)^-1 per output axis j, with sigma_j^2 the larger
    of the pose means' white-noise variance on axis j and the pose-to-pose scatter of the
    residuals (``calibration_common.pooled_scatter``: pooled over the axes, Student-corrected).
    The scatter is what shows a bias that drifts between poses; white noise alone would
    understate it.

    Parameters
    ----------
    means : ndarray, (P, 3)
        Mean raw reading y_p of each pose.
    up : ndarray, (P, 3)
        Unit up vector u_p of each pose (sensor frame).
    g : float
        Local gravity, m/s^2.
    mean_var : ndarray, (P, 3)
        Variance of each mean from the samples' scatter.
    labels : list of str
        Pose labels, for error messages.

    Returns
    -------
    PoseFit

    Raises
    ------
    EngineInputError
        Fewer than four poses, or poses that do not excite every column of X (named).
    """
    means = np.asarray(means, float)
    x = _design(up, g)
    if len(means) < 4 or np.linalg.matrix_rank(_unit_columns(x), tol=1e-9) < 4:
        if len(means) < 4:
            raise EngineInputError(f"only {len(means)} static poses ({', '.join(labels)}): the accelerometer "
                                   "needs at least 4 (six-position: +x -x +y -y +z -z)")
        raise EngineInputError(explain_rank_deficiency(up, labels))
    theta, *_ = np.linalg.lstsq(x, means, rcond=None)
    residual = means - x @ theta
    xtx_inv = np.linalg.inv(x.T @ x)
    noise_var = np.mean(mean_var, axis=0)
    scatter = pooled_scatter(residual, 4)
    sigma2 = noise_var if scatter is None else np.maximum(scatter, noise_var)
    cov = np.zeros((12, 12))
    # Theta[k, j] = M[j, k] (k < 3) or b[j] (k = 3); index in [M.ravel(), b]
    index = [[3 * j + k if k < 3 else 9 + j for k in range(4)] for j in range(3)]
    for j in range(3):
        idx = index[j]
        cov[np.ix_(idx, idx)] = sigma2[j] * xtx_inv
    xn = _unit_columns(x)
    return PoseFit(theta[:3].T, theta[3], cov, residual, float(np.linalg.cond(xn)), sigma2)


SIX = ("+x", "-x", "+y", "-y", "+z", "-z")


def six_position(means: dict[str, np.ndarray], g: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (3) (Ferraris et al. 1995, eqs. 19-23): M and b from the six up/down poses.

    Parameters
    ----------
    means : dict of str to ndarray (3,)
        Mean raw reading of each of the poses +x -x +y -y +z -z.
    g : float
        Local gravity, m/s^2.

    Returns
    -------
    tuple of ndarray
        M (3, 3) and b (3,).

    Raises
    ------
    EngineInputError
        A pose of the six is missing.
    """
    missing = [p for p in SIX if p not in means]
    if missing:
        raise EngineInputError(f"the six-position solution needs the poses {missing} as well")
    y = {k: np.asarray(v, float) for k, v in means.items()}
    m = np.column_stack([(y[f"+{a}"] - y[f"-{a}"]) / (2 * g) for a in "xyz"])
    b = np.array([(y[f"+{a}"][i] + y[f"-{a}"][i]) / 2 for i, a in enumerate("xyz")])
    return m, b


def six_position_cov(means: dict[str, np.ndarray], g: float, sigma2: np.ndarray) -> np.ndarray:
    """Covariance of eq. (3) over [M.ravel(), b] by first-order propagation.

    Parameters
    ----------
    means : dict of str to ndarray (3,)
        Mean raw reading of each of the six poses.
    g : float
        Local gravity, m/s^2.
    sigma2 : ndarray, (3,)
        Variance of one pose mean, per axis.

    Returns
    -------
    ndarray, (12, 12)
    """
    flat = np.concatenate([np.asarray(means[p], float) for p in SIX])

    def solution(v: np.ndarray) -> np.ndarray:
        m, b = six_position({p: v[3 * k:3 * k + 3] for k, p in enumerate(SIX)}, g)
        return np.concatenate([m.ravel(), b])

    # eq. (3) is linear in the means, so a unit step gives its exact Jacobian
    base = solution(flat)
    jac = np.column_stack([solution(flat + np.eye(18)[k]) - base for k in range(18)])
    return jac @ np.diag(np.tile(sigma2, 6)) @ jac.T
