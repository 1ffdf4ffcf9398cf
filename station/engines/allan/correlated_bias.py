"""A correlated (first-order Gauss-Markov) bias fitted beside white noise and random walk, where the IEEE
952 terms cannot draw the curve.

Such a bias draws a hump: the curve rises, peaks near 1.9 correlation times and falls again, which no term
of (C.1) (:mod:`station.engines.allan.fit`) can draw. Where the curve visibly falls again after rising at
well-measured points, N, K and a Gauss-Markov term (sigma, T_c) are fitted instead; when that beats the
IEEE fit by the same chi-square margin an optional IEEE term must earn, B is the peak of the Gauss-Markov
curve divided by 0.66428 (the convention that makes a flicker floor and a Gauss-Markov peak the same B), K
is kept only if still significant, and the report says which method gave each term. Where the curve
leaves the white-noise line and never visibly falls, the same is tried with correlation times from there
on, and taken only where the bias explains the whole rise (see :func:`fit_correlated_bias`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from station.engines.allan.estimates import AxisNoise
from station.engines.allan.shapes import (
    B_FACTOR,
    GM_ADEV_PEAK,
    GM_PEAK_X,
    basis,
    gauss_markov_avar,
    weighted_nnls,
)

# The IEEE fit's own margins (station.engines.allan.fit takes them from here): a Gauss-Markov term must
# earn its place as an optional IEEE 952 term does, and K stays only where it is still significant.
SIGNIFICANCE = 3.0
CHI2_GAIN = 9.0
MIN_EDF_SHOWN = 10.0  # points that count as showing a term or a floor
HUMP_RISE = 0.1
HUMP_FALL = -0.1
DEPARTURE_SLOPE = -0.3  # the curve has left the white-noise line (slope -1/2) upward
UNRESOLVED_PEAK_MARGIN = 4.0  # an unresolved Gauss-Markov bias must peak this factor before the last tau


def fit_correlated_bias(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, result: AxisNoise,
                        values: dict[str, float], chi2: float, duration_s: float) -> dict[str, float]:
    """N, K and a Gauss-Markov bias in place of the IEEE 952 fit, where the curve shows one and the fit
    shows no flat floor.

    A hump (the curve rises then falls again at well-measured points) is fitted with correlation times
    from the curve's first point on; a curve that leaves the white-noise line and never falls, with
    correlation times from where it leaves it on (an unresolved bias). Where the bias is taken,
    ``result`` holds it, its 1-sigma no smaller than the record's length allows, and N, K and B from it.

    Parameters
    ----------
    tau, adev, edf : ndarray, (M,)
        The points the IEEE fit used: averaging times (s), Allan deviations, equivalent degrees of freedom.
    result : AxisNoise
        The IEEE fit of the axis, updated in place where the bias is taken.
    values : dict of str to float
        The IEEE fit's variance coefficients (Q^2, N^2, ...) by term.
    chi2 : float
        The IEEE fit's weighted chi-square.
    duration_s : float
        Length T of the record, s.

    Returns
    -------
    dict of str to float
        The variance coefficients now in the model: the Gauss-Markov fit's N^2 and K^2, or ``values``.
    """
    if _hump_top(tau, adev, edf) is not None:
        values = _fit_with_gauss_markov(tau, adev, edf, result, values, chi2, float(tau[0]), False)
    else:
        departure = _departure_tau(tau, adev, edf)
        if departure is not None:
            values = _fit_with_gauss_markov(tau, adev, edf, result, values, chi2, departure / GM_PEAK_X, True)
    if result.gauss_markov is not None:
        result.gauss_markov_stddev = _at_least_record_bound(result.gauss_markov, result.gauss_markov_stddev,
                                                            duration_s)
    return values


def _hump_top(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray) -> int | None:
    """Index of the top of a hump: after the white-noise decline the curve rises (slope >= +0.1) then
    falls again (slope <= -0.1) at well-measured points. That is a correlated (Gauss-Markov) bias, which
    the IEEE 952 terms cannot draw; its top is the bias-instability level (0.66428 B)."""
    well = np.flatnonzero(edf >= MIN_EDF_SHOWN)
    if len(well) < 5:
        return None
    slope = np.gradient(np.log10(adev), np.log10(tau))
    # from the end of the white-noise decline on
    flat = well[slope[well] >= -0.05]
    if len(flat) == 0:
        return None
    after = well[well >= flat[0]]
    rising = after[slope[after] >= HUMP_RISE]
    if len(rising) == 0:
        return None
    falling = after[(after > rising[0]) & (slope[after] <= HUMP_FALL)]
    if len(falling) == 0:
        return None
    top = rising[0] + int(np.argmax(adev[rising[0]:falling[0] + 1]))
    return top


def _departure_tau(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray) -> float | None:
    """tau of the first well-measured point (EDF >= 10) where the curve has left the white-noise line
    (slope -1/2) upward, slope >= DEPARTURE_SLOPE; None where it never does."""
    slope = np.gradient(np.log10(adev), np.log10(tau))
    where = np.flatnonzero((edf >= MIN_EDF_SHOWN) & (slope >= DEPARTURE_SLOPE))
    return float(tau[where[0]]) if len(where) else None


def _fit_with_gauss_markov(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, result: AxisNoise,
                           values: dict[str, float], chi2_ieee: float, shortest_tc: float,
                           unresolved: bool) -> dict[str, float]:
    """N, K and a first-order Gauss-Markov bias (sigma, T_c on a log grid from ``shortest_tc``),
    EDF-weighted. Where it beats the IEEE fit by CHI2_GAIN or more, writes N, K and B (the Gauss-Markov
    peak / 0.66428) into ``result`` and returns its variance coefficients; else returns ``values``.

    ``unresolved``: the curve shows no hump. A bias of T_c near T/70 (the mocks' unit: 100 s in 2 h)
    rises into a flat stretch and never visibly falls; fitted as N and K, the rise gives K 2.4x too high
    (benchmarks/allan_sweep.py). There T_c starts where the curve leaves the white-noise line (the bias
    cannot peak, at 1.89 T_c, before that: shorter T_c fit the correlated wiggles of the many-EDF first
    points, a chi-square gain of 15 to 50 on white noise alone), and the bias is taken only where it
    explains the whole rise, K no longer significant, and peaks UNRESOLVED_PEAK_MARGIN times before the
    curve's end, so that its fall is drawn by more than the last few-EDF points: a Gauss-Markov term also
    bends an N + K curve near the crossing (a gain of 35 on one of the mocks' N + K records, K still
    significant) or near its end (T_c of 43 s in 20 min, the walk's last points flat by chance)."""
    avar = adev**2
    grid = np.geomspace(min(shortest_tc, tau[-1]), tau[-1], 64)
    fits = []
    for tau_c in grid:
        a = np.column_stack([basis(tau)[:, [1, 3]], gauss_markov_avar(tau, tau_c)])
        c, cov, chi2 = weighted_nnls(a, avar, edf)
        fits.append((chi2, c, cov))
    at = int(np.argmin([f[0] for f in fits]))
    chi2, c, cov = fits[at]
    tau_c = float(grid[at])
    if c[2] <= 0 or chi2_ieee - chi2 < CHI2_GAIN:  # a hump in the noise, not a correlated bias
        return values
    inflate = max(chi2 / max(len(tau) - 4, 1), 1.0)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0) * inflate)
    if unresolved and ((c[1] > 0 and c[1] >= SIGNIFICANCE * sd[1])
                       or GM_PEAK_X * tau_c * UNRESOLVED_PEAK_MARGIN > tau[-1]):
        return values
    sigma = math.sqrt(c[2])
    result.gauss_markov = (sigma, tau_c)
    sd_tau_c = _profile_stddev(grid, [f[0] for f in fits], at, inflate)
    sd_log_sigma = sd[2] / (2.0 * c[2])  # with T_c held
    if sd_tau_c is not None:  # and as T_c moves: the profiled sigma's slope in ln T_c, between the neighbours
        s_lo, s_hi = fits[at - 1][1][2], fits[at + 1][1][2]  # sigma^2 at the neighbours
        step = math.log(grid[at + 1] / grid[at - 1])
        slope = math.log(s_hi / s_lo) / (2.0 * step) if s_lo > 0 < s_hi else 0.0  # d ln sigma / d ln T_c
        sd_log_sigma = math.hypot(sd_log_sigma, slope * sd_tau_c / tau_c)
    result.gauss_markov_stddev = (sigma * sd_log_sigma, sd_tau_c)
    result.reduced_chi2 = chi2 / max(len(tau) - 4, 1)
    how = (f"fit with a Gauss-Markov bias (sigma {sigma:.3g}, T_c {tau_c:.3g} s): the curve rises then "
           "falls again")
    b_est = result.terms["B"]
    b_est.value = GM_ADEV_PEAK * sigma / B_FACTOR  # its Allan deviation peaks at 0.66428 B
    b_est.stddev = b_est.value * sd[2] / (2.0 * c[2])
    b_est.reason = None
    b_est.method = "peak of the " + how
    for i, term in ((0, "N"), (1, "K")):
        est = result.terms[term]
        est.method = how
        if c[i] > 0 and c[i] >= SIGNIFICANCE * sd[i]:
            est.value, est.stddev, est.reason = math.sqrt(c[i]), sd[i] / (2.0 * math.sqrt(c[i])), None
        else:
            est.value = est.stddev = None
            est.reason = ("hidden by the correlated (Gauss-Markov) bias: record longer, until the curve "
                          "rises again after its hump")
    result.coeffs = {t: math.sqrt(v) for t, v in (("N", c[0]), ("K", c[1])) if v > 0}
    result.fitted = ("N", "K")
    return {"N": float(c[0]), "K": float(c[1])}


def _at_least_record_bound(gm: tuple[float, float], sd: tuple[float | None, float | None], duration_s: float
                           ) -> tuple[float | None, float | None]:
    """The curve's 1-sigma of a Gauss-Markov (sigma, T_c), raised to what a record of ``duration_s`` can
    tell at best where they fall below it (they count the curve's overlapping points as independent: on
    the benchmark's 60 axes 2.5 to 2.7 times below the scatter).

    The bound is that of the process observed alone: its sample variance has variance 2 sigma^4 T_c / T
    (Bendat and Piersol, "Random Data", 4th ed., eq. 8.72, T >> T_c), so sd(ln sigma) = sqrt(T_c / 2T);
    its AR(1) coefficient phi = exp(-dt / T_c) has asymptotic variance (1 - phi^2) / n (Brockwell and
    Davis, "Time Series: Theory and Methods", 8.10), so sd(ln T_c) = sqrt(2 T_c / T) for dt << T_c. White
    noise and the other terms on top only widen it."""
    sigma, tau_c = gm
    floor = (sigma * math.sqrt(tau_c / (2.0 * duration_s)), tau_c * math.sqrt(2.0 * tau_c / duration_s))
    return (max(sd[0], floor[0]) if sd[0] is not None else None,
            max(sd[1], floor[1]) if sd[1] is not None else None)


def _profile_stddev(grid: np.ndarray, chi2: Sequence[float], at: int, inflate: float) -> float | None:
    """1-sigma of a positive parameter from its profiled chi-square on a log-spaced ``grid``, minimum at
    ``at``: the parabola in ln(parameter) through the minimum and its neighbours gives sd(ln) =
    sqrt(2 inflate / chi2''), chi2 rising by the reduced chi-square ``inflate`` at 1-sigma (Press et al.,
    Numerical Recipes, 15.6); times the value (delta method). None where the minimum is at an end of the
    grid or the profile is not curved upward there."""
    if at == 0 or at == len(grid) - 1:
        return None
    (x0, x1, x2), (y0, y1, y2) = np.log(grid[at - 1:at + 2]), chi2[at - 1:at + 2]
    curvature = 2.0 * ((y2 - y1) / (x2 - x1) - (y1 - y0) / (x1 - x0)) / (x2 - x0)
    return float(grid[at]) * math.sqrt(2.0 * inflate / curvature) if curvature > 0 else None
