"""Statistical process control of one measurement across units: capability and the individuals chart.

Pure numpy; equations from D. C. Montgomery, *Introduction to Statistical Quality Control*, 7th ed.
(Wiley, 2013): the process capability index Cpk, eq. (8.8) with its one-sided forms (8.6), (8.7),
and the individuals control chart with the moving range of span two, eq. (6.33).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

D2_SPAN_TWO = 1.128
"""d2 of a moving range of two observations (Montgomery, Appendix VI): sigma estimate = MR-bar / d2."""


@dataclass(frozen=True)
class Capability:
    """n, mean, sample standard deviation (n - 1) and Cpk of one measurement (NaN where undefined)."""

    n: int
    mean: float
    std: float
    cpk: float | None


@dataclass(frozen=True)
class ControlChart:
    """An individuals chart: centre line, control limits and which points lie beyond them."""

    center: float
    lcl: float
    ucl: float
    mr_bar: float
    beyond: np.ndarray


def capability(values: np.ndarray, low: float | None, high: float | None) -> Capability:
    """Capability of ``values`` against the specification limits ``low``/``high``.

    Parameters
    ----------
    values : ndarray, (N,)
        The measured values, in the limits' unit; NaN values are left out.
    low, high : float or None
        Lower and upper specification limits; None is no limit on that side.

    Returns
    -------
    Capability
        ``cpk`` is min(CPU, CPL) with CPU = (USL - mean) / (3 s), CPL = (mean - LSL) / (3 s)
        (eq. 8.8); with one limit it is that side's index alone (eqs. 8.6, 8.7); None without limits,
        and NaN when s is zero or fewer than two values exist (the index is undefined).
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    n = int(x.size)
    mean = float(x.mean()) if n else math.nan
    std = float(x.std(ddof=1)) if n > 1 else math.nan  # sample standard deviation, n - 1
    if low is None and high is None:
        return Capability(n, mean, std, None)
    if not (n > 1 and std > 0.0):
        return Capability(n, mean, std, math.nan)
    sides = []
    if high is not None:
        sides.append((high - mean) / (3.0 * std))  # CPU, eq. (8.6)
    if low is not None:
        sides.append((mean - low) / (3.0 * std))  # CPL, eq. (8.7)
    return Capability(n, mean, std, float(min(sides)))


def individuals_chart(values: np.ndarray) -> ControlChart:
    """The individuals control chart of ``values`` in time order (Montgomery eq. 6.33).

    Parameters
    ----------
    values : ndarray, (N,)
        The measured values in time order; NaN values are neither used nor flagged.

    Returns
    -------
    ControlChart
        Centre line x-bar; limits x-bar -/+ 3 MR-bar / d2 with MR-bar the mean of |x_i - x_{i-1}|
        over consecutive values (d2 = 1.128); ``beyond`` (N,) marks the values outside them.
        Fewer than two values give NaN limits and flag nothing.
    """
    x = np.asarray(values, dtype=float)
    finite = np.isfinite(x)
    kept = x[finite]
    if kept.size < 2:
        center = float(kept.mean()) if kept.size else math.nan
        return ControlChart(center, math.nan, math.nan, math.nan, np.zeros(x.shape, dtype=bool))
    center = float(kept.mean())
    mr_bar = float(np.abs(np.diff(kept)).mean())
    half = 3.0 * mr_bar / D2_SPAN_TWO
    lcl, ucl = center - half, center + half
    beyond = np.zeros(x.shape, dtype=bool)
    beyond[finite] = (kept < lcl) | (kept > ucl)
    return ControlChart(center, lcl, ucl, mr_bar, beyond)
