"""Gyroscope scale-factor nonlinearity and asymmetry from constant-rate steps (``rate+z:90`` labels).

Each step k about sensor axis i at the true rate w_k (signed, rad/s; ``rate-z:90`` is -90 deg/s about
+z) gives the mean output y_k of that axis over the step's labelled (steady) samples. With the
definitions of ``shared/specs/params-file.md`` (IEEE Std 952-1997, 3.x "scale factor nonlinearity"
and "scale factor asymmetry", least-squares straight line):

    y_k ~ K w_k + c                        least squares over every step of the axis        (1)
    NL = max_k |y_k - (K w_k + c)| / max_k |y_k|  * 1e6   ppm                                (2)
    K+, K-: slopes of (1) fitted through the positive, the negative rates alone
    A = (K+ - K-) / ((K+ + K-) / 2)  * 1e6   ppm                                             (3)
    scale-factor error = (K - 1) * 1e6   ppm                                                 (4)

Uncertainties (1-sigma) come from each step mean's white noise, var(y_k) = s_k^2 / n_k: through the
line fits' covariance for K, K+ and K- (A by first-order propagation), and for NL the noise of the
point with the largest residual over max |y|.

A step is steady when its labelled samples show no trend: the difference of the mean of its first
and its last third must stay within four standard errors plus 0.1 % of the rate, else the table had
not settled (or the label covers the spin-up).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from station.engines.calibration.common import segments
from station.errors import EngineInputError

_RATE = re.compile(r"^rate([+-])([xyz]):(\d+(?:\.\d*)?)$")
AXES = "xyz"
MIN_STEP_SAMPLES = 20
TREND_SIGMAS = 4.0
TREND_FRACTION = 1e-3


def rate_of(label: str) -> tuple[int, float] | None:
    """(axis index, signed rate in rad/s about the positive axis) of a ``rate+z:90`` label, else None.

    Parameters
    ----------
    label : str

    Returns
    -------
    tuple or None
    """
    m = _RATE.match(label.strip())
    if not m:
        return None
    sign, axis, degrees = m.groups()
    rate = np.radians(float(degrees))
    return AXES.index(axis), float(rate if sign == "+" else -rate)


@dataclass(frozen=True)
class RateStep:
    """One steady rate step: its axis, true rate (rad/s), mean output of that axis and the mean's
    white-noise variance."""

    label: str
    axis: int
    rate: float
    mean: float
    mean_var: float
    samples: int


def rate_steps(t: np.ndarray, gyro: np.ndarray, step: np.ndarray | None, source: str) -> list[RateStep]:
    """The constant-rate steps of a labelled capture, each checked steady.

    Parameters
    ----------
    t : ndarray, (N,)
        Times, s.
    gyro : ndarray, (N, 3)
        Raw gyroscope, rad/s.
    step : ndarray of str, (N,) or None
        Step labels.
    source : str
        The capture's name in messages.

    Returns
    -------
    list of RateStep
        Empty when the capture has no rate step.

    Raises
    ------
    EngineInputError
        A step too short, or not steady (naming the step and its time).
    """
    out: list[RateStep] = []
    if step is None:
        return out
    for label, sl in segments(step):
        parsed = rate_of(label)
        if parsed is None:
            continue
        axis, rate = parsed
        y = gyro[sl, axis]
        where = f"{source}: step {label} at t = {t[sl.start]:.3f} s"
        if len(y) < MIN_STEP_SAMPLES:
            raise EngineInputError(f"{where} has {len(y)} steady samples; a rate step needs at least "
                                   f"{MIN_STEP_SAMPLES}: hold each rate longer after the table settles")
        third = len(y) // 3
        first, last = y[:third], y[-third:]
        diff = abs(last.mean() - first.mean())
        allowed = TREND_SIGMAS * np.sqrt(first.var(ddof=1) / third + last.var(ddof=1) / third) \
            + TREND_FRACTION * abs(rate)
        if diff > allowed:
            raise EngineInputError(f"{where}: the rate changes by {np.degrees(diff):.4g} deg/s within the "
                                   f"step (allowed {np.degrees(allowed):.3g}): the table had not settled; "
                                   "let it settle longer before the labelled samples")
        out.append(RateStep(label, axis, rate, float(y.mean()), float(y.var(ddof=1) / len(y)), len(y)))
    return out


def _line(w: np.ndarray, y: np.ndarray, var: np.ndarray) -> tuple[float, float, float, np.ndarray]:
    """Least-squares line y = K w + c (eq. 1): K, c, var(K) from the points' variances, residuals."""
    a = np.column_stack([w, np.ones_like(w)])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    pinv = np.linalg.pinv(a)
    cov = pinv @ np.diag(var) @ pinv.T
    return float(coef[0]), float(coef[1]), float(cov[0, 0]), y - a @ coef


@dataclass(frozen=True)
class ScaleAxis:
    """Eqs. (1)-(4) of one axis (ppm), with 1-sigma; asymmetry None without two rates each way."""

    axis: str
    rates_dps: list[float]
    slope: float
    slope_sd: float
    scale_error_ppm: float
    scale_error_sd_ppm: float
    nonlinearity_ppm: float
    nonlinearity_sd_ppm: float
    asymmetry_ppm: float | None
    asymmetry_sd_ppm: float | None


def scale_axis(steps: Sequence[RateStep], axis: int, source: str) -> ScaleAxis:
    """Nonlinearity, asymmetry and scale-factor error of one axis, eqs. (1)-(4).

    Parameters
    ----------
    steps : sequence of RateStep
        The steps about this axis.
    axis : int
    source : str
        The capture(s) in messages.

    Returns
    -------
    ScaleAxis

    Raises
    ------
    EngineInputError
        Fewer than three distinct rates, or one sign only.
    """
    w = np.array([s.rate for s in steps])
    y = np.array([s.mean for s in steps])
    var = np.array([s.mean_var for s in steps])
    name = AXES[axis]
    if len(np.unique(w)) < 3 or not (np.any(w > 0) and np.any(w < 0)):
        shown = ", ".join(f"{np.degrees(v):+g}" for v in sorted(set(w))) or "none"
        raise EngineInputError(f"{source}: axis {name} has rate steps at {shown} deg/s; the nonlinearity "
                               f"needs at least three rates over the range, both ways (e.g. rate+{name}:30 "
                               f"rate+{name}:300 rate-{name}:30 rate-{name}:300)")
    k, _, k_var, residual = _line(w, y, var)
    peak = int(np.argmax(np.abs(residual)))
    full = float(np.max(np.abs(y)))
    asym = asym_sd = None
    pos, neg = w > 0, w < 0
    if len(np.unique(w[pos])) >= 2 and len(np.unique(w[neg])) >= 2:
        kp, _, kp_var, _ = _line(w[pos], y[pos], var[pos])
        kn, _, kn_var, _ = _line(w[neg], y[neg], var[neg])
        mid = 0.5 * (kp + kn)
        asym = (kp - kn) / mid * 1e6
        # d A / d K+ = K- / mid^2, d A / d K- = -K+ / mid^2
        asym_sd = float(np.sqrt((kn / mid**2) ** 2 * kp_var + (kp / mid**2) ** 2 * kn_var) * 1e6)
    return ScaleAxis(name, sorted(float(np.degrees(v)) for v in w), k, float(np.sqrt(k_var)),
                     (k - 1.0) * 1e6, float(np.sqrt(k_var)) * 1e6,
                     float(abs(residual[peak]) / full * 1e6), float(np.sqrt(var[peak]) / full * 1e6),
                     None if asym is None else float(asym), asym_sd)


def scale_linearity(steps: Sequence[RateStep], source: str) -> list[ScaleAxis | None]:
    """Eqs. (1)-(4) for every axis that has rate steps (None for an axis without any).

    Parameters
    ----------
    steps : sequence of RateStep
    source : str
        The capture(s) in messages.

    Returns
    -------
    list of ScaleAxis or None
        Per axis x, y, z.

    Raises
    ------
    EngineInputError
        No rate step at all, or an axis whose steps cannot determine the figures.
    """
    if not steps:
        raise EngineInputError(f"{source}: no constant-rate steps (labels such as rate+z:90): the "
                               "scale-factor figures need steps at several rates both ways about each axis")
    return [scale_axis([s for s in steps if s.axis == i], i, source) if any(s.axis == i for s in steps)
            else None for i in range(3)]
