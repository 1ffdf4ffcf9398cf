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

Where no flat floor shows but the curve draws a correlated (first-order Gauss-Markov) bias, N, K and that
bias are fitted instead of (C.1) (:mod:`station.engines.allan.correlated_bias`), and B is the bias's peak.

Beside the fit, the classic slope-line reading (IEEE 952 Annex C; e.g. El-Sheimy, Hou and Niu, "Analysis
and modeling of inertial sensors using Allan variance", IEEE TIM 57(1), 2008): where the curve's
log-log slope is -1, -1/2, 0, +1/2, +1, the straight line of that slope through the curve, read at
tau = 1 s, and the term it gives (Q at tau = sqrt(3), N at 1, B = floor / 0.66428, K at 3, R at sqrt(2)).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

# the module, not its choose_model: the function is looked up when called, so that
# benchmarks/allan_day.py can time the model choice by wrapping it
from station.engines.allan import model
from station.engines.allan.correlated_bias import CHI2_GAIN, MIN_EDF_SHOWN, SIGNIFICANCE, fit_correlated_bias
from station.engines.allan.deviation import AllanCurve
from station.engines.allan.estimates import AxisNoise, TermEstimate
from station.engines.allan.likelihood import block_length, white_walk_ml
from station.engines.allan.shapes import B_FACTOR, basis, gauss_markov_avar, weighted_nnls
from station.engines.allan.shapes import model_avar as model_avar
from station.engines.allan.terms import TERMS
from station.errors import EngineInputError

ALPHA_OF_TERM = {"Q": 2, "N": 0, "B": -1, "K": -2, "R": -2}
SLOPE_OF_TERM = {"Q": -1.0, "N": -0.5, "B": 0.0, "K": 0.5, "R": 1.0}
# tau where the slope line equals the term:
# sigma = sqrt(3) Q / tau, N / sqrt(tau), K sqrt(tau / 3), R tau / sqrt(2)
READ_TAU = {"Q": math.sqrt(3.0), "N": 1.0, "K": 3.0, "R": math.sqrt(2.0)}
SLOPE_TOLERANCE = 0.1
MIN_DOMINANT_POINTS = 3
OPTIONAL = ("Q", "B", "R")
MODELLED_UNSHOWN = ("Q",)  # kept in the fit where significant and material, reported only where shown
MODELLED_SHARE = 0.2  # material: this share of the Allan variance at the shortest tau or more
K_CROSSING_FRACTION = 20.0  # K needs the N and K lines to cross before T / 20
# The horizon (s) over which a random walk must be resolved unless --horizon says: a K whose line
# crosses the white noise's beyond it adds less than the white noise within it. A minute and a half
# covers what visual-inertial filters propagate on the IMU alone (frames, outages of tens of seconds).
K_HORIZON_S = 100.0
FILTER_SLOPE = -0.45  # a curve starting above this slope starts with a sensor's filter, not a noise term
FILTER_MARGIN = 3.0  # the fit starts this factor in tau after the filtered start reaches FILTER_SLOPE
ML_AGREEMENT = 1.15  # the likelihood's K replaces the curve fit's only within this factor of it
ML_METHOD = "exact Gaussian maximum likelihood"


def _fit(tau: np.ndarray, avar: np.ndarray, edf: np.ndarray, terms: tuple[str, ...]
         ) -> tuple[dict[str, float], dict[str, float], float]:
    cols = [TERMS.index(t) for t in terms]
    c, cov, chi2 = weighted_nnls(basis(tau)[:, cols], avar, edf)
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
    if result.terms["B"].value is None:  # no floor: a correlated bias may draw what (C.1) cannot
        values = fit_correlated_bias(tau, adev, edf, result, values, chi2, duration_s)
    n_val = values.get("N", 0.0)
    k_val = values.get("K", 0.0)
    if n_val > 0 and k_val > 0:
        result.crossing_tau_nk = math.sqrt(3.0) * math.sqrt(n_val) / math.sqrt(k_val)  # N^2/tau = K^2 tau / 3
    k_est = result.terms["K"]
    if k_est.value is not None and result.crossing_tau_nk is not None:
        limit = duration_s / K_CROSSING_FRACTION
        if result.crossing_tau_nk > limit:
            # no record length here: the one length asked for is missing_terms' (it does not move with T)
            k_est.reason = (f"record too short: the white-noise and random-walk lines cross at tau = "
                            f"{result.crossing_tau_nk:.3g} s, beyond T/20 = {limit:.3g} s")
            k_est.value = None
            k_est.stddev = None
    return result


@dataclass(frozen=True)
class MissingTerm:
    """A noise term asked for that an axis's record does not resolve.

    ``needed_s`` is the record length that resolves it where one can be told (K: :func:`k_record_length`),
    None where this record is already that long or no length can be told; ``matters_above`` (K only) is
    the smallest K that adds as much as the white noise within the horizon, sqrt(3) N / H.
    """

    axis: str
    term: str
    reason: str
    needed_s: float | None
    matters_above: float | None = None


def k_record_length(horizon_s: float = K_HORIZON_S) -> float:
    """The still record that resolves every random walk K that matters within ``horizon_s``.

    K matters within a horizon H when its Allan variance reaches the white noise's there:
    K^2 H / 3 >= N^2 / H, i.e. the two lines cross at tau_c = sqrt(3) N / K <= H. The fit resolves K
    when tau_c <= T / 20 (``K_CROSSING_FRACTION``: 20 clusters at tau_c, where the overlapping Allan
    deviation of a random walk has about 17 equivalent degrees of freedom, a 17 % 1-sigma). So
    T = 20 H resolves every K that matters within H, and a K such a record does not resolve does not
    matter there. The length depends on H alone: not on this record, whose bound on an unseen K only
    tightens as it grows (the length it implied moved from 5.9 to 19.5 to 39.7 min over records of
    101 s, 5 min and 20 min of one unit).

    Parameters
    ----------
    horizon_s : float
        H, s.

    Returns
    -------
    float
        T, s.
    """
    return K_CROSSING_FRACTION * horizon_s


def missing_terms(noise: Sequence[AxisNoise], terms: Sequence[str], duration_s: float,
                  horizon_s: float | None = None) -> list[MissingTerm]:
    """The terms of ``terms`` that some axis leaves null, with why and the record length they need.

    Parameters
    ----------
    noise : sequence of AxisNoise
        Every axis's fit (:func:`identify_noise`).
    terms : sequence of str
        The terms asked for (keys of ``TERMS``).
    duration_s : float
        Length of the record, s.
    horizon_s : float, optional
        The horizon over which K must be resolved (default ``K_HORIZON_S``).

    Returns
    -------
    list of MissingTerm
        Empty when every axis resolves every term asked for. K's length is :func:`k_record_length`'s;
        the other terms give none but "longer".
    """
    horizon = K_HORIZON_S if horizon_s is None else horizon_s
    out = []
    for axis in noise:
        for term in terms:
            est = axis.terms[term]
            if est.value is not None:
                continue
            needed, matters = None, None
            if term == "K":
                needed = k_record_length(horizon)
                needed = needed if needed > duration_s else None
                n_val = axis.terms["N"].value or axis.coeffs.get("N")
                matters = math.sqrt(3.0) * n_val / horizon if n_val else None
            out.append(MissingTerm(axis.axis, term, est.reason or "not resolved", needed, matters))
    return out


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
    for j, axis in enumerate(noise):
        model.choose_model(axis, refined.tau, refined.adev[:, j], refined.edf[:, j], refined.ci_low[:, j],
                     refined.ci_high[:, j], refined.rate_hz)
    return refined, noise
