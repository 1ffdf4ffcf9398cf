"""Gyroscope from rotations by known angles (turntable or fixture) and static steps.

About an axis e fixed in the sensor frame, the true rate integrates to the turned angle:
int w dt = theta e (the turntable's angle is the reference, not its rate). With the model
raw = M w + b, the integrated raw rate of rotation step r, lasting T_r, is

    Y_r = int raw dt = M theta_r e_r + b T_r (+ M Omega_v T_r u_r with Earth rate)         (1)

Stacked over R rotations: Y = X Theta, X = [theta_r e_r^T (+ Omega_v T_r u_r^T), T_r] (R x 4),
Theta = [M^T; b^T], solved by least squares; a positive and a negative turn about each axis
make the bias column separable from the scale (for equal durations, b cancels in their
difference; Ferraris et al. 1995 eqs. 13-15 is the three-rotation special case). The bias
itself comes from the static steps:

    b = mean(raw over static steps) - M Omega_v u_p (the Earth rate's vertical part, optional) (2)

Integration is the trapezoid rule over each sample interval, on the samples' own timestamps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.calibration._static import _unit_columns
from station.engines.calibration.common import pooled_scatter
from station.errors import EngineInputError


@dataclass
class RotationFit:
    """Result of eq. (1) over the rotations: M, its covariance and each rotation's angle error."""

    matrix: np.ndarray
    bias_rotation: np.ndarray   # b of eq. (1), a by-product
    cov: np.ndarray             # (12, 12) over [M.ravel(), b of eq. (1)]
    angle_error: np.ndarray     # (R,) rad: calibrated integrated angle about e_r minus theta_r
    condition: float


def integrate(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Trapezoid-rule integral of the rates over their own timestamps: Y_r of eq. (1).

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    x : ndarray, (N, 3)
        Raw rates.

    Returns
    -------
    ndarray, (3,)
    """
    dt = np.diff(t)[:, None]
    return np.sum(0.5 * (x[1:] + x[:-1]) * dt, axis=0)


def explain_rotations(axes: np.ndarray, labels: list[str]) -> str:
    """Why the rotations cannot determine M in eq. (1): an axis never turned about, or turned one
    way only (the bias column then cannot separate from the scale).

    Parameters
    ----------
    axes : ndarray, (R, 3)
        Signed rotation axes.
    labels : list of str

    Returns
    -------
    str
        The error message.
    """
    axes = np.asarray(axes, float)
    reasons = []
    for i, name in enumerate("xyz"):
        comp = axes[:, i]
        if np.all(np.abs(comp) < 1e-9):
            reasons.append(f"no rotation about the {name} axis (add rot+{name} and rot-{name})")
        elif np.all(comp[np.abs(comp) > 1e-9] > 0) or np.all(comp[np.abs(comp) > 1e-9] < 0):
            reasons.append(f"rotations about {name} turn one way only; add the opposite turn (rot+{name} and "
                           f"rot-{name}) so the bias separates from the scale")
    detail = "; ".join(reasons) if reasons else "the rotations are linearly dependent"
    return (f"the rotation steps {', '.join(labels) or '(none)'} cannot determine the gyroscope's scale and "
            f"misalignment: {detail}")


def fit_rotations(integrals: np.ndarray, angles: np.ndarray, axes: np.ndarray, durations: np.ndarray,
                  noise_var: np.ndarray, labels: list[str], static_bias: np.ndarray,
                  earth_terms: np.ndarray | None = None) -> tuple[RotationFit, bool]:
    """Eq. (1) by least squares over rotation steps.

    With turns both ways (rank 4) b is solved for and cancels; with one turn per axis only
    (Ferraris' three rotations) the static bias is subtracted instead and M alone is solved.

    Parameters
    ----------
    integrals : ndarray, (R, 3)
        Y_r, the integrated raw rate of each rotation.
    angles : ndarray, (R,)
        theta_r, rad.
    axes : ndarray, (R, 3)
        Unit axis e_r of each rotation.
    durations : ndarray, (R,)
        T_r, s.
    noise_var : ndarray, (R, 3)
        Variance of each Y_r from the sample noise.
    labels : list of str
        Rotation labels, for error messages.
    static_bias : ndarray, (3,)
        b of eq. (2).
    earth_terms : ndarray, (R, 3), optional
        Omega_v T_r u_r, the Earth rate's share of each integral.

    Returns
    -------
    tuple
        The :class:`RotationFit` and whether the bias was solved for.

    Raises
    ------
    EngineInputError
        Rotations that cannot determine M (the reason is named).
    """
    integrals = np.asarray(integrals, float)
    durations = np.asarray(durations, float)
    angle_vec = np.asarray(angles, float)[:, None] * np.asarray(axes, float)
    reference = angle_vec if earth_terms is None else angle_vec + earth_terms
    signed_axes = angle_vec / np.maximum(np.linalg.norm(angle_vec, axis=1, keepdims=True), 1e-300)
    if len(integrals) < 3:
        raise EngineInputError(explain_rotations(signed_axes, labels) if len(integrals) else
                               "no rotation steps (labels rot+x, rot-x, ...): the gyroscope's scale and "
                               "misalignment need rotations about every axis, both ways")
    x = np.hstack([reference, durations[:, None]])
    xn = _unit_columns(x)
    with_bias = len(integrals) >= 4 and np.linalg.matrix_rank(xn, tol=1e-6) == 4
    if with_bias:
        y = integrals
    else:
        x = reference
        xn = _unit_columns(x)
        if np.linalg.matrix_rank(xn, tol=1e-6) < 3:
            raise EngineInputError(explain_rotations(signed_axes, labels))
        y = integrals - np.outer(durations, static_bias)
    k = x.shape[1]
    theta, *_ = np.linalg.lstsq(x, y, rcond=None)
    residual = y - x @ theta
    # the larger of the integrals' white noise and their scatter about the fit (pooled over axes,
    # Student-corrected): bias drift during the turns shows in the scatter only
    scatter = pooled_scatter(residual, k)
    white = np.mean(noise_var, axis=0)
    sigma2 = white if scatter is None else np.maximum(scatter, white)
    xtx_inv = np.linalg.inv(x.T @ x)
    cov = np.zeros((12, 12))
    for j in range(3):
        idx = [3 * j, 3 * j + 1, 3 * j + 2, 9 + j][:k]
        cov[np.ix_(idx, idx)] = sigma2[j] * xtx_inv
    m = theta[:3].T
    b = theta[3] if with_bias else np.asarray(static_bias, float)
    calibrated = (integrals - np.outer(durations, b)) @ np.linalg.inv(m).T
    unit = signed_axes * np.sign(np.asarray(angles))[:, None]
    angle_error = np.sum(calibrated * unit, axis=1) - np.asarray(angles, float)
    return RotationFit(m, b, cov, angle_error, float(np.linalg.cond(xn))), with_bias
