"""A noise model chosen by the data: IEEE 952 terms, Gauss-Markov processes, the sensor's filter, sinusoids.

The model's Allan variance is a sum of non-negative terms (IEEE Std 952-1997, Annex C):

    sigma^2(tau) = 3 Q^2 / tau^2 + N^2 h_f(tau) + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2     (C.1)
                   + sum_k sigma_k^2 g(tau, T_k)                                  Gauss-Markov, (C.6)
                   + sum_j A_j^2 sin^4(pi f_j tau) / (pi f_j tau)^2               sinusoids, (C.7)

g is the Allan variance of a unit first-order Gauss-Markov process of correlation time T
(:func:`station.engines.allan.fit.gauss_markov_avar`); h_f(tau) = 1 / tau for white noise, and for white
noise seen through the sensor's first-order digital output filter of time constant T_f the exact Allan
variance of the sampled AR(1) output (:func:`filtered_white_avar`; g(tau, T_f) / (2 T_f) in the
continuous limit): its curve bends below the white-noise line at the shortest cluster times and meets it,
within 3 %, from 50 T_f on.

The fit follows the generalized method of wavelet moments (Guerrier, Skaloud, Stebler and Victoria-Feser,
"Wavelet-variance-based estimation for composite stochastic processes", JASA 108(503), 2013; the Allan
variance is twice the Haar wavelet variance) with the weights of the curve's own EDF: it minimises

    sum_i [ln(sigma_hat^2(tau_i) / sigma^2(tau_i; theta)) - m(edf_i)]^2 / v(edf_i)                     (1)

where m = psi(edf / 2) - ln(edf / 2) and v = psi'(edf / 2) are the mean and variance of the logarithm of
a chi-square variable of edf degrees of freedom scaled by edf (:func:`log_chi2_moments`; ~ -1 / edf and
2 / edf for many EDF, but at the few EDF of the longest cluster times the mean matters: without it the
fit sits under those points), over the logarithms of every coefficient and time constant
(Levenberg-Marquardt type trust region, scipy), started from a non-negative least-squares fit of a
dictionary of Gauss-Markov curves (correlation times six per decade: the active ones cluster where the
curve needs a process).

Which terms: every admissible combination (any subset of Q, B, K, R beside N, and zero to three Gauss-Markov
processes; the filter and sinusoids where the curve shows them) is fitted, and the simplest (fewest
parameters; then the smallest (1)) that describes the curve is chosen (:func:`preferred`). "Describes" is a
goodness-of-fit test point by point: the model lies inside the curve's 68 % interval, or within TOLERANCE of
the curve, at every cluster time of the valid range. Not an information criterion: the points of an
overlapping Allan curve are strongly correlated (neighbouring cluster times share most of their data), so (1)
is not a log-likelihood and AIC or BIC would count the same evidence many times over. The band test asks of
each point only what its own EDF promises, which is also what the plot shows and what a filter that takes
the model as its process noise needs. Where no combination passes, the points left outside may be scatter (a
third of independent points fall outside a 68 % interval by chance): then the fewest outside is the
reference, and a simpler combination is preferred unless the reference lowers (1) by CHI2_GAIN per added
parameter (about ln 53, BIC's for the points of a 10,000 s curve), so that chance is kept apart from
evidence. The IEEE fit is tried first and stands where it describes the curve well enough (see
:func:`choose_model`), which keeps records of the IEEE terms from gaining processes. Each term's 1-sigma
comes from the Jacobian of (1) at the optimum, inflated by the reduced chi-square where that exceeds one.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, special

from station.engines.allan.fit import B_FACTOR, TERMS, AxisNoise, TermEstimate, _irls, gauss_markov_avar

OPTIONAL = ("Q", "B", "K", "R")
MAX_GM = 3
MAX_SINUSOIDS = 2
TOLERANCE = 0.10  # a point is described within its 68 % interval or within 10 % of its value
GM_PER_DECADE = 6  # the dictionary's correlation times
FILTER_SLOPE = -0.45  # a curve that starts above this slope bends below the white-noise line: a filter
SHORTEST_VALID = 0.1  # s: leading points the filter model leaves undescribed are dropped up to here at most
SIN_PER_DECADE = 40  # frequencies tried for a sinusoid's start
SIN_PARAMS = 2
CHI2_GAIN = 4.0  # per parameter: what a richer model must gain in (1) over a simpler one
KEEP_REDUCED_CHI2 = 3.0  # (1) per point beyond which the IEEE fit misses the curve (see choose_model)
SIN_GAIN = 100.0  # a sinusoid draws the correlated wiggles of the many-EDF first points too (gains of tens)
GM_PARAMS = 2
JAC_STEP = 1e-6  # in the log of a time constant or frequency


@dataclass(frozen=True)
class Estimate:
    """A fitted quantity and its 1-sigma (None where the fit cannot tell it)."""

    value: float
    stddev: float | None


@dataclass(frozen=True)
class GaussMarkov:
    """A first-order Gauss-Markov process: steady-state 1-sigma and correlation time (s)."""

    sigma: Estimate
    tau_c: Estimate


@dataclass(frozen=True)
class Sinusoid:
    """A sinusoid in the rate: amplitude (the section's unit) and frequency (Hz)."""

    amplitude: Estimate
    freq_hz: Estimate


@dataclass
class NoiseModel:
    """The model chosen for one axis, with every term's value and 1-sigma, and how it was chosen.

    ``terms`` holds the IEEE 952 terms present (Q, N, B, K, R); ``filter_s`` the output filter's time
    constant where modelled; ``valid_tau`` the cluster times (s) the model was fitted to and describes;
    ``outside`` how many of them it leaves outside both the 68 % interval and the tolerance.
    """

    terms: dict[str, Estimate] = field(default_factory=dict)
    gauss_markov: list[GaussMarkov] = field(default_factory=list)
    sinusoids: list[Sinusoid] = field(default_factory=list)
    filter_s: Estimate | None = None
    valid_tau: tuple[float, float] = (math.nan, math.nan)
    outside: int = 0
    points: int = 0
    chi2: float = math.nan
    parameters: int = 0
    combinations: int = 0
    describes: bool = False
    method: str = ""
    dt_s: float = 0.0  # sample period (the filter's discrete form)

    def describe(self) -> str:
        """The model's terms in words, e.g. ``N (filtered) + K + 2 Gauss-Markov + 1 sinusoid``."""
        parts = [f"{name} (filtered)" if name == "N" and self.filter_s is not None else name
                 for name in self.terms]
        if self.gauss_markov:
            parts.append(f"{len(self.gauss_markov)} Gauss-Markov")
        if self.sinusoids:
            parts.append(f"{len(self.sinusoids)} sinusoid{'s' if len(self.sinusoids) > 1 else ''}")
        return " + ".join(parts)

    def parts(self, tau: np.ndarray) -> dict[str, np.ndarray]:
        """Allan variance of each term at ``tau``, by label (``N``, ``K``, ``GM1``, ``S1``, ...).

        Parameters
        ----------
        tau : ndarray, (M,)
            Averaging times, s.

        Returns
        -------
        dict of str to ndarray
        """
        tau = np.asarray(tau, dtype=np.float64)
        t_f = self.filter_s.value if self.filter_s is not None else None
        out = {name: est.value**2 * _shape(name, tau, t_f, self.dt_s) for name, est in self.terms.items()}
        for k, gm in enumerate(self.gauss_markov, 1):
            out[f"GM{k}"] = gm.sigma.value**2 * gauss_markov_avar(tau, gm.tau_c.value)
        for k, s in enumerate(self.sinusoids, 1):
            out[f"S{k}"] = s.amplitude.value**2 * sinusoid_avar(tau, s.freq_hz.value)
        return out

    def avar(self, tau: np.ndarray) -> np.ndarray:
        """The model's Allan variance at ``tau``: the sum of :meth:`parts`.

        Parameters
        ----------
        tau : ndarray, (M,)
            Averaging times, s.

        Returns
        -------
        ndarray, (M,)
        """
        return np.sum(list(self.parts(tau).values()), axis=0)


def log_chi2_moments(edf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation of ln(X / edf) for X chi-square of ``edf`` degrees of freedom.

    An Allan variance estimate is sigma^2 X / edf, so its logarithm is ln sigma^2 plus a term of mean
    psi(edf / 2) - ln(edf / 2) and variance psi'(edf / 2) (digamma and trigamma; Bartlett and Kendall,
    "The statistical analysis of variance-heterogeneity and the logarithmic transformation", JRSS
    Suppl. 8, 1946). For many EDF these are -1/edf and 2/edf; at the 3 to 10 EDF of a curve's last
    points the mean is -0.1 to -0.4: fitted without it, a model sits 5 to 17 % below those points in
    deviation and the curve's end pulls the long-tau terms down.

    Parameters
    ----------
    edf : ndarray
        Equivalent degrees of freedom.

    Returns
    -------
    tuple of ndarray
        (mean, standard deviation), each shaped like ``edf``.
    """
    half = np.asarray(edf, dtype=np.float64) / 2.0
    return special.digamma(half) - np.log(half), np.sqrt(special.polygamma(1, half))


def sinusoid_avar(tau: np.ndarray, freq_hz: float) -> np.ndarray:
    """Allan variance of a unit-amplitude sinusoid, sin^4(pi f tau) / (pi f tau)^2 (IEEE 952, C.7).

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    freq_hz : float
        Its frequency.

    Returns
    -------
    ndarray, (M,)
    """
    x = math.pi * freq_hz * np.asarray(tau, dtype=np.float64)
    return np.sin(x) ** 4 / x**2


def filtered_white_avar(tau: np.ndarray, t_f: float | None, dt: float = 0.0) -> np.ndarray:
    """Allan variance of unit-density white noise through a first-order filter of time constant ``t_f``.

    Sampled every ``dt`` the filter is y_k = p y_{k-1} + (1 - p) w_k, p = exp(-dt / T_f), unity gain at DC
    (a sensor's digital filter); its output is AR(1) of variance s^2 = (1 / dt) (1 - p) / (1 + p), and the
    Allan variance of means of m = tau / dt samples is exactly (from the autocovariance s^2 p^|k|)

        s^2 / m^2 [m + (2 p (m - 1 - m p + p^m) - p (1 - p^m)^2) / (1 - p)^2]

    which tends to 1 / tau for tau >> T_f. ``dt`` 0 or T_f >> dt: the continuous limit g(tau, T_f) / (2 T_f)
    (a Gauss-Markov process of variance 1 / (2 T_f)). ``t_f`` None: 1 / tau.

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    t_f : float or None
        The filter's time constant, s.
    dt : float
        Sample period, s (0: continuous).

    Returns
    -------
    ndarray, (M,)
    """
    tau = np.asarray(tau, dtype=np.float64)
    if t_f is None:
        return 1.0 / tau
    if dt <= 0.0 or dt / t_f < 1e-3:  # the difference below cancels; the continuous form is exact there
        return gauss_markov_avar(tau, t_f) / (2.0 * t_f)
    p = math.exp(-dt / t_f)
    q = 1.0 - p
    m = tau / dt
    pm = p**m
    s2 = q / (1.0 + p) / dt
    return s2 / m**2 * (m + (2.0 * p * (m * q - 1.0 + pm) - p * (1.0 - pm) ** 2) / q**2)


def _shape(name: str, tau: np.ndarray, t_f: float | None, dt: float) -> np.ndarray:
    """Allan variance of IEEE 952 term ``name`` of unit coefficient (C.1), N through the filter if any."""
    if name == "N":
        return filtered_white_avar(tau, t_f, dt)
    return {"Q": 3.0 / tau**2, "B": np.full_like(tau, B_FACTOR**2), "K": tau / 3.0, "R": tau**2 / 2.0}[name]


@dataclass(frozen=True)
class _Combination:
    """The terms of one candidate model."""

    terms: tuple[str, ...]  # IEEE 952 terms, N first
    n_gm: int
    filtered: bool
    n_sin: int
    dt: float = 0.0  # the sample period, for the filter's discrete form

    @property
    def parameters(self) -> int:
        return len(self.terms) + GM_PARAMS * self.n_gm + self.filtered + SIN_PARAMS * self.n_sin


@dataclass
class _Fit:
    combo: _Combination
    x: np.ndarray  # log coefficients, then log T_f, log T_k, log f_j
    chi2: float
    cov: np.ndarray


def _unpack(combo: _Combination, x: np.ndarray) -> tuple[np.ndarray, float | None, np.ndarray, np.ndarray]:
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


def _columns(combo: _Combination, tau: np.ndarray, t_f: float | None, t_gm: Sequence[float],
             freqs: Sequence[float]) -> np.ndarray:
    cols = [_shape(t, tau, t_f, combo.dt) for t in combo.terms]
    cols += [gauss_markov_avar(tau, t) for t in t_gm]
    cols += [sinusoid_avar(tau, f) for f in freqs]
    return np.column_stack(cols)


def _model(combo: _Combination, tau: np.ndarray, x: np.ndarray) -> np.ndarray:
    c, t_f, t_gm, freqs = _unpack(combo, x)
    return _columns(combo, tau, t_f, t_gm, freqs) @ c


@dataclass
class _Curve:
    """The points fitted, with their weights and 68 % interval."""

    tau: np.ndarray
    avar: np.ndarray
    edf: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    rate_hz: float
    filter_reach_s: float | None = None  # where a filtered start falls to FILTER_SLOPE (_filter_reach)

    def part(self, keep: np.ndarray | slice) -> _Curve:
        """The points ``keep`` selects."""
        return _Curve(self.tau[keep], self.avar[keep], self.edf[keep], self.lo[keep], self.hi[keep],
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


def _solve(curve: _Curve, combo: _Combination, x0: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]
           ) -> _Fit:
    """Minimise (1) from ``x0``; the covariance of the log parameters from the Jacobian."""
    mean, sd = log_chi2_moments(curve.edf)
    w = 1.0 / sd
    log_avar = np.log(curve.avar) - mean
    tiny = np.finfo(float).tiny

    n_lin = len(combo.terms) + combo.n_gm + combo.n_sin

    def residuals(x: np.ndarray) -> np.ndarray:
        return w * (log_avar - np.log(np.maximum(_model(combo, curve.tau, x), tiny)))

    def jacobian(x: np.ndarray) -> np.ndarray:
        # d r / d log c_j = -w c_j col_j / model, exactly; the time constants by central differences
        c, t_f, t_gm, freqs = _unpack(combo, x)
        parts = _columns(combo, curve.tau, t_f, t_gm, freqs) * c
        model = np.maximum(parts.sum(axis=1), tiny)
        jac = np.empty((len(curve.tau), len(x)))
        jac[:, :n_lin] = -w[:, None] * parts / model[:, None]
        for k in range(n_lin, len(x)):
            step = np.zeros_like(x)
            step[k] = JAC_STEP
            jac[:, k] = (residuals(x + step) - residuals(x - step)) / (2.0 * JAC_STEP)
        return jac

    x0 = np.clip(x0, bounds[0] + 1e-9, bounds[1] - 1e-9)
    # a term the data does not need shrinks until its Jacobian column is zero; the trust-region's
    # secular equation then divides by zero on its way to the same step (RuntimeWarnings, no harm)
    with np.errstate(divide="ignore", invalid="ignore"):
        sol = optimize.least_squares(residuals, x0, jac=jacobian, bounds=bounds, method="trf", x_scale=1.0,
                                     max_nfev=400)
    chi2 = float(np.sum(sol.fun**2))
    jac = sol.jac
    dof = max(len(curve.tau) - len(sol.x), 1)
    with np.errstate(all="ignore"):
        cov = np.linalg.pinv(jac.T @ jac) * max(chi2 / dof, 1.0)
    return _Fit(combo, sol.x, chi2, cov)


def _bounds(combo: _Combination, curve: _Curve) -> tuple[np.ndarray, np.ndarray]:
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


def _gm_grid(curve: _Curve) -> np.ndarray:
    decades = math.log10(curve.tau[-1] / curve.tau[0])
    return np.geomspace(curve.tau[0], curve.tau[-1], max(int(decades * GM_PER_DECADE) + 1, 2))


def _linear_start(curve: _Curve, combo: _Combination, t_f: float | None, t_gm: Sequence[float],
                  freqs: Sequence[float]) -> np.ndarray:
    """Log coefficients of the EDF-weighted non-negative least squares for fixed time constants; terms
    it zeroes start at a millionth of the curve's scale (a log parameter cannot start at zero)."""
    a = _columns(combo, curve.tau, t_f, t_gm, freqs)
    c, _, _ = _irls(a, curve.avar, curve.edf)
    floor = 1e-6 * float(np.median(curve.avar)) / np.maximum(np.max(a, axis=0), np.finfo(float).tiny)
    return np.log(np.maximum(c, floor))


def _gm_starts(curve: _Curve, terms: tuple[str, ...], t_f: float | None, freqs: Sequence[float]
               ) -> list[float]:
    """Correlation times where a dictionary of Gauss-Markov curves (beside the IEEE terms) puts weight:
    the active entries cluster; each cluster's weighted geometric mean, the largest contribution first."""
    grid = _gm_grid(curve)
    combo = _Combination(terms, len(grid), t_f is not None, len(freqs), 1.0 / curve.rate_hz)
    a = _columns(combo, curve.tau, t_f, grid, freqs)
    c, _, _ = _irls(a, curve.avar, curve.edf)
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


def _padded(times: Sequence[float], n: int, curve: _Curve) -> list[float]:
    """The first ``n`` of ``times``, completed by times spread over the curve, in increasing order."""
    out = [float(t) for t in times[:n]]
    for t in np.geomspace(curve.tau[0] * 3.0, curve.tau[-1] / 3.0, n + 2)[1:-1]:
        if len(out) >= n:
            break
        out.append(float(t))
    return sorted(out)


def _fit_combo(curve: _Curve, combo: _Combination, t_f: float | None, t_gm: Sequence[float],
               freqs: Sequence[float]) -> _Fit:
    """Fit one combination from the given time constants and frequencies (coefficients from the linear
    fit with those held)."""
    x0 = list(_linear_start(curve, combo, t_f, t_gm, freqs))
    if combo.filtered:
        x0.append(math.log(t_f if t_f is not None else curve.filter_start()))
    x0 += [math.log(t) for t in t_gm] + [math.log(f) for f in freqs]
    return _solve(curve, combo, np.array(x0), _bounds(combo, curve))


def _by_weight(fit: _Fit) -> list[float]:
    """The correlation times of a fit's processes, the largest peak first."""
    c, _, t_gm, _ = _unpack(fit.combo, fit.x)
    sig2 = c[len(fit.combo.terms):len(fit.combo.terms) + fit.combo.n_gm]
    return [float(t) for _, t in sorted(zip(sig2, t_gm, strict=True), reverse=True)]


def _fit_best_start(curve: _Curve, combo: _Combination, t_f: float | None, starts: Sequence[Sequence[float]],
                    freqs: Sequence[float]) -> _Fit:
    """Fit ``combo`` from each list of correlation times in ``starts`` (the first ``combo.n_gm`` of each),
    keep the smallest (1)."""
    best: _Fit | None = None
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


def _sinusoid_start(curve: _Curve, base: _Fit) -> float:
    """The frequency whose sinusoid, added to ``base`` (its time constants fixed), fits best."""
    _, t_f, t_gm, freqs = _unpack(base.combo, base.x)
    combo = _Combination(base.combo.terms, base.combo.n_gm, base.combo.filtered, base.combo.n_sin + 1,
                         base.combo.dt)
    best = (math.inf, 1.0)
    lo, hi = 0.25 / curve.tau[-1], curve.rate_hz / 2.0
    for f in np.geomspace(lo, hi, int(SIN_PER_DECADE * math.log10(hi / lo)) + 1):
        a = _columns(combo, curve.tau, t_f, t_gm, [*freqs, f])
        _, _, chi2 = _irls(a, curve.avar, curve.edf, iterations=3)
        if chi2 < best[0]:
            best = (chi2, float(f))
    return best[1]


def _filter_reach(tau: np.ndarray, adev: np.ndarray) -> float | None:
    """Where a curve that starts above slope FILTER_SLOPE (below the white-noise line: a filter or
    decimation) first falls to it; None where it starts below that slope or never falls to it."""
    if len(tau) < 3:
        return None
    slope = np.gradient(np.log10(adev), np.log10(tau))
    below = np.flatnonzero(slope <= FILTER_SLOPE)
    if slope[0] <= FILTER_SLOPE or len(below) == 0:
        return None
    return float(tau[below[0]])


def _estimates(fit: _Fit) -> tuple[list[Estimate], Estimate | None, list[Estimate], list[Estimate]]:
    """Every parameter's value and 1-sigma: coefficients as sqrt (delta method: sd = value sd(log c) / 2),
    time constants and frequencies as themselves (sd = value sd(log))."""
    combo = fit.combo
    sd = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    c, t_f, t_gm, freqs = _unpack(combo, fit.x)
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


def _as_model(fit: _Fit, curve: _Curve, combinations: int) -> NoiseModel:
    combo = fit.combo
    amplitudes, filt, times, freqs = _estimates(fit)
    n_terms = len(combo.terms)
    model = NoiseModel(filter_s=filt, chi2=fit.chi2, parameters=combo.parameters, combinations=combinations,
                       dt_s=combo.dt)
    model.terms = dict(zip(combo.terms, amplitudes[:n_terms], strict=True))
    gms = [GaussMarkov(a, t) for a, t in zip(amplitudes[n_terms:n_terms + combo.n_gm], times, strict=True)]
    model.gauss_markov = sorted(gms, key=lambda g: g.tau_c.value)
    model.sinusoids = [Sinusoid(a, f) for a, f in zip(amplitudes[n_terms + combo.n_gm:], freqs, strict=True)]
    outside = curve.outside(_model(combo, curve.tau, fit.x))
    model.outside = int(np.count_nonzero(outside))
    model.points = len(curve.tau)
    model.describes = model.outside == 0
    model.valid_tau = (float(curve.tau[0]), float(curve.tau[-1]))
    model.method = (f"the simplest of {combinations} combinations that describes the curve (within its 68 % "
                    f"interval or {TOLERANCE:.0%} at every cluster time)" if model.describes else
                    f"of {combinations} combinations, the simplest that no richer one betters by "
                    f"{CHI2_GAIN:g} in (1) per added parameter; it leaves {model.outside} of {model.points} "
                    f"cluster times outside the 68 % interval and {TOLERANCE:.0%}")
    return model


def _outside_count(fit: _Fit, curve: _Curve) -> int:
    return int(np.count_nonzero(curve.outside(_model(fit.combo, curve.tau, fit.x))))


def preferred(candidates: Sequence[tuple[int, int, float]]) -> int:
    """Index of the model to report among candidates given as (points outside, parameters, (1)).

    Where models describe the curve (no point outside), the simplest of them (the smallest (1) among
    equals): the goodness-of-fit test the issue of the method states, and what a filter downstream needs
    (a model inside the band everywhere it claims to hold). Where none does, the reference is the one
    leaving fewest points outside (the smallest (1) among equals), and a simpler model is preferred to it
    unless the reference lowers (1) by CHI2_GAIN or more per added parameter; one with as many parameters
    never is: then no model passes the test, and the points left outside are read as scatter unless a
    richer model earns its parameters in (1).

    Parameters
    ----------
    candidates : sequence of (int, int, float)
        Per model: cluster times outside the 68 % interval and the tolerance, parameters, (1).

    Returns
    -------
    int
    """
    order = range(len(candidates))
    describing = [i for i in order if candidates[i][0] == 0]
    if describing:
        return min(describing, key=lambda i: (candidates[i][1], candidates[i][2]))
    ref = min(order, key=lambda i: (candidates[i][0], candidates[i][2]))
    _, p_ref, chi2_ref = candidates[ref]
    eligible = [ref] + [i for i in order if candidates[i][1] < p_ref
                        and candidates[i][2] <= chi2_ref + CHI2_GAIN * (p_ref - candidates[i][1])]
    return min(eligible, key=lambda i: (candidates[i][1], candidates[i][2]))


def _fit_all(curve: _Curve, filtered: bool) -> list[_Fit]:
    """Fit every admissible combination: sinusoids first, added to the fullest model while it does not
    describe the curve and each one removes points outside and lowers (1) by SIN_GAIN; then every subset
    of the optional terms with zero to MAX_GM processes, beside those sinusoids.

    Each combination starts from two sets of correlation times: the dictionary's clusters and the
    fullest model's processes, the largest first (either alone misses a process now and then)."""
    full_terms = ("N", *OPTIONAL)
    t_f = curve.filter_start() if filtered else None
    dt = 1.0 / curve.rate_hz
    full_combo = _Combination(full_terms, MAX_GM, filtered, 0, dt)
    full = _fit_best_start(curve, full_combo, t_f, [_gm_starts(curve, full_terms, t_f, [])], [])
    fits = [full]
    while full.combo.n_sin < MAX_SINUSOIDS:
        before = _outside_count(full, curve)
        if before == 0:
            break
        _, t_f_full, _, freqs_full = _unpack(full.combo, full.x)
        trial_freqs = [*(float(f) for f in freqs_full), _sinusoid_start(curve, full)]
        combo = _Combination(full_terms, MAX_GM, filtered, len(trial_freqs), dt)
        trial = _fit_best_start(curve, combo, t_f_full,
                                [_by_weight(full), _gm_starts(curve, full_terms, t_f_full, trial_freqs)],
                                trial_freqs)
        if _outside_count(trial, curve) >= before or full.chi2 - trial.chi2 < SIN_GAIN:
            break
        full = trial
        fits = [full]
    _, t_f, _, freqs_arr = _unpack(full.combo, full.x)
    freqs = [float(f) for f in freqs_arr]
    from_full = _by_weight(full)
    for k in range(len(OPTIONAL) + 1):
        for extra in itertools.combinations(OPTIONAL, k):
            terms = ("N", *extra)
            starts = [_gm_starts(curve, terms, t_f, freqs), from_full]
            for n_gm in range(MAX_GM + 1):
                combo = _Combination(terms, n_gm, filtered, len(freqs), dt)
                if combo != full.combo:
                    fits.append(_fit_best_start(curve, combo, t_f, starts, freqs))
    return fits


def _select(curve: _Curve, filtered: bool) -> tuple[_Fit, int]:
    """The preferred fit (:func:`preferred`) of every admissible combination, and how many were fitted."""
    fits = _fit_all(curve, filtered)
    best = preferred([(_outside_count(f, curve), f.combo.parameters, f.chi2) for f in fits])
    return fits[best], len(fits)


def select_model(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, ci_low: np.ndarray,
                 ci_high: np.ndarray, rate_hz: float) -> NoiseModel:
    """The simplest model of (C.1) + Gauss-Markov + filter + sinusoids that describes one axis's curve.

    Where the curve starts bending below the white-noise line (slope above FILTER_SLOPE), the white noise
    is fitted through a first-order filter; leading points that model still leaves outside are left out
    (up to SHORTEST_VALID s), and the fit repeated: ``valid_tau`` starts at the first point kept and ends
    at the last cluster time.

    Parameters
    ----------
    tau, adev, edf : ndarray, (M,)
        The curve: averaging times (s), Allan deviations, equivalent degrees of freedom.
    ci_low, ci_high : ndarray, (M,)
        Its 68 % interval.
    rate_hz : float
        Sample rate (the highest sinusoid frequency is its Nyquist frequency).

    Returns
    -------
    NoiseModel
    """
    curve = _curve_of(tau, adev, edf, ci_low, ci_high, rate_hz)
    curve.filter_reach_s = _filter_reach(curve.tau, np.sqrt(curve.avar))
    filtered = curve.filter_reach_s is not None
    total = 0
    while True:
        best, fitted = _select(curve, filtered)
        total += fitted
        outside = curve.outside(_model(best.combo, curve.tau, best.x))
        lead = 0
        while lead < len(outside) and outside[lead] and curve.tau[lead] < SHORTEST_VALID:
            lead += 1
        if not filtered or lead == 0 or len(curve.tau) - lead < 8:
            break
        curve = curve.part(slice(lead, None))
    return _as_model(best, curve, total)


def _curve_of(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, ci_low: np.ndarray, ci_high: np.ndarray,
              rate_hz: float) -> _Curve:
    tau = np.asarray(tau, dtype=np.float64)
    adev = np.asarray(adev, dtype=np.float64)
    edf = np.asarray(edf, dtype=np.float64)
    ok = np.isfinite(adev) & (adev > 0) & np.isfinite(edf) & (edf > 0)
    return _Curve(tau[ok], adev[ok] ** 2, edf[ok], np.asarray(ci_low, dtype=np.float64)[ok],
                  np.asarray(ci_high, dtype=np.float64)[ok], float(rate_hz))


def ieee_model(axis: AxisNoise, tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, ci_low: np.ndarray,
               ci_high: np.ndarray, rate_hz: float) -> NoiseModel:
    """The IEEE 952 fit of ``axis`` (its fitted terms and Gauss-Markov bias) as a :class:`NoiseModel`,
    checked against the curve from its first fitted cluster time on.

    Parameters
    ----------
    axis : AxisNoise
        The fit (:func:`station.engines.allan.fit.fit_axis`).
    tau, adev, edf, ci_low, ci_high : ndarray, (M,)
        The curve it was fitted to, with its 68 % interval.
    rate_hz : float
        Sample rate.

    Returns
    -------
    NoiseModel
    """
    curve = _curve_of(tau, adev, edf, ci_low, ci_high, rate_hz)
    curve = curve.part(curve.tau >= (axis.fitted_from_tau or curve.tau[0]))
    model = NoiseModel(method="IEEE 952 fit", combinations=1)
    for term, value in axis.coeffs.items():
        est = axis.terms[term]
        model.terms[term] = Estimate(value, est.stddev if est.value == value else None)
    if axis.gauss_markov is not None:
        (sigma, tau_c), (sd_sigma, sd_tau_c) = axis.gauss_markov, axis.gauss_markov_stddev
        model.gauss_markov = [GaussMarkov(Estimate(sigma, sd_sigma), Estimate(tau_c, sd_tau_c))]
    model.parameters = len(model.terms) + GM_PARAMS * len(model.gauss_markov)
    outside = curve.outside(model.avar(curve.tau))
    model.outside = int(np.count_nonzero(outside))
    model.points = len(curve.tau)
    model.describes = model.outside == 0
    model.chi2 = curve.chi2(model.avar(curve.tau))
    model.valid_tau = (float(curve.tau[0]), float(curve.tau[-1]))
    return model


def choose_model(axis: AxisNoise, tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, ci_low: np.ndarray,
                 ci_high: np.ndarray, rate_hz: float) -> None:
    """Keep the IEEE 952 fit of ``axis`` where it describes its curve, else report the selected model.

    The IEEE fit is tried first because its terms are what navigation filters take, and on records of
    white noise, random walk and the other IEEE terms it is the better estimator (K from the exact
    likelihood, at the Cramer-Rao bound). Where it leaves cluster times outside the band, or leaves out
    the first ones (a sensor's filter, :func:`station.engines.allan.fit._filter_settled`), every admissible
    combination is fitted (:func:`select_model`); the chosen one replaces the IEEE fit only where the
    fit misses the curve grossly over the chosen model's valid range: (1) above KEEP_REDUCED_CHI2 per
    point. On records of white noise and random walk the fit's (1) is near 0.7 per point and a richer
    model only follows the correlated scatter of the points (lowering (1) by 2 to 23 on 50 points); on
    the ADIS16405 records the fit's is 1,700 to 7,000 per point (the filter, sinusoids, humps). The chosen
    model's terms then replace the fit's in ``axis.terms`` (method "model selection"; terms it does not
    need are null, with the reason) and ``axis.noise_model`` holds it, Gauss-Markov processes and valid
    range included.

    Parameters
    ----------
    axis : AxisNoise
        The axis's IEEE 952 fit, updated in place.
    tau, adev, edf, ci_low, ci_high : ndarray, (M,)
        Its curve and 68 % interval.
    rate_hz : float
        Sample rate.
    """
    kept = ieee_model(axis, tau, adev, edf, ci_low, ci_high, rate_hz)
    axis.noise_model = kept
    if kept.describes and axis.fitted_from_tau is None:  # the whole curve: nothing left out for a filter
        return
    curve = _curve_of(tau, adev, edf, ci_low, ci_high, rate_hz)
    # Whatever model is chosen, its valid range keeps every cluster time from SHORTEST_VALID on, and (1) only
    # grows with points: a fit within KEEP_REDUCED_CHI2 per point of those over the whole curve stands on any
    # such range, so the hundreds of fits of the selection would not change the answer.
    always_kept = np.count_nonzero(curve.tau >= SHORTEST_VALID)
    if axis.fitted_from_tau is None and curve.chi2(kept.avar(curve.tau)) <= KEEP_REDUCED_CHI2 * always_kept:
        return
    chosen = select_model(tau, adev, edf, ci_low, ci_high, rate_hz)
    on = (curve.tau >= chosen.valid_tau[0]) & (curve.tau <= chosen.valid_tau[1])
    curve = curve.part(on)
    kept_chi2 = curve.chi2(kept.avar(curve.tau))
    if kept_chi2 <= KEEP_REDUCED_CHI2 * len(curve.tau):
        return
    axis.noise_model = chosen
    _report(axis, chosen)


def _report(axis: AxisNoise, model: NoiseModel) -> None:
    """Write the chosen model's IEEE terms into ``axis.terms`` (slope readings kept; ``fitted_from_tau``
    stays the IEEE fit's, the model's own range is ``model.valid_tau``)."""
    how = f"model selection ({model.describe()}): {model.method}"
    for term in TERMS:
        old = axis.terms.get(term) or TermEstimate()
        est = TermEstimate(slope_line_at_1s=old.slope_line_at_1s, slope_value=old.slope_value,
                           slope_tau=old.slope_tau, slope_reason=old.slope_reason)
        if term in model.terms:
            est.value, est.stddev, est.method = model.terms[term].value, model.terms[term].stddev, how
        else:
            est.reason = f"not needed: the chosen model ({model.describe()}) describes the curve without it"
        axis.terms[term] = est
    axis.fitted = tuple(model.terms)
    axis.coeffs = {t: e.value for t, e in model.terms.items()}
    axis.gauss_markov = None
    axis.gauss_markov_stddev = (None, None)
    axis.reduced_chi2 = model.chi2 / max(model.points - model.parameters, 1)
    n_val, k_val = axis.coeffs.get("N"), axis.coeffs.get("K")
    axis.crossing_tau_nk = math.sqrt(3.0) * n_val / k_val if n_val and k_val else None
    axis.k_needed_s = None
