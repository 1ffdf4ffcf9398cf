"""Gyroscope g-sensitivity from the static poses of a turntable capture.

A gyroscope whose bias changes with specific force f (linear-acceleration effect, IEEE Std 1293-2018
and 952-1997 "acceleration-sensitive drift"; datasheets' deg/s/g) reads, still in pose p,

    w_p = b + G f_p (+ M Omega sin(phi) u_p, the Earth rate's vertical part)           (1)

with G the 3x3 g-sensitivity (rad/s per m/s^2) and f_p the specific force the accelerometer feels,
taken as its calibrated pose mean ``correction (a_p - b_a)``. Per gyro axis i, (1) is linear in
(b_i, G_i1, G_i2, G_i3) with the design row [1, f_p]; the P pose means give the least-squares
solution. Column j of G is determined only when e_j lies in the row space of the design
(``A^+ A e_j = e_j``): f_j must take at least two values independently of the other components. The
six poses +-x +-y +-z do (each column from the difference of opposite poses, two spare poses per
axis), the twelve-position sequence adds six tilted ones; a set of poses that never turns an axis
(e.g. only +-x and +-z) leaves that column undetermined, and G is then not given.

Uncertainty: the covariance of the fit, ``s^2 (A^T A)^-1``, with s^2 the larger of the pose means'
white-noise variance and the residual scatter pooled over the axes (``pooled_scatter``): the bias
drifts from pose to pose, and only the scatter shows it. The Earth rate's horizontal part changes
with the heading of each pose, which the capture does not know; it is left in the scatter (at most
Omega cos(phi) = 5e-5 rad/s, about 2e-6 rad/s per m/s^2 of G).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from station.engines.calibration.common import pooled_scatter

AXES = "xyz"


@dataclass
class GSensitivity:
    """The g-sensitivity fit of eq. (1).

    Attributes
    ----------
    matrix, stddev : ndarray (3, 3) or None
        G (rad/s per m/s^2) and its 1-sigma; None unless every column is determined.
    intercept : ndarray, (3,) or None
        b of eq. (1), the bias at zero specific force.
    determined : ndarray of bool, (3,)
        Which columns of G the poses determine.
    warnings : list of str
    """

    matrix: np.ndarray | None
    stddev: np.ndarray | None
    intercept: np.ndarray | None
    determined: np.ndarray
    warnings: list[str] = field(default_factory=list)


def fit_g_sensitivity(gyro_means: np.ndarray, force: np.ndarray, mean_var: np.ndarray,
                      labels: list[str]) -> GSensitivity:
    """G and b of eq. (1) by least squares over the static poses.

    Parameters
    ----------
    gyro_means : ndarray, (P, 3)
        Each pose's mean gyroscope reading, rad/s (the Earth rate's vertical part removed where known).
    force : ndarray, (P, 3)
        Each pose's specific force, m/s^2.
    mean_var : ndarray, (P, 3)
        White-noise variance of each gyro pose mean.
    labels : list of str
        The poses, for messages.

    Returns
    -------
    GSensitivity
    """
    a = np.column_stack([np.ones(len(force)), np.asarray(force, float)])
    pinv = np.linalg.pinv(a, rcond=1e-10)
    projector = pinv @ a
    determined = np.array([np.allclose(projector[:, j], np.eye(4)[:, j], atol=1e-6) for j in (1, 2, 3)])
    if not determined.all():
        missing = ", ".join(AXES[j] for j in range(3) if not determined[j])
        return GSensitivity(None, None, None, determined, [
            f"gyroscope g-sensitivity: the poses ({' '.join(labels)}) do not determine the column(s) "
            f"{missing} of G (the specific force along {missing} never changes on its own); add poses with "
            "those axes up and down (six-position or twelve-position); g_sensitivity is not written"])
    coef = pinv @ np.asarray(gyro_means, float)          # (4, 3): rows b, G^T
    residual = gyro_means - a @ coef
    white = float(np.mean(mean_var))
    scatter = pooled_scatter(residual, 4)
    warnings = []
    if scatter is None:
        warnings.append("gyroscope g-sensitivity: no spare poses, its uncertainty rests on the white noise "
                        "alone; use the twelve-position sequence")
    s2 = max(white, scatter or 0.0)
    cov = s2 * np.linalg.inv(a.T @ a)
    sd = np.sqrt(np.diag(cov))
    return GSensitivity(coef[1:].T.copy(), np.tile(sd[1:], (3, 1)), coef[0].copy(), determined, warnings)


def g_sensitivity_from_poses(acc: np.ndarray, gyro: np.ndarray, statics: list[tuple[str, slice]],
                             accel_matrix: np.ndarray, accel_bias: np.ndarray, gyro_matrix: np.ndarray,
                             earth_vertical: float = 0.0) -> GSensitivity:
    """Eq. (1) over the static steps of a capture.

    Parameters
    ----------
    acc, gyro : ndarray, (N, 3)
        Raw samples.
    statics : list of (label, slice)
        The static pose steps.
    accel_matrix, accel_bias : ndarray
        The accelerometer's calibration (M, b): f_p = M^-1 (a_p - b).
    gyro_matrix : ndarray, (3, 3)
        The gyroscope's M, for the Earth rate's vertical part.
    earth_vertical : float
        Omega sin(latitude), rad/s (0: not compensated).

    Returns
    -------
    GSensitivity
    """
    labels = [lab for lab, _ in statics]
    counts = np.array([sl.stop - sl.start for _, sl in statics], float)
    correction = np.linalg.inv(accel_matrix)
    force = np.array([correction @ (acc[sl].mean(axis=0) - accel_bias) for _, sl in statics])
    up = force / np.linalg.norm(force, axis=1, keepdims=True)
    gyro_means = np.array([gyro[sl].mean(axis=0) for _, sl in statics]) - earth_vertical * up @ gyro_matrix.T
    mean_var = np.array([gyro[sl].var(axis=0, ddof=1) for _, sl in statics]) / counts[:, None]
    return fit_g_sensitivity(gyro_means, force, mean_var, labels)
