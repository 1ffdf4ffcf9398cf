"""A noise model chosen by the data: IEEE 952 terms, Gauss-Markov processes, the sensor's filter, sinusoids.

The model's Allan variance is a sum of non-negative terms (IEEE Std 952-1997, Annex C):

    sigma^2(tau) = 3 Q^2 / tau^2 + N^2 h_f(tau) + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2     (C.1)
                   + sum_k sigma_k^2 g(tau, T_k)                                  Gauss-Markov, (C.6)
                   + sum_j A_j^2 sin^4(pi f_j tau) / (pi f_j tau)^2               sinusoids, (C.7)

g is the Allan variance of a unit first-order Gauss-Markov process of correlation time T
(:func:`station.engines.allan.shapes.gauss_markov_avar`); h_f(tau) = 1 / tau for white noise, and for white
noise seen through the sensor's first-order digital output filter of time constant T_f the exact Allan
variance of the sampled AR(1) output (:func:`station.engines.allan.shapes.filtered_white_avar`;
g(tau, T_f) / (2 T_f) in the continuous limit): its curve bends below the white-noise line at the shortest
cluster times and meets it, within 3 %, from 50 T_f on.

The fit follows the generalized method of wavelet moments (Guerrier, Skaloud, Stebler and Victoria-Feser,
"Wavelet-variance-based estimation for composite stochastic processes", JASA 108(503), 2013; the Allan
variance is twice the Haar wavelet variance) with the weights of the curve's own EDF: it minimises

    sum_i [ln(sigma_hat^2(tau_i) / sigma^2(tau_i; theta)) - m(edf_i)]^2 / v(edf_i)                     (1)

where m = psi(edf / 2) - ln(edf / 2) and v = psi'(edf / 2) are the mean and variance of the logarithm of
a chi-square variable of edf degrees of freedom scaled by edf
(:func:`station.engines.allan.uncertainty.log_chi2_moments`; ~ -1 / edf and 2 / edf for many EDF, but at
the few EDF of the longest cluster times the mean matters: without it the fit sits under those points),
over the logarithms of every coefficient and time constant (scipy's trust-region reflective method, compiled
with the residuals in the private ``_trf`` module),
started from a non-negative least-squares fit of a dictionary of Gauss-Markov curves (correlation times
six per decade: the active ones cluster where the curve needs a process). The fit of one combination is
the package's private ``_wavelet_moments`` module; this one chooses among them.

Which terms: every admissible combination (any subset of Q, B, K, R beside N, and zero to three Gauss-Markov
processes; the filter and sinusoids where the curve shows them) is a candidate, and the simplest (fewest
parameters; then the smallest (1)) that describes the curve is chosen (:func:`preferred`). They are fitted
fewest parameters first, and those with more parameters than one that already describes the curve are not
fitted at all (they could not be chosen; on the ADIS16405 records 20 to 40 of the 64 are fitted). "Describes"
is a goodness-of-fit test point by point: the model lies inside the curve's 68 % interval, or within TOLERANCE
of the curve, at every cluster time of the valid range. Not an information criterion: the points of an
overlapping Allan curve are strongly correlated (neighbouring cluster times share most of their data), so (1)
is not a log-likelihood and AIC or BIC would count the same evidence many times over. The band test asks of
each point only what its own EDF promises, which is also what the plot shows and what a filter that takes the
model as its process noise needs. Where no combination passes, the points left outside may be scatter (a third
of independent points fall outside a 68 % interval by chance): then the fewest outside is the reference, and a
simpler combination is preferred unless the reference lowers (1) by CHI2_GAIN per added parameter (about ln
53, BIC's for the points of a 10,000 s curve), so that chance is kept apart from evidence. The IEEE fit is
tried first and stands where it describes the curve well enough (see :func:`choose_model`), which keeps
records of the IEEE terms from gaining processes. Each term's 1-sigma comes from the Jacobian of (1) at the
optimum, inflated by the reduced chi-square where that exceeds one.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

# The ``name as name`` imports re-export what moved below this module (the shapes, the log-chi-square
# moments, the estimate types): callers import those names from here.
from station.engines.allan._wavelet_moments import (
    GM_PARAMS,
    TOLERANCE,
    CandidateFit,
    Combination,
    WeightedCurve,
    by_weight,
    combination_avar,
    curve_of,
    filter_reach,
    fit_best_start,
    gm_starts,
    outside_count,
    parameter_estimates,
    sinusoid_start,
    unpack,
)
from station.engines.allan.estimates import (
    AxisNoise,
    Estimate,
    GaussMarkov,
    NoiseModel,
    Sinusoid,
    TermEstimate,
)
from station.engines.allan.shapes import filtered_white_avar as filtered_white_avar
from station.engines.allan.shapes import sinusoid_avar as sinusoid_avar
from station.engines.allan.terms import TERMS
from station.engines.allan.uncertainty import log_chi2_moments as log_chi2_moments

OPTIONAL = ("Q", "B", "K", "R")
MAX_GM = 3
MAX_SINUSOIDS = 2
SHORTEST_VALID = 0.1  # s: leading points the filter model leaves undescribed are dropped up to here at most
CHI2_GAIN = 4.0  # per parameter: what a richer model must gain in (1) over a simpler one
KEEP_REDUCED_CHI2 = 3.0  # (1) per point beyond which the IEEE fit misses the curve (see choose_model)
SIN_GAIN = 100.0  # a sinusoid draws the correlated wiggles of the many-EDF first points too (gains of tens)


def _as_model(fit: CandidateFit, curve: WeightedCurve, combinations: int) -> NoiseModel:
    combo = fit.combo
    amplitudes, filt, times, freqs = parameter_estimates(fit)
    n_terms = len(combo.terms)
    model = NoiseModel(filter_s=filt, chi2=fit.chi2, parameters=combo.parameters, combinations=combinations,
                       dt_s=combo.dt)
    model.terms = dict(zip(combo.terms, amplitudes[:n_terms], strict=True))
    gms = [GaussMarkov(a, t) for a, t in zip(amplitudes[n_terms:n_terms + combo.n_gm], times, strict=True)]
    model.gauss_markov = sorted(gms, key=lambda g: g.tau_c.value)
    model.sinusoids = [Sinusoid(a, f) for a, f in zip(amplitudes[n_terms + combo.n_gm:], freqs, strict=True)]
    outside = curve.outside(combination_avar(combo, curve.tau, fit.x))
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


def _fit_all(curve: WeightedCurve, filtered: bool, prune: bool = True) -> tuple[list[CandidateFit], int]:
    """Fit every admissible combination: sinusoids first, added to the fullest model while it does not
    describe the curve and each one removes points outside and lowers (1) by SIN_GAIN; then every subset
    of the optional terms with zero to MAX_GM processes, beside those sinusoids. Returns the fits and how
    many combinations were admissible.

    Each combination starts from two sets of correlation times: the dictionary's clusters and the
    fullest model's processes, the largest first (either alone misses a process now and then). The
    combinations are fitted fewest parameters first, and (``prune``) none is fitted once one with fewer
    parameters describes the curve: :func:`preferred` would not choose it (each fit depends only on its
    own starts, so the fits made are the same as without pruning)."""
    full_terms = ("N", *OPTIONAL)
    t_f = curve.filter_start() if filtered else None
    dt = 1.0 / curve.rate_hz
    full_combo = Combination(full_terms, MAX_GM, filtered, 0, dt)
    full = fit_best_start(curve, full_combo, t_f, [gm_starts(curve, full_terms, t_f, [])], [])
    fits = [full]
    while full.combo.n_sin < MAX_SINUSOIDS:
        before = outside_count(full, curve)
        if before == 0:
            break
        _, t_f_full, _, freqs_full = unpack(full.combo, full.x)
        trial_freqs = [*(float(f) for f in freqs_full), sinusoid_start(curve, full)]
        combo = Combination(full_terms, MAX_GM, filtered, len(trial_freqs), dt)
        trial = fit_best_start(curve, combo, t_f_full,
                               [by_weight(full), gm_starts(curve, full_terms, t_f_full, trial_freqs)],
                               trial_freqs)
        if outside_count(trial, curve) >= before or full.chi2 - trial.chi2 < SIN_GAIN:
            break
        full = trial
        fits = [full]
    _, t_f, _, freqs_arr = unpack(full.combo, full.x)
    freqs = [float(f) for f in freqs_arr]
    from_full = by_weight(full)
    combos = [Combination(("N", *extra), n_gm, filtered, len(freqs), dt)
              for k in range(len(OPTIONAL) + 1) for extra in itertools.combinations(OPTIONAL, k)
              for n_gm in range(MAX_GM + 1)]
    combos = [c for c in combos if c != full.combo]
    starts: dict[tuple[str, ...], list[list[float]]] = {}
    done: dict[int, CandidateFit] = {}
    for p in sorted({c.parameters for c in combos}):
        if prune and any(f.combo.parameters < p and outside_count(f, curve) == 0
                         for f in [*fits, *done.values()]):
            break
        for i, combo in enumerate(combos):
            if combo.parameters == p:
                if combo.terms not in starts:
                    starts[combo.terms] = [gm_starts(curve, combo.terms, t_f, freqs), from_full]
                done[i] = fit_best_start(curve, combo, t_f, starts[combo.terms], freqs)
    return fits + [done[i] for i in sorted(done)], len(fits) + len(combos)


def _select(curve: WeightedCurve, filtered: bool) -> tuple[CandidateFit, int]:
    """The preferred fit (:func:`preferred`) of every admissible combination, and how many were fitted."""
    fits, admissible = _fit_all(curve, filtered)
    best = preferred([(outside_count(f, curve), f.combo.parameters, f.chi2) for f in fits])
    return fits[best], admissible


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
    curve = curve_of(tau, adev, edf, ci_low, ci_high, rate_hz)
    curve.filter_reach_s = filter_reach(curve.tau, np.sqrt(curve.avar))
    filtered = curve.filter_reach_s is not None
    total = 0
    while True:
        best, fitted = _select(curve, filtered)
        total += fitted
        outside = curve.outside(combination_avar(best.combo, curve.tau, best.x))
        lead = 0
        while lead < len(outside) and outside[lead] and curve.tau[lead] < SHORTEST_VALID:
            lead += 1
        if not filtered or lead == 0 or len(curve.tau) - lead < 8:
            break
        curve = curve.part(slice(lead, None))
    return _as_model(best, curve, total)


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
    curve = curve_of(tau, adev, edf, ci_low, ci_high, rate_hz)
    curve = curve.part(curve.tau >= (axis.fitted_from_tau or curve.tau[0]))
    model = NoiseModel(method="IEEE 952 fit", combinations=1)
    for term, value in axis.coeffs.items():
        est = axis.terms[term]
        model.terms[term] = Estimate(value, est.stddev if est.value == value else None)
    model.unresolved = tuple(term for term in model.terms if axis.terms[term].value is None)
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
    curve = curve_of(tau, adev, edf, ci_low, ci_high, rate_hz)
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
