"""Noise terms of an Allan deviation curve on the IEEE Std 952-1997 (Annex C) model.

    sigma^2(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2      (C.1)

Q quantization (unit s), N white noise / angle or velocity random walk (unit/sqrt(Hz)), B bias instability
(unit; the flat floor is 0.66428 B, 0.66428 = sqrt(2 ln 2 / pi)), K rate random walk (unit sqrt(Hz)/s =
unit/s/sqrt(Hz)), R rate ramp (unit/s).

The model is linear in c = (Q^2, N^2, B^2, K^2, R^2), so it is fitted by non-negative least squares with
weights from the equivalent degrees of freedom: var(sigma_hat^2) = 2 sigma^4 / edf, re-weighted with the
model's own values (iteratively re-weighted least squares). N and K are always fitted; Q, B and R are added
only where the record shows them: significant (> 3 standard deviations), improving the weighted
chi-square by more than 9, and dominating the model at three or more well-measured points (backward
elimination from the full model). Quantization that dominates fewer points but makes a fifth or more of
the first point stays in the model (else its excess goes into N), reported null with its modelled value.
K is null when its line crosses the white-noise line beyond T/20.

A sensor's low-pass filter makes the curve start flat or rising before it falls into the white-noise
line; those points are left out of the fit (see :func:`_filter_settled`, ``AxisNoise.fitted_from_tau``).

A correlated (first-order Gauss-Markov) bias draws a hump: the curve rises, peaks near 1.9 correlation
times and falls again, which no term of (C.1) can draw. Where the curve visibly falls again after rising
at well-measured points, N, K and a Gauss-Markov term (sigma, T_c) are fitted instead; when that beats
the IEEE fit by the same chi-square margin, B is the peak of the Gauss-Markov curve divided by 0.66428
(the convention that makes a flicker floor and a Gauss-Markov peak the same B), K is kept only if still
significant, and the report says which method gave each term. Where the curve leaves the white-noise
line and never visibly falls, the same is tried with correlation times from there on, and taken only
where the bias explains the whole rise (see :func:`_fit_with_gauss_markov`).

Beside the fit, the classic slope-line reading (IEEE 952 Annex C; e.g. El-Sheimy, Hou and Niu, "Analysis
and modeling of inertial sensors using Allan variance", IEEE TIM 57(1), 2008): where the curve's
log-log slope is -1, -1/2, 0, +1/2, +1, the straight line of that slope through the curve, read at
tau = 1 s, and the term it gives (Q at tau = sqrt(3), N at 1, B = floor / 0.66428, K at 3, R at sqrt(2)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy import optimize

from station.engines.allan.deviation import AllanCurve
from station.engines.allan.likelihood import block_length, white_walk_ml
from station.engines.allan.terms import TERMS
from station.errors import EngineInputError

if TYPE_CHECKING:
    from station.engines.allan.model import NoiseModel

B_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.66428
ALPHA_OF_TERM = {"Q": 2, "N": 0, "B": -1, "K": -2, "R": -2}
SLOPE_OF_TERM = {"Q": -1.0, "N": -0.5, "B": 0.0, "K": 0.5, "R": 1.0}
# tau where the slope line equals the term:
# sigma = sqrt(3) Q / tau, N / sqrt(tau), K sqrt(tau / 3), R tau / sqrt(2)
READ_TAU = {"Q": math.sqrt(3.0), "N": 1.0, "K": 3.0, "R": math.sqrt(2.0)}
SLOPE_TOLERANCE = 0.1
SIGNIFICANCE = 3.0
CHI2_GAIN = 9.0
MIN_DOMINANT_POINTS = 3
OPTIONAL = ("Q", "B", "R")
MODELLED_UNSHOWN = ("Q",)  # kept in the fit where significant and material, reported only where shown
MODELLED_SHARE = 0.2  # material: this share of the Allan variance at the shortest tau or more
K_CROSSING_FRACTION = 20.0  # K needs the N and K lines to cross before T / 20
MIN_EDF_SHOWN = 10.0  # points that count as showing a term or a floor
HUMP_RISE = 0.1
HUMP_FALL = -0.1
DEPARTURE_SLOPE = -0.3  # the curve has left the white-noise line (slope -1/2) upward
UNRESOLVED_PEAK_MARGIN = 4.0  # an unresolved Gauss-Markov bias must peak this factor before the last tau
FILTER_SLOPE = -0.45  # a curve starting above this slope starts with a sensor's filter, not a noise term
FILTER_MARGIN = 3.0  # the fit starts this factor in tau after the filtered start reaches FILTER_SLOPE
ML_AGREEMENT = 1.15  # the likelihood's K replaces the curve fit's only within this factor of it
ML_METHOD = "exact Gaussian maximum likelihood"


def basis(tau: np.ndarray) -> np.ndarray:
    """Columns of eq. (C.1) for c = (Q^2, N^2, B^2, K^2, R^2): shape (len(tau), 5).

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.

    Returns
    -------
    ndarray, (M, 5)
    """
    tau = np.asarray(tau, dtype=np.float64)
    return np.column_stack([3.0 / tau**2, 1.0 / tau, np.full_like(tau, B_FACTOR**2), tau / 3.0, tau**2 / 2.0])


def model_avar(tau: np.ndarray, coeffs: dict[str, float | None]) -> np.ndarray:
    """Allan variance of eq. (C.1) for the terms given (None or missing terms count as zero).

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    coeffs : dict of str to float or None
        Q, N, B, K, R in their units.

    Returns
    -------
    ndarray, (M,)
    """
    c = np.array([(coeffs.get(t) or 0.0) ** 2 for t in TERMS])
    return basis(tau) @ c


@dataclass
class TermEstimate:
    """One noise term of one axis: the fitted value and its 1-sigma, or None with the reason.

    ``slope_line_at_1s`` is the slope line's value at tau = 1 s, ``slope_value`` the term it gives;
    ``slope_reason`` says why there is none. Where the maximum-likelihood estimate gave ``value``
    (``method`` starts with ML_METHOD), ``adev_value`` and ``adev_stddev`` keep the IEEE 952 fit's.
    """

    value: float | None = None
    stddev: float | None = None
    reason: str | None = None
    method: str | None = None
    adev_value: float | None = None  # the IEEE 952 fit's value where another method gave ``value``
    adev_stddev: float | None = None
    slope_line_at_1s: float | None = None
    slope_value: float | None = None
    slope_tau: float | None = None
    slope_reason: str | None = None


@dataclass
class AxisNoise:
    """The noise terms of one axis and the fit that gave them."""

    axis: str
    terms: dict[str, TermEstimate] = field(default_factory=dict)
    fitted: tuple[str, ...] = ()
    coeffs: dict[str, float] = field(default_factory=dict)  # all fitted terms, shown or not
    reduced_chi2: float = float("nan")
    crossing_tau_nk: float | None = None
    gauss_markov: tuple[float, float] | None = None  # (sigma, correlation time s) where a hump was fitted
    gauss_markov_stddev: tuple[float | None, float | None] = (None, None)  # their 1-sigma
    fitted_from_tau: float | None = None  # first tau fitted after a sensor filter
    k_needed_s: float | None = None  # record length that could show K, where K is not shown (a lower bound)
    noise_model: NoiseModel | None = None  # the model reported and drawn (model.choose_model)

    def value(self, term: str) -> float | None:
        """The estimate of noise term ``term`` (N, B, K, ...) in its own unit, or None if not resolved.

        Parameters
        ----------
        term : str
            A key of ``TERMS``.

        Returns
        -------
        float or None
        """
        return self.terms[term].value

    def model(self, tau: np.ndarray) -> np.ndarray:
        """Allan deviation of the fitted model (every fitted term, and the Gauss-Markov bias if any).

        Parameters
        ----------
        tau : ndarray, (M,)
            Averaging times, s.

        Returns
        -------
        ndarray, (M,)
        """
        if self.noise_model is not None:
            return np.sqrt(self.noise_model.avar(np.asarray(tau, dtype=np.float64)))
        avar = model_avar(tau, self.coeffs)
        if self.gauss_markov is not None:
            sigma, tau_c = self.gauss_markov
            avar = avar + sigma**2 * gauss_markov_avar(tau, tau_c)
        return np.sqrt(avar)


def gauss_markov_avar(tau: np.ndarray, tau_c: float) -> np.ndarray:
    """Allan variance of a first-order Gauss-Markov process of unit variance and correlation time T_c.

    sigma^2(tau) = 2 (T_c / tau) [1 - (T_c / 2 tau) (3 - 4 e^(-x) + e^(-2x))], x = tau / T_c (e.g. El-Sheimy
    et al. 2008, eq. 21 with q_c = 2 / T_c); the bracket is 2u + u^2 over 2x with u = 1 - e^(-x), and its
    series x^2/3 - x^3/4 below x = 1e-3 where the difference would cancel.

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    tau_c : float
        Correlation time T_c, s.

    Returns
    -------
    ndarray, (M,)
    """
    x = np.asarray(tau, dtype=np.float64) / tau_c
    u = -np.expm1(-x)
    with np.errstate(divide="ignore", invalid="ignore"):
        bracket = np.where(x < 1e-3, x**2 / 3.0 - x**3 / 4.0, 1.0 - (2.0 * u + u * u) / (2.0 * x))
    return 2.0 * bracket / x


_X = np.geomspace(1e-2, 1e2, 4001)
GM_ADEV_PEAK = float(np.sqrt(gauss_markov_avar(_X, 1.0).max()))  # peak Allan deviation / sigma, ~0.62
GM_PEAK_X = float(_X[np.argmax(gauss_markov_avar(_X, 1.0))])  # the peak's tau / T_c, ~1.89


def _irls(a: np.ndarray, avar: np.ndarray, edf: np.ndarray, iterations: int = 6
          ) -> tuple[np.ndarray, np.ndarray, float]:
    """EDF-weighted non-negative least squares of ``a c = avar``; returns (c, covariance, chi2)."""
    scale = np.max(np.abs(a), axis=0)  # columns span many decades: normalise before NNLS
    an = a / scale
    model = avar.copy()
    c = np.zeros(a.shape[1])
    for _ in range(iterations):
        w = np.sqrt(edf / 2.0) / np.maximum(model, np.finfo(float).tiny)
        cn, _ = optimize.nnls(an * w[:, None], avar * w, maxiter=50 * a.shape[1])
        c = cn / scale
        new_model = a @ c
        if np.allclose(new_model, model, rtol=1e-9, atol=0.0):  # variances are tiny: no absolute floor
            break
        model = np.where(new_model > 0, new_model, avar)
    w2 = (edf / 2.0) / np.maximum(model, np.finfo(float).tiny) ** 2
    chi2 = float(np.sum(w2 * (avar - model) ** 2))
    active = c > 0
    cov = np.full((a.shape[1], a.shape[1]), np.nan)
    if active.any():
        aa = an[:, active]  # normalised columns keep the Fisher matrix well conditioned
        fisher = aa.T @ (aa * w2[:, None])
        with np.errstate(all="ignore"):
            cov_active = np.linalg.pinv(fisher) / np.outer(scale[active], scale[active])
        cov[np.ix_(active, active)] = cov_active
    return c, cov, chi2


def _fit(tau: np.ndarray, avar: np.ndarray, edf: np.ndarray, terms: tuple[str, ...]
         ) -> tuple[dict[str, float], dict[str, float], float]:
    cols = [TERMS.index(t) for t in terms]
    c, cov, chi2 = _irls(basis(tau)[:, cols], avar, edf)
    dof = max(len(tau) - int(np.count_nonzero(c)), 1)
    inflate = max(chi2 / dof, 1.0)  # correlated, overlapping points: trust the scatter if it is larger
    values = {t: float(c[i]) for i, t in enumerate(terms)}
    var = {t: max(float(cov[i, i]), 0.0) * inflate for i, t in enumerate(terms)}
    return values, var, chi2


def _first_share(tau: np.ndarray, c: dict[str, float], term: str) -> float:
    """Share of ``term`` in the fitted Allan variance at the shortest tau."""
    parts = {t: basis(tau[:1])[0, TERMS.index(t)] * c[t] for t in c}
    total = sum(parts.values())
    return parts[term] / total if total > 0 else 0.0


def _shows(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, c: dict[str, float], term: str) -> bool:
    """Whether the curve shows an optional term: it dominates the model at MIN_DOMINANT_POINTS or more
    well-measured points (EDF >= 10) spanning a factor of 3 in tau or more, and the curve itself reaches
    the term's slope there. The few-EDF tail of a random walk often looks like a ramp or a floor."""
    parts = {t: basis(tau)[:, TERMS.index(t)] * c[t] for t in c}
    total = sum(parts.values())
    where = np.flatnonzero((parts[term] > 0.5 * total) & (edf >= MIN_EDF_SHOWN))
    if len(where) < MIN_DOMINANT_POINTS or tau[where[-1]] < 3.0 * tau[where[0]]:
        return False
    slope = np.gradient(np.log10(adev), np.log10(tau))
    return bool(np.any(np.abs(slope[where] - SLOPE_OF_TERM[term]) <= SLOPE_TOLERANCE))


def _slope_reading(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, term: str, est: TermEstimate) -> None:
    """The slope-line reading of IEEE 952 Annex C, written into ``est``."""
    target = SLOPE_OF_TERM[term]
    logt = np.log10(tau)
    loga = np.log10(adev)
    slope = np.gradient(loga, logt)
    if term == "B":
        # the minimum of a few-EDF point is biased low: only read the floor where it is measured well
        flat = np.flatnonzero((np.abs(slope) <= SLOPE_TOLERANCE) & (edf >= MIN_EDF_SHOWN))
        if len(flat) == 0:
            est.slope_reason = "the curve has no flat part (slope 0) with 10 or more degrees of freedom"
            return
        i = int(flat[np.argmin(adev[flat])])
        est.slope_tau = float(tau[i])
        est.slope_line_at_1s = float(adev[i])
        est.slope_value = float(adev[i] / B_FACTOR)
        return
    i = int(np.argmin(np.abs(slope - target)))
    if abs(slope[i] - target) > SLOPE_TOLERANCE:
        est.slope_reason = (f"the curve never has slope {target:+g} (closest {slope[i]:+.2f} at tau = "
                            f"{tau[i]:.3g} s)")
        return
    b = loga[i] - target * logt[i]
    est.slope_tau = float(tau[i])
    est.slope_line_at_1s = float(10.0**b)
    est.slope_value = float(10.0 ** (b + target * math.log10(READ_TAU[term])))


def _filter_settled(tau: np.ndarray, adev: np.ndarray) -> int:
    """Index of the first point the fit uses: 0, unless the curve starts above slope FILTER_SLOPE (flat or
    rising, then falling into the white-noise line): a sensor's low-pass filter. Its output is a
    Gauss-Markov process of correlation time T_f whose Allan variance, for tau >> T_f, is
    N^2 / tau (1 - 3 T_f / (2 tau)) (El-Sheimy et al. 2008, eq. 21, expanded), of slope
    -1/2 + 3 T_f / (4 tau) in deviation. The slope reaches FILTER_SLOPE near tau = 15 T_f, 10 % below
    N^2 / tau; the fit starts FILTER_MARGIN times later (3 %). No IEEE 952 term draws this start, and its
    many-EDF points outweigh the rest of the curve (N null and a spurious B under a 6.7 Hz first-order
    filter at 400 Hz, benchmarks/allan_sweep.py)."""
    slope = np.gradient(np.log10(adev), np.log10(tau)) if len(tau) > 1 else np.array([-0.5])
    if slope[0] <= FILTER_SLOPE:
        return 0
    below = np.flatnonzero(slope <= FILTER_SLOPE)
    if len(below) == 0:
        return 0
    return int(np.searchsorted(tau, FILTER_MARGIN * tau[below[0]]))


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


def fit_axis(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray, duration_s: float,
             axis: str = "") -> AxisNoise:
    """Noise terms of one axis from its Allan deviation curve, eq. (C.1).

    Parameters
    ----------
    tau, adev, edf : ndarray
        The curve: averaging times (s), Allan deviations, equivalent degrees of freedom.
    duration_s : float
        Length T of the record; K is reported only where the white-noise and random-walk lines cross
        before T / 20.
    axis : str
        Name of the axis, for the report.

    Returns
    -------
    AxisNoise
        Every term of ``TERMS`` with value and 1-sigma, or None and the reason.
    """
    tau = np.asarray(tau, dtype=np.float64)
    adev = np.asarray(adev, dtype=np.float64)
    edf = np.asarray(edf, dtype=np.float64)
    ok = np.isfinite(adev) & (adev > 0) & np.isfinite(edf) & (edf > 0)
    tau, adev, edf = tau[ok], adev[ok], edf[ok]
    start = _filter_settled(tau, adev)
    settled_tau = float(tau[start]) if start else None
    tau, adev, edf = tau[start:], adev[start:], edf[start:]
    avar = adev**2
    # Backward elimination: start from the whole model, drop the weakest optional term that the record
    # does not show until every optional term left is significant, shown, and worth its chi-square.
    active: tuple[str, ...] = TERMS
    values, var, chi2 = _fit(tau, avar, edf, active)
    while True:
        weakest = None
        for extra in OPTIONAL:
            if extra not in active:
                continue
            c, sd = values[extra], math.sqrt(var[extra]) if np.isfinite(var[extra]) else math.inf
            without = tuple(t for t in active if t != extra)
            # quantization stays in the model where it is significant, worth its chi-square and a fifth of
            # the first point even if it dominates too few points to be reported: dropped, its excess at
            # the first, many-EDF points goes into N (+26 % where the Q and N lines cross at 1.5 samples,
            # benchmarks/allan_sweep.py). Below a fifth it is the first points' correlated scatter: white
            # noise alone shows a "significant" Q of 0.6 % of the first point in 3 of 20 records.
            material = extra in MODELLED_UNSHOWN and _first_share(tau, values, extra) >= MODELLED_SHARE
            keep = (c > 0 and c >= SIGNIFICANCE * sd and (material or _shows(tau, adev, edf, values, extra))
                    and _fit(tau, avar, edf, without)[2] - chi2 >= CHI2_GAIN)
            score = c / sd if c > 0 else 0.0
            if not keep and (weakest is None or score < weakest[1]):
                weakest = (without, score)
        if weakest is None:
            break
        active = weakest[0]
        values, var, chi2 = _fit(tau, avar, edf, active)
    result = AxisNoise(axis=axis, fitted=active, reduced_chi2=chi2 / max(len(tau) - len(active), 1),
                       fitted_from_tau=settled_tau)
    result.coeffs = {t: math.sqrt(values[t]) for t in active if values[t] > 0}
    for term in TERMS:
        est = TermEstimate()
        if term not in active:
            est.reason = {"Q": "quantization is not visible: no slope -1 region above the white noise",
                          "B": "no flat floor: bias instability is hidden by white noise and random walk",
                          "R": "no slope +1 region: rate ramp is not visible in this record"}[term]
        else:
            c = values[term]
            sd_c = math.sqrt(var[term]) if np.isfinite(var[term]) else float("nan")
            if c <= 0:
                est.reason = "the fit gives zero: the record does not show this term"
            elif not c >= SIGNIFICANCE * sd_c:
                est.reason = (f"not significant: {math.sqrt(c):.3g} with a 1-sigma of the variance term of "
                              f"{sd_c / c:.0%}")
            elif term in MODELLED_UNSHOWN and not _shows(tau, adev, edf, values, term):
                est.reason = (f"modelled ({math.sqrt(c):.3g}) but not shown: it dominates fewer than "
                              f"{MIN_DOMINANT_POINTS} points at the shortest tau; a faster rate shows it")
            else:
                est.value = math.sqrt(c)
                est.stddev = sd_c / (2.0 * est.value)  # delta method: d sqrt(c) = dc / (2 sqrt(c))
                est.method = "IEEE 952 fit"
        _slope_reading(tau, adev, edf, term, est)
        result.terms[term] = est
    if result.terms["B"].value is None:
        if _hump_top(tau, adev, edf) is not None:
            values = _fit_with_gauss_markov(tau, adev, edf, result, values, chi2, float(tau[0]), False)
        else:
            departure = _departure_tau(tau, adev, edf)
            if departure is not None:
                values = _fit_with_gauss_markov(tau, adev, edf, result, values, chi2, departure / GM_PEAK_X,
                                                True)
        if result.gauss_markov is not None:
            result.gauss_markov_stddev = _at_least_record_bound(result.gauss_markov,
                                                                result.gauss_markov_stddev, duration_s)
    n_val = values.get("N", 0.0)
    k_val = values.get("K", 0.0)
    if n_val > 0 and k_val > 0:
        result.crossing_tau_nk = math.sqrt(3.0) * math.sqrt(n_val) / math.sqrt(k_val)  # N^2/tau = K^2 tau / 3
    k_est = result.terms["K"]
    if k_est.value is not None and result.crossing_tau_nk is not None:
        limit = duration_s / K_CROSSING_FRACTION
        if result.crossing_tau_nk > limit:
            k_est.reason = (f"record too short: the white-noise and random-walk lines cross at tau = "
                            f"{result.crossing_tau_nk:.3g} s, beyond T/20 = {limit:.3g} s; record at least "
                            f"{K_CROSSING_FRACTION * result.crossing_tau_nk / 3600:.2g} h still")
            k_est.value = None
            k_est.stddev = None
    if k_est.value is None and n_val > 0 and np.isfinite(var["K"]):
        # the largest K this record allows (its estimate where significant, else 2-sigma above it) puts
        # the crossing with N, hence the length that would show K, no earlier than this
        c_k, sd_k = values.get("K", 0.0), math.sqrt(var["K"])
        bound = c_k if c_k >= SIGNIFICANCE * sd_k else max(c_k, 0.0) + 2.0 * sd_k
        if bound > 0:
            result.k_needed_s = K_CROSSING_FRACTION * math.sqrt(3.0 * n_val / bound)
    return result


@dataclass(frozen=True)
class MissingTerm:
    """A noise term asked for that an axis's record does not resolve."""

    axis: str
    term: str
    reason: str
    needed_s: float | None  # record length that could resolve it, where one can be told


def missing_terms(noise: Sequence[AxisNoise], terms: Sequence[str], duration_s: float) -> list[MissingTerm]:
    """The terms of ``terms`` that some axis leaves null, with why and the record length they need.

    Parameters
    ----------
    noise : sequence of AxisNoise
        Every axis's fit (:func:`identify_noise`).
    terms : sequence of str
        The terms asked for (keys of ``TERMS``).
    duration_s : float
        Length of the record, s.

    Returns
    -------
    list of MissingTerm
        Empty when every axis resolves every term asked for. K's length is the one at which its
        line would cross the white noise's before T/20; the other terms give none but "longer".
    """
    out = []
    for axis in noise:
        for term in terms:
            est = axis.terms[term]
            if est.value is not None:
                continue
            needed = axis.k_needed_s if term == "K" else None
            if needed is not None and needed <= duration_s:
                needed = None  # the bound says nothing this record did not
            out.append(MissingTerm(axis.axis, term, est.reason or "not resolved", needed))
    return out


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
        c, cov, chi2 = _irls(a, avar, edf)
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


def dominant_alpha(tau: np.ndarray, noise: AxisNoise) -> np.ndarray:
    """Power-law noise type of the model term that dominates at each tau (for Greenhall's EDF).

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    noise : AxisNoise
        The axis's fit.

    Returns
    -------
    ndarray of int, (M,)
        alpha per point (0, white rate, without a fit).
    """
    if not noise.coeffs:
        return np.zeros(len(tau), dtype=np.int64)
    names = list(noise.coeffs)
    parts = [basis(tau)[:, TERMS.index(t)] * noise.coeffs[t] ** 2 for t in names]
    alphas = [ALPHA_OF_TERM[t] for t in names]
    if noise.gauss_markov is not None:  # flat-topped like flicker where it dominates
        parts.append(noise.gauss_markov[0] ** 2 * gauss_markov_avar(tau, noise.gauss_markov[1]))
        alphas.append(-1)
    return np.array([alphas[i] for i in np.argmax(np.column_stack(parts), axis=1)], dtype=np.int64)


def use_white_walk_ml(noise: AxisNoise, phase: np.ndarray, rate_hz: float) -> None:
    """Take K of an axis from its exact likelihood where the curve shows only white noise and random walk.

    Where the IEEE 952 fit keeps N and K alone (no Q, B, R, no Gauss-Markov hump) and shows K, the
    record is white noise plus a random walk, the model of
    :func:`station.engines.allan.likelihood.white_walk_ml`,
    whose likelihood uses all the record says about K: on 2 h records its scatter of log K is within
    8 % of the Cramer-Rao bound (0.181 against 0.168), where the curve's few correlated points at long
    tau do worse (median error 11 % against 15 %, see the README). K is then the
    likelihood's value (whether the record shows K at all stays the fit's decision, T/20 rule
    included); the fit's K stays beside, in ``adev_value``. N stays the fit's: the curve's short-tau
    points measure it better than block means. Anywhere else (other terms shown, K null, the
    likelihood's optimum at an end of its search) the fit stands, and where the two K differ by more
    than ML_AGREEMENT. On white noise plus random walk the two differ by 7 % (1-sigma, Monte Carlo, 2 h
    records); a Gauss-Markov bias that the curve does not resolve (its hump hidden under the random
    walk's rise) raises both, the likelihood's more (1.0x to 1.9x the fit's on the mocks' 100 s bias): a
    larger gap keeps the fit's value, so such a record's K moves by 15 % at most.

    Parameters
    ----------
    noise : AxisNoise
        The axis's fit, updated in place.
    phase : ndarray, (P,)
        The axis's integrated record (eq. 1 of ``allan``).
    rate_hz : float
        Sample rate.
    """
    n_est, k_est = noise.terms["N"], noise.terms["K"]
    if (noise.fitted != ("N", "K") or noise.gauss_markov is not None or n_est.value is None
            or k_est.value is None):
        return
    crossing = noise.crossing_tau_nk  # the fit's, to size the blocks
    try:
        ml = white_walk_ml(phase, rate_hz, block_length(len(phase) - 1, rate_hz, crossing))
    except EngineInputError:
        return
    if ml.at_bound:
        return
    k_curve = noise.coeffs.get("K")
    apart = max(ml.k / k_curve, k_curve / ml.k) if k_curve else 1.0
    if apart > ML_AGREEMENT:
        k_est.method = (f"IEEE 952 fit; the likelihood of white noise + random walk gives {ml.k:.3g}, "
                        f"{apart:.2g} times apart: the record holds more than those two terms (e.g. a "
                        "correlated bias the curve does not resolve)")
        return
    k_est.adev_value, k_est.adev_stddev = k_est.value, k_est.stddev
    k_est.method = (f"{ML_METHOD} on {ml.block}-sample block means (white noise + random walk), 1-sigma "
                    "from the observed Fisher information")
    noise.coeffs["K"] = ml.k
    noise.crossing_tau_nk = math.sqrt(3.0) * n_est.value / ml.k
    k_est.value, k_est.stddev = ml.k, ml.k_stddev


def identify_noise(curve: AllanCurve, phase: np.ndarray | Sequence[np.ndarray] | None = None
                   ) -> tuple[AllanCurve, list[AxisNoise]]:
    """Fit every axis, then recompute EDF and intervals with the fitted noise types and fit again.

    The first pass takes each point's noise type from the curve's local slope; the second from the
    term that dominates the first fit there, which is steadier at long tau where the slope is noisy.
    Given the integrated records the curve came from (``phase``, one row per axis), K of the axes
    that show only those two terms is then taken from their exact likelihood (:func:`use_white_walk_ml`).
    Last, each axis's model is checked against its curve and, where it does not describe it, replaced
    by the simplest that does (:func:`station.engines.allan.model.choose_model`: Gauss-Markov processes,
    the sensor's filter, sinusoids); ``AxisNoise.noise_model`` holds the model and its valid range.

    Parameters
    ----------
    curve : AllanCurve
        The curves of every axis.
    phase : ndarray or sequence of ndarray, optional
        The integrated records the curve came from, one row per axis.

    Returns
    -------
    tuple
        The curve with EDF and intervals from the fitted noise types, and one :class:`AxisNoise` per axis.
    """
    first = [fit_axis(curve.tau, curve.adev[:, j], curve.edf[:, j], curve.duration_s, name)
             for j, name in enumerate(curve.axes)]
    alpha = np.column_stack([dominant_alpha(curve.tau, f) for f in first])
    refined = curve.with_alpha(alpha)
    noise = [fit_axis(refined.tau, refined.adev[:, j], refined.edf[:, j], refined.duration_s, name)
             for j, name in enumerate(refined.axes)]
    if phase is not None:
        for j, axis in enumerate(noise):
            use_white_walk_ml(axis, phase[j], curve.rate_hz)
    from station.engines.allan.model import choose_model  # it builds on this module's fit: no import cycle

    for j, axis in enumerate(noise):
        choose_model(axis, refined.tau, refined.adev[:, j], refined.edf[:, j], refined.ci_low[:, j],
                     refined.ci_high[:, j], refined.rate_hz)
    return refined, noise
