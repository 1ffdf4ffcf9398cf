"""Pieces every calibration method shares: step labels, covariances, the result type, conventions.

The forward model of every triad is raw = M true + b with M = K (I + S) (``sensor_model``);
the fits below estimate either M and b directly (linear least squares) or a correction
C = M^-1 (nonlinear fits, like imu_tk's X' = T K (X - B)), converted here.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from station.engines.shared.sensor_model import SensorCalibration

AXES = "xyz"
_POSE = re.compile(r"^(?:[+-][xyz])+$")
_ROTATION = re.compile(r"^rot([+-])([xyz])(?::([+-]?\d+(?:\.\d*)?))?$")


def pose_vector(label: str) -> np.ndarray | None:
    """The unit vector (sensor frame) that points up in a static pose label (``shared/specs/capture-csv.md``).

    Parameters
    ----------
    label : str
        ``+z``, ``-x``, ``+x+y``, ...

    Returns
    -------
    ndarray (3,) or None
        ``+z`` -> (0, 0, 1); ``+x+y`` -> (1, 1, 0)/sqrt(2); None for a label that is not a pose.
    """
    label = label.strip()
    if not _POSE.match(label):
        return None
    v = np.zeros(3)
    for sign, axis in re.findall(r"([+-])([xyz])", label):
        idx = AXES.index(axis)
        if v[idx] != 0:
            return None
        v[idx] = 1.0 if sign == "+" else -1.0
    return v / np.linalg.norm(v)


def rotation_of(label: str) -> tuple[np.ndarray, float] | None:
    """Axis and signed angle of a rotation label.

    Parameters
    ----------
    label : str
        ``rot+z``, ``rot-x:90``, ...

    Returns
    -------
    tuple or None
        (axis unit vector (3,), angle in rad): ``rot-z`` is -360 deg about +z; None for a label that
        is not a rotation.
    """
    m = _ROTATION.match(label.strip())
    if not m:
        return None
    sign, axis, degrees = m.groups()
    vec = np.zeros(3)
    vec[AXES.index(axis)] = 1.0
    angle = np.radians(float(degrees) if degrees else 360.0)
    return vec, (angle if sign == "+" else -angle)


def segments(step: np.ndarray) -> list[tuple[str, slice]]:
    """Contiguous runs of one non-empty label (the same rule as Capture).

    Parameters
    ----------
    step : ndarray of str, (N,)
        Step labels, "" between steps.

    Returns
    -------
    list of (str, slice)
    """
    # neighbours compared as they are: converting a capture's object array of labels to a fixed-width
    # string array first took 10 times longer than the comparison (27 ms for 600,000 labels)
    labels = np.asarray(step)
    if len(labels) == 0:
        return []
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    bounds = np.concatenate([[0], change, [len(labels)]])
    return [(str(labels[a]), slice(int(a), int(b))) for a, b in zip(bounds[:-1], bounds[1:], strict=True)
            if str(labels[a]).strip() != ""]


def covariance(jac: np.ndarray, residual: np.ndarray,
               observations: int | None = None) -> tuple[np.ndarray, float]:
    """Parameter covariance s^2 d / (d - 2) (J^T J)^-1 with s^2 = r^T r / d, d = m - p; and s^2.

    The usual Gauss-Newton estimate at the optimum (e.g. Nocedal & Wright eq. 10.2 with
    the residual variance estimated from the fit), times Student's t variance factor d / (d - 2)
    as in :func:`pooled_scatter`, so that errors over sigma have unit variance with few spare
    residuals (the factor is 1 + 2/d: negligible for sample-level fits).

    Parameters
    ----------
    jac : ndarray, (m, p)
        Jacobian of the residuals at the optimum.
    residual : ndarray, (m,)
        Residuals at the optimum.
    observations : int, optional
        The number m of residual components that carry noise, when fewer than ``len(residual)``
        (a difference of unit vectors has two per vector: its component along them is second order).

    Returns
    -------
    tuple
        Covariance (p, p) and s^2.
    """
    m, p = jac.shape
    m = m if observations is None else observations
    dof = m - p
    s2 = float(residual @ residual / dof) if dof > 0 else float("nan")
    student = dof / (dof - 2) if dof > 2 else float("nan")
    # columns scaled to unit norm first: parameters of very different sizes (a bias in counts beside
    # a scale in g per count) would otherwise make the pseudo-inverse drop the small directions
    norm = np.linalg.norm(jac, axis=0)
    norm[norm == 0] = 1.0
    scaled = jac / norm
    return s2 * student * np.linalg.pinv(scaled.T @ scaled) / np.outer(norm, norm), s2


def pooled_scatter(residual: np.ndarray, unknowns: int) -> float | None:
    """Variance of one row of ``residual`` about a fit, pooled over the three axes.

    s^2 = sum r^2 / d with d = 3 (P - unknowns) degrees of freedom, times Student's t variance
    factor d / (d - 2): a scale estimated from d residuals makes err / s a t variable, whose
    variance is d / (d - 2), so the product gives z-scores of unit variance (for d > 2).
    Pooling the axes assumes their drift and noise are alike (one die, one process), which
    triples the degrees of freedom of a six-pose or six-rotation fit (2 per axis).

    Parameters
    ----------
    residual : ndarray, (P, 3)
        Residuals of the fit.
    unknowns : int
        Parameters per axis of the fit.

    Returns
    -------
    float or None
        s^2, or None when there are no spare rows (d <= 2).
    """
    r = np.asarray(residual, float)
    dof = r.size - 3 * unknowns
    if dof <= 2:
        return None
    return float(np.sum(r**2) / dof * dof / (dof - 2))


def drift_budget(residual: np.ndarray, unknowns: int, white: np.ndarray) -> np.ndarray:
    """Variance budgeted for the session-common bias drift that no single capture can see.

    The poses scatter by white noise plus the drift between them; the drift's variance is
    estimated as the excess s^2 - w (s^2 the scatter pooled over the axes with d = 3 (P - unknowns)
    degrees of freedom and Student-corrected as in :func:`pooled_scatter`, w the mean white
    variance), plus one standard error of s^2, s^2 sqrt(2 / d), so a drift hidden in the noise is
    not budgeted as zero:

        D = max(s^2 - w, 0) + s^2 sqrt(2 / d)

    The rule: the bias may be offset from the unit's long-run value by as much as it drifted from
    pose to pose during the session.

    Parameters
    ----------
    residual : ndarray, (P, 3)
        Per-pose values about a fit with ``unknowns`` parameters per axis (pose means minus their
        mean, or a pose fit's residuals).
    unknowns : int
        Parameters per axis of that fit.
    white : ndarray, (3,)
        White-noise variance of one pose value.

    Returns
    -------
    ndarray, (3,)
        D per axis; ``white`` itself with too few spare poses (d <= 2).
    """
    r = np.asarray(residual, float)
    w = np.asarray(white, float)
    s2 = pooled_scatter(r, unknowns)
    if s2 is None:
        return w
    dof = r.size - 3 * unknowns
    return np.full(3, max(s2 - float(np.mean(w)), 0.0) + s2 * np.sqrt(2.0 / dof))


def propagate(fun: Callable[[np.ndarray], np.ndarray], p: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Covariance of fun(p) by first-order propagation J cov J^T (J by central differences).

    Parameters
    ----------
    fun : callable
        ndarray (n,) -> ndarray.
    p : ndarray, (n,)
    cov : ndarray, (n, n)
        Covariance of ``p``.

    Returns
    -------
    ndarray
        Covariance of the flattened ``fun(p)``.
    """
    p = np.asarray(p, float)
    f0 = np.asarray(fun(p), float).ravel()
    jac = np.empty((len(f0), len(p)))
    for k in range(len(p)):
        h = 1e-6 * max(abs(p[k]), 1e-3 * np.sqrt(max(cov[k, k], 0.0)), 1e-12)
        dp = np.zeros_like(p)
        dp[k] = h
        jac[:, k] = (np.asarray(fun(p + dp)).ravel() - np.asarray(fun(p - dp)).ravel()) / (2 * h)
    return jac @ cov @ jac.T


def _forward_parts(matrix: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """[M (9), b (3), K (3), S (9)] flattened, for uncertainty propagation."""
    scale = np.diag(matrix)
    mis = matrix / scale[:, None] - np.eye(3)
    np.fill_diagonal(mis, 0.0)
    return np.concatenate([matrix.ravel(), bias, scale, mis.ravel()])


def stddev_from(fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], p: np.ndarray,
                cov: np.ndarray) -> dict[str, Any]:
    """1-sigma of matrix, bias, scale and misalignment by first-order propagation (:func:`propagate`).

    Parameters
    ----------
    fun : callable
        (M, b) = fun(p), the forward model's parts from the fitted parameters.
    p : ndarray, (n,)
        Fitted parameters.
    cov : ndarray, (n, n)
        Their covariance.

    Returns
    -------
    dict
        ``matrix`` (3, 3), ``bias`` (3,), ``scale`` (3,), ``misalignment`` (3, 3).
    """
    def parts(q: np.ndarray) -> np.ndarray:
        return _forward_parts(*fun(q))

    sd = np.sqrt(np.clip(np.diag(propagate(parts, p, cov)), 0.0, None))
    return {
        "matrix": sd[0:9].reshape(3, 3),
        "bias": sd[9:12],
        "scale": sd[12:15],
        "misalignment": sd[15:24].reshape(3, 3),
    }


def describe_null(vector: np.ndarray, names: list[str]) -> str:
    """Name the parameter combination a rank-deficient design leaves free (largest entries).

    Parameters
    ----------
    vector : ndarray
        A null vector of the design.
    names : list of str
        The parameters' names.

    Returns
    -------
    str
        e.g. ``+1*b_x -0.5*k_x``.
    """
    v = np.asarray(vector, float)
    v = v / np.max(np.abs(v))
    terms = [f"{v[i]:+.2g}*{names[i]}" for i in np.argsort(-np.abs(v)) if abs(v[i]) > 0.05]
    return " ".join(terms)


@dataclass
class CalibrationReport:
    """What a calibration produced: the two triads plus what a user needs to judge it."""

    accel: SensorCalibration | None
    gyro: SensorCalibration | None
    method: str
    gravity: float
    poses: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)


def triangular_correction(correction: np.ndarray, convention: str) -> tuple[np.ndarray, np.ndarray]:
    """Split a correction C into a rotation Q and a triangular C' with C = Q C' (diag(C') > 0).

    ``upper``: C' upper triangular (imu_tk's T K, T unit upper triangular), by QR of C.
    ``lower``: C' lower triangular (the lecture's body frame: body x = sensor x, body xy plane =
    sensor xy plane), by QR of the row- and column-reversed C (a "QL" decomposition).
    The two conventions of one sensor therefore differ exactly by the rotation between
    their body frames: C_upper = Q_u^T C = Q_u^T Q_l C_lower.

    Parameters
    ----------
    correction : ndarray, (3, 3)
        C = M^-1.
    convention : str
        "lower" or "upper".

    Returns
    -------
    tuple of ndarray
        Q and C'.

    Raises
    ------
    ValueError
        An unknown convention.
    """
    c = np.asarray(correction, float)
    if convention == "upper":
        q, r = np.linalg.qr(c)
    elif convention == "lower":
        flip = np.eye(3)[::-1]
        q0, r0 = np.linalg.qr(flip @ c @ flip)
        q, r = flip @ q0 @ flip, flip @ r0 @ flip
    else:
        raise ValueError(f"convention must be 'lower' or 'upper', got {convention!r}")
    signs = np.sign(np.diag(r))
    signs[signs == 0] = 1.0
    return q * signs, signs[:, None] * r


def convert_convention(accel_correction: np.ndarray, gyro_correction: np.ndarray | None,
                       to: str) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Re-express an (accel, gyro) correction pair in the body frame of convention ``to``.

    The accelerometer's correction becomes triangular (see :func:`triangular_correction`),
    the gyroscope's is rotated with it (its rates are expressed in the same body frame).

    Parameters
    ----------
    accel_correction : ndarray, (3, 3)
        The accelerometer's C.
    gyro_correction : ndarray, (3, 3) or None
        The gyroscope's C.
    to : str
        "lower" or "upper".

    Returns
    -------
    tuple
        (accel C', gyro C' or None, Q^T) where Q^T rotates old body vectors into the new frame.
    """
    q, acc_c = triangular_correction(accel_correction, to)
    gyro_c = None if gyro_correction is None else q.T @ np.asarray(gyro_correction, float)
    return acc_c, gyro_c, q.T


def quantum(values: np.ndarray) -> float:
    """The smallest step between distinct values (the output's resolution, if quantized).

    Parameters
    ----------
    values : ndarray

    Returns
    -------
    float
        0 when all values are equal.
    """
    levels = np.unique(np.asarray(values, float))
    return float(np.diff(levels).min()) if len(levels) > 1 else 0.0


def dithers(spread: np.ndarray, static: np.ndarray) -> np.ndarray:
    """Per axis: does the noise of still samples exceed their resolution (and floating-point rounding)?

    Only then does a run of identical samples at an axis's extreme mean clipping: under a
    resolution much coarser than the noise, a steady rate reads one value for many samples
    without being clipped.

    Parameters
    ----------
    spread : ndarray, (3,)
        Noise (standard deviation) of the still samples.
    static : ndarray, (n, 3)
        The still samples.

    Returns
    -------
    ndarray of bool, (3,)
    """
    static = np.asarray(static, float)
    floor = np.array([max(quantum(static[:, i]), 1e-9 * max(1.0, np.abs(static[:, i]).max()))
                      for i in range(3)])
    return np.asarray(spread) > floor


# A time step longer than this many median steps is lost samples.
GAP_FACTOR = 2.5


def lost_samples(t: np.ndarray, step: float) -> tuple[int, float] | None:
    """The largest time step of ``t`` where it exceeds ``GAP_FACTOR`` times the nominal step.

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    step : float
        Nominal time step, s.

    Returns
    -------
    tuple or None
        (index of the sample before the gap, its size in s), or None where no samples were lost.
    """
    gaps = np.diff(np.asarray(t, float))
    if len(gaps) == 0:
        return None
    k = int(np.argmax(gaps))
    return (k, float(gaps[k])) if gaps[k] > GAP_FACTOR * step else None


def pinned_run(values: np.ndarray, extreme: float) -> tuple[int, int]:
    """The longest run of consecutive samples equal to ``extreme``.

    Parameters
    ----------
    values : ndarray, (N,)
    extreme : float

    Returns
    -------
    tuple of int
        (start index, length); (0, 0) without such a sample.
    """
    pinned = np.concatenate([[0], (np.asarray(values) == extreme).astype(np.int8), [0]])
    edges = np.flatnonzero(np.diff(pinned))
    if len(edges) == 0:
        return 0, 0
    starts, lengths = edges[::2], edges[1::2] - edges[::2]
    k = int(np.argmax(lengths))
    return int(starts[k]), int(lengths[k])
