"""The fit of one candidate noise model to an Allan deviation curve: eq. (1) of
:mod:`station.engines.allan.model`, minimised over the logarithms of the candidate's coefficients and
time constants.

A candidate is a set of terms (:class:`Combination`: IEEE 952 terms, Gauss-Markov processes, the output
filter, sinusoids); the curve's points carry their weights and 68 % interval (:class:`WeightedCurve`).
Here are the starts (a dictionary of Gauss-Markov curves fitted by weighted non-negative least squares),
the bounds, the trust-region solve and the covariance from its Jacobian. Which candidates are fitted, which
is reported, and why, is the model module's: its docstring describes the method and cites its sources.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from station.engines.allan.estimates import Estimate
from station.engines.allan.shapes import (
    gauss_markov_avar,
    sinusoid_avar,
    term_avar,
    weighted_nnls_fit,
)
from station.engines.allan.uncertainty import log_chi2_moments

TOLERANCE = 0.10  # a point is described within its 68 % interval or within 10 % of its value
GM_PER_DECADE = 6  # the dictionary's correlation times
FILTER_SLOPE = -0.45  # a curve that starts above this slope bends below the white-noise line: a filter
SIN_PER_DECADE = 40  # frequencies tried for a sinusoid's start
SIN_PARAMS = 2
GM_PARAMS = 2
MAX_NFEV = 400  # evaluations of (1) per solve


@dataclass(frozen=True)
class Combination:
    """The terms of one candidate model."""

    terms: tuple[str, ...]  # IEEE 952 terms, N first
    n_gm: int
    filtered: bool
    n_sin: int
    dt: float = 0.0  # the sample period, for the filter's discrete form

    @property
    def parameters(self) -> int:
        """How many parameters the combination fits."""
        return len(self.terms) + GM_PARAMS * self.n_gm + self.filtered + SIN_PARAMS * self.n_sin


@dataclass
class CandidateFit:
    """One combination fitted: its log parameters, (1) at them and their covariance."""

    combo: Combination
    x: np.ndarray  # log coefficients, then log T_f, log T_k, log f_j
    chi2: float
    cov: np.ndarray


def unpack(combo: Combination, x: np.ndarray) -> tuple[np.ndarray, float | None, np.ndarray, np.ndarray]:
    """(coefficients, T_f, GM correlation times, sinusoid frequencies) from the log parameters."""
    n_lin = len(combo.terms) + combo.n_gm + combo.n_sin
    c = np.exp(np.minimum(x[:n_lin], 300.0))  # a trial step may overshoot: no overflow
    at = n_lin
    t_f = None
    if combo.filtered:
        t_f = float(np.exp(x[at]))
        at += 1
    t_gm = np.exp(x[at:at + combo.n_gm])
    freqs = np.exp(x[at + combo.n_gm:at + combo.n_gm + combo.n_sin])
    return c, t_f, t_gm, freqs


def _columns(combo: Combination, tau: np.ndarray, t_f: float | None, t_gm: Sequence[float] | np.ndarray,
             freqs: Sequence[float] | np.ndarray) -> np.ndarray:
    """The shapes of ``combo``'s terms at ``tau`` for the given time constants: one column each."""
    cols = [term_avar(t, tau, t_f, combo.dt) for t in combo.terms]
    cols += [gauss_markov_avar(tau, t) for t in t_gm]
    cols += [sinusoid_avar(tau, f) for f in freqs]
    return np.column_stack(cols)


def combination_avar(combo: Combination, tau: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The Allan variance at ``tau`` of ``combo`` with the log parameters ``x``."""
    c, t_f, t_gm, freqs = unpack(combo, x)
    return _columns(combo, tau, t_f, t_gm, freqs) @ c


@dataclass
class WeightedCurve:
    """The points fitted, with their weights and 68 % interval."""

    tau: np.ndarray
    avar: np.ndarray
    edf: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    rate_hz: float
    filter_reach_s: float | None = None  # where a filtered start falls to FILTER_SLOPE (filter_reach)

    def part(self, keep: np.ndarray | slice) -> WeightedCurve:
        """The points ``keep`` selects."""
        return WeightedCurve(self.tau[keep], self.avar[keep], self.edf[keep], self.lo[keep], self.hi[keep],
                             self.rate_hz, self.filter_reach_s)

    def filter_start(self) -> float:
        """The filter's time constant to start from: a fifteenth of where the slope reaches FILTER_SLOPE
        (:func:`station.engines.allan.fit._filter_settled`)."""
        return (self.filter_reach_s or 3.0 * float(self.tau[0])) / 15.0

    def log_residuals(self, model_avar: np.ndarray) -> np.ndarray:
        """The weighted residuals of (1): (ln sigma_hat^2 - E ln - ln sigma^2) / sd, exact for a scaled
        chi-square of edf degrees of freedom (:func:`log_chi2_moments`)."""
        mean, sd = log_chi2_moments(self.edf)
        tiny = np.finfo(float).tiny
        return (np.log(self.avar) - mean - np.log(np.maximum(model_avar, tiny))) / sd

    def chi2(self, model_avar: np.ndarray) -> float:
        """(1) for a model's Allan variance at the curve's cluster times."""
        return float(np.sum(self.log_residuals(model_avar) ** 2))

    def outside(self, model_avar: np.ndarray) -> np.ndarray:
        """Which points the model leaves outside both their 68 % interval and the tolerance."""
        adev = np.sqrt(np.maximum(model_avar, 0.0))
        meas = np.sqrt(self.avar)
        out_band = (adev < self.lo) | (adev > self.hi)
        return out_band & (np.abs(adev / meas - 1.0) > TOLERANCE)


def _strictly_feasible(x: np.ndarray, lb: np.ndarray, ub: np.ndarray, rstep: float = 1e-10) -> np.ndarray:
    """``x`` moved at least ``rstep`` (relative) inside its bounds, as scipy's least_squares moves its start
    (``scipy.optimize._lsq.common.make_strictly_feasible``)."""
    lower_dist, upper_dist = x - lb, ub - x
    lower_thr, upper_thr = rstep * np.maximum(1, np.abs(lb)), rstep * np.maximum(1, np.abs(ub))
    lower = np.isfinite(lb) & (lower_dist <= np.minimum(upper_dist, lower_thr))
    upper = np.isfinite(ub) & (upper_dist <= np.minimum(lower_dist, upper_thr))
    lower &= ~upper
    x_new = x.copy()
    x_new[lower] = lb[lower] + rstep * np.maximum(1, np.abs(lb[lower]))
    x_new[upper] = ub[upper] - rstep * np.maximum(1, np.abs(ub[upper]))
    tight = (x_new < lb) | (x_new > ub)
    x_new[tight] = 0.5 * (lb[tight] + ub[tight])
    return x_new


def _solve(curve: WeightedCurve, combo: Combination, x0: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]
           ) -> CandidateFit:
    """Minimise (1) from ``x0`` (scipy's trust-region reflective method, compiled: :mod:`._trf`); the
    covariance of the log parameters from the Jacobian."""
    from station.engines.allan import _trf  # numba: only a command that selects a model compiles it

    mean, sd = log_chi2_moments(curve.edf)
    w = np.ascontiguousarray(1.0 / sd)
    log_avar = np.ascontiguousarray(np.log(curve.avar) - mean)
    tau = np.ascontiguousarray(curve.tau)
    # the IEEE terms' columns, built once; the solve writes those of the filtered N, processes, sinusoids
    fixed = np.zeros((len(tau), len(combo.terms) + combo.n_gm + combo.n_sin))
    for j, t in enumerate(combo.terms):
        if not (t == "N" and combo.filtered):
            fixed[:, j] = term_avar(t, tau, None, combo.dt)
    if combo.terms[0] != "N":
        raise ValueError(f"a combination starts with N, not {combo.terms[0]}")
    x0 = _strictly_feasible(np.clip(x0, bounds[0] + 1e-9, bounds[1] - 1e-9), *bounds)
    x, fun, jac, _ = _trf.solve(x0, bounds[0], bounds[1], tau, fixed, len(combo.terms), combo.n_gm,
                                combo.filtered, combo.dt, w, log_avar, MAX_NFEV)
    chi2 = float(np.sum(fun**2))
    dof = max(len(curve.tau) - len(x), 1)
    with np.errstate(all="ignore"):
        cov = np.linalg.pinv(jac.T @ jac) * max(chi2 / dof, 1.0)
    return CandidateFit(combo, x, chi2, cov)


def _bounds(combo: Combination, curve: WeightedCurve) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients free; T_f up to where the filtered start reaches FILTER_SLOPE (3 tau0 at least),
    correlation times within the curve (beyond it a process is white noise or a random walk) and, with
    the filter, beyond that reach; sinusoids between 1 / (4 T) and Nyquist."""
    n_lin = len(combo.terms) + combo.n_gm + combo.n_sin
    lo = [-np.inf] * n_lin
    hi = [np.inf] * n_lin
    tau0, tau1 = float(curve.tau[0]), float(curve.tau[-1])
    if combo.filtered:
        lo.append(math.log(tau0 * 1e-3))
        hi.append(math.log(max(3.0 * tau0, curve.filter_reach_s or 0.0)))
    # a process faster than the filter's reach would draw the filter again (a degenerate pair)
    lo += [math.log(max(tau0, curve.filter_reach_s or 0.0) if combo.filtered else tau0)] * combo.n_gm
    hi += [math.log(tau1)] * combo.n_gm
    lo += [math.log(0.25 / tau1)] * combo.n_sin
    hi += [math.log(curve.rate_hz / 2.0)] * combo.n_sin
    return np.array(lo), np.array(hi)


def _gm_grid(curve: WeightedCurve) -> np.ndarray:
    decades = math.log10(curve.tau[-1] / curve.tau[0])
    return np.geomspace(curve.tau[0], curve.tau[-1], max(int(decades * GM_PER_DECADE) + 1, 2))


def _linear_start(curve: WeightedCurve, combo: Combination, t_f: float | None, t_gm: Sequence[float],
                  freqs: Sequence[float]) -> np.ndarray:
    """Log coefficients of the EDF-weighted non-negative least squares for fixed time constants; terms
    it zeroes start at a millionth of the curve's scale (a log parameter cannot start at zero)."""
    a = _columns(combo, curve.tau, t_f, t_gm, freqs)
    c, _ = weighted_nnls_fit(a, curve.avar, curve.edf)
    floor = 1e-6 * float(np.median(curve.avar)) / np.maximum(np.max(a, axis=0), np.finfo(float).tiny)
    return np.log(np.maximum(c, floor))


def gm_starts(curve: WeightedCurve, terms: tuple[str, ...], t_f: float | None, freqs: Sequence[float]
              ) -> list[float]:
    """Correlation times where a dictionary of Gauss-Markov curves (beside the IEEE terms) puts weight:
    the active entries cluster; each cluster's weighted geometric mean, the largest contribution first."""
    grid = _gm_grid(curve)
    combo = Combination(terms, len(grid), t_f is not None, len(freqs), 1.0 / curve.rate_hz)
    a = _columns(combo, curve.tau, t_f, grid, freqs)
    c, _ = weighted_nnls_fit(a, curve.avar, curve.edf)
    g = c[len(terms):len(terms) + len(grid)]
    clusters: list[list[int]] = []
    for i in np.flatnonzero(g > 0):
        if clusters and i - clusters[-1][-1] <= 1:
            clusters[-1].append(int(i))
        else:
            clusters.append([int(i)])
    # with the filter, the dictionary's curves below its reach stand in for the filter itself: a process
    # there is out of bounds (_bounds), and starting one there wastes it (the full fit misses a process)
    fastest = max(float(curve.tau[0]), curve.filter_reach_s or 0.0) if t_f is not None else 0.0
    peaks = []
    for cl in clusters:
        weight = g[cl] * gauss_markov_avar(grid[cl] * 1.89, 1.0).max()
        t = float(np.exp(np.sum(weight * np.log(grid[cl])) / np.sum(weight)))
        if t >= fastest:
            peaks.append((float(np.sum(weight)), t))
    peaks.sort(reverse=True)
    return [t for _, t in peaks]


def _padded(times: Sequence[float], n: int, curve: WeightedCurve) -> list[float]:
    """The first ``n`` of ``times``, completed by times spread over the curve, in increasing order."""
    out = [float(t) for t in times[:n]]
    for t in np.geomspace(curve.tau[0] * 3.0, curve.tau[-1] / 3.0, n + 2)[1:-1]:
        if len(out) >= n:
            break
        out.append(float(t))
    return sorted(out)


def _fit_combo(curve: WeightedCurve, combo: Combination, t_f: float | None, t_gm: Sequence[float],
               freqs: Sequence[float]) -> CandidateFit:
    """Fit one combination from the given time constants and frequencies (coefficients from the linear
    fit with those held)."""
    x0 = list(_linear_start(curve, combo, t_f, t_gm, freqs))
    if combo.filtered:
        x0.append(math.log(t_f if t_f is not None else curve.filter_start()))
    x0 += [math.log(t) for t in t_gm] + [math.log(f) for f in freqs]
    return _solve(curve, combo, np.array(x0), _bounds(combo, curve))


def by_weight(fit: CandidateFit) -> list[float]:
    """The correlation times of a fit's processes, the largest peak first."""
    c, _, t_gm, _ = unpack(fit.combo, fit.x)
    sig2 = c[len(fit.combo.terms):len(fit.combo.terms) + fit.combo.n_gm]
    return [float(t) for _, t in sorted(zip(sig2, t_gm, strict=True), reverse=True)]


def fit_best_start(curve: WeightedCurve, combo: Combination, t_f: float | None,
                   starts: Sequence[Sequence[float]], freqs: Sequence[float]) -> CandidateFit:
    """Fit ``combo`` from each list of correlation times in ``starts`` (the first ``combo.n_gm`` of each),
    keep the smallest (1)."""
    best: CandidateFit | None = None
    tried: list[list[float]] = []
    for times in starts:
        t_gm = _padded(times, combo.n_gm, curve)
        if any(np.allclose(t_gm, t, rtol=1e-6) for t in tried):
            continue
        tried.append(t_gm)
        fit = _fit_combo(curve, combo, t_f, t_gm, freqs)
        if best is None or fit.chi2 < best.chi2:
            best = fit
    assert best is not None
    return best


def sinusoid_start(curve: WeightedCurve, base: CandidateFit) -> float:
    """The frequency whose sinusoid, added to ``base`` (its time constants fixed), fits best."""
    _, t_f, t_gm, freqs = unpack(base.combo, base.x)
    combo = Combination(base.combo.terms, base.combo.n_gm, base.combo.filtered, base.combo.n_sin + 1,
                         base.combo.dt)
    best = (math.inf, 1.0)
    lo, hi = 0.25 / curve.tau[-1], curve.rate_hz / 2.0
    grid = np.geomspace(lo, hi, int(SIN_PER_DECADE * math.log10(hi / lo)) + 1)
    a = _columns(combo, curve.tau, t_f, t_gm, [*freqs, grid[0]])  # the last column moves alone
    for f in grid:
        a[:, -1] = sinusoid_avar(curve.tau, f)
        _, chi2 = weighted_nnls_fit(a, curve.avar, curve.edf, iterations=3)
        if chi2 < best[0]:
            best = (chi2, float(f))
    return best[1]


def filter_reach(tau: np.ndarray, adev: np.ndarray) -> float | None:
    """Where a curve that starts above slope FILTER_SLOPE (below the white-noise line: a filter or
    decimation) first falls to it; None where it starts below that slope or never falls to it."""
    if len(tau) < 3:
        return None
    slope = np.gradient(np.log10(adev), np.log10(tau))
    below = np.flatnonzero(slope <= FILTER_SLOPE)
    if slope[0] <= FILTER_SLOPE or len(below) == 0:
        return None
    return float(tau[below[0]])


def parameter_estimates(fit: CandidateFit
                        ) -> tuple[list[Estimate], Estimate | None, list[Estimate], list[Estimate]]:
    """Every parameter's value and 1-sigma: coefficients as sqrt (delta method: sd = value sd(log c) / 2),
    time constants and frequencies as themselves (sd = value sd(log))."""
    combo = fit.combo
    sd = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    c, t_f, t_gm, freqs = unpack(combo, fit.x)
    n_lin = len(c)

    def est(value: float, sd_log: float) -> Estimate:
        return Estimate(value, value * sd_log if np.isfinite(sd_log) else None)

    amplitudes = [est(math.sqrt(ci), sd[i] / 2.0) for i, ci in enumerate(c)]
    at = n_lin
    filt = None
    if t_f is not None:
        filt = est(t_f, sd[at])
        at += 1
    times = [est(float(t), sd[at + k]) for k, t in enumerate(t_gm)]
    at += len(t_gm)
    fr = [est(float(f), sd[at + k]) for k, f in enumerate(freqs)]
    return amplitudes, filt, times, fr


def outside_count(fit: CandidateFit, curve: WeightedCurve) -> int:
    """How many of the curve's points the fit leaves outside their 68 % interval and the tolerance."""
    return int(np.count_nonzero(curve.outside(combination_avar(fit.combo, curve.tau, fit.x))))


def curve_of(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, ci_low: np.ndarray, ci_high: np.ndarray,
             rate_hz: float) -> WeightedCurve:
    """The points of a curve that can be fitted (a positive deviation and EDF), as variances."""
    tau = np.asarray(tau, dtype=np.float64)
    adev = np.asarray(adev, dtype=np.float64)
    edf = np.asarray(edf, dtype=np.float64)
    ok = np.isfinite(adev) & (adev > 0) & np.isfinite(edf) & (edf > 0)
    return WeightedCurve(tau[ok], adev[ok] ** 2, edf[ok], np.asarray(ci_low, dtype=np.float64)[ok],
                         np.asarray(ci_high, dtype=np.float64)[ok], float(rate_hz))
