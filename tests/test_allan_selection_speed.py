"""The model selection made fast (issue 30) chooses what it chose before: simulated units give their terms
and the values the former implementation (scipy's least_squares, every combination fitted) gave; the
compiled trust-region solve ends where scipy's does; leaving out the combinations a simpler describing one
rules out does not change the model chosen. No timing here: benchmarks/allan_model.py measures the cost."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import optimize
from scipy.signal import lfilter

from station.engines.allan import _wavelet_moments as wm
from station.engines.allan import model
from station.engines.allan.deviation import allan_curve, integrate_rates
from station.engines.allan.model import select_model
from station.engines.allan.uncertainty import log_chi2_moments

RATE = 100.0
POLE = 0.6  # the sensor's filter: T_f = -dt / ln 0.6 = 19.6 ms


def _unit(seed: int, gm: bool, sine: bool):
    """1 h at 100 Hz of white noise (1e-3 /sqrt(Hz)) through a first-order filter, with a Gauss-Markov
    process (sigma 3e-4, 20 s) and a 7 Hz sinusoid of amplitude 2e-3 where asked: the curve of gx."""
    rng = np.random.default_rng(seed)
    n = 360_000
    y = lfilter([1.0 - POLE], [1.0, -POLE], rng.standard_normal(n) * 1e-3 * math.sqrt(RATE))
    if gm:
        a = math.exp(-1.0 / RATE / 20.0)
        y += lfilter([math.sqrt(1 - a * a) * 3e-4], [1.0, -a], rng.standard_normal(n))
    if sine:
        y += 2e-3 * np.sin(2 * math.pi * 7.0 * np.arange(n) / RATE)
    return allan_curve(integrate_rates(y, RATE), RATE, ("gx",))


# what the former implementation (commit 946e613) chose on these units: terms, then (value, 1-sigma) of
# N, T_f, each process's sigma and tau_c, each sinusoid's amplitude and frequency
BEFORE = {
    (1, True, True): ("N (filtered) + 1 Gauss-Markov + 1 sinusoid",
                      [(9.945010659732933e-4, 1.796e-6), (1.9475616064243466e-2, 5.121e-5),
                       (3.0699209907171363e-4, 1.019e-5), (11.649093017912435, 1.469),
                       (2.008593836222721e-3, 1.898e-5), (6.993945259540065, 5.076e-2)]),
    (1, True, False): ("N (filtered) + 1 Gauss-Markov",
                       [(9.94666710448183e-4, 1.283e-6), (1.9479914799663246e-2, 4.329e-5),
                        (3.0681088981284724e-4, 1.011e-5), (11.67769076309931, 1.465)]),
    (2, False, True): ("N (filtered) + 1 sinusoid",
                       [(9.994235651270805e-4, 1.742e-6), (1.9543953151983207e-2, 5.024e-5),
                        (2.0106639253303607e-3, 1.893e-5), (7.045511494532146, 5.132e-2)]),
}


def _values(m) -> list[tuple[float, float | None]]:
    out = [(e.value, e.stddev) for e in m.terms.values()]
    out.append((m.filter_s.value, m.filter_s.stddev))
    for g in m.gauss_markov:
        out += [(g.sigma.value, g.sigma.stddev), (g.tau_c.value, g.tau_c.stddev)]
    for s in m.sinusoids:
        out += [(s.amplitude.value, s.amplitude.stddev), (s.freq_hz.value, s.freq_hz.stddev)]
    return out


@pytest.mark.parametrize("unit", list(BEFORE))
def test_simulated_units_get_their_terms_and_the_former_values(unit):
    curve = _unit(*unit)
    got = select_model(curve.tau, curve.adev[:, 0], curve.edf[:, 0], curve.ci_low[:, 0], curve.ci_high[:, 0],
                       RATE)
    terms, before = BEFORE[unit]
    assert got.describe() == terms
    assert got.describes and got.outside == 0 and got.points == 49 and got.combinations == 64
    assert got.valid_tau == (0.01, float(curve.tau[-1]))
    values = _values(got)
    assert len(values) == len(before)
    for (value, sd), (old, old_sd) in zip(values, before, strict=True):
        assert abs(value - old) <= 1e-3 * old_sd  # well within its 1-sigma: the same fit
        assert sd == pytest.approx(old_sd, rel=1e-3)
    # and near the truth
    assert got.terms["N"].value == pytest.approx(1e-3, rel=0.01)
    assert got.filter_s.value == pytest.approx(-0.01 / math.log(POLE), rel=0.02)
    for s in got.sinusoids:
        assert s.amplitude.value == pytest.approx(2e-3, rel=0.02)
        assert s.freq_hz.value == pytest.approx(7.0, rel=0.01)


def _scipy_solve(curve: wm.WeightedCurve, combo: wm.Combination, x0: np.ndarray, bounds
                 ) -> tuple[np.ndarray, float]:
    """The former solve: scipy's least_squares on (1), the Jacobian exact in the log coefficients and by
    central differences in the log time constants."""
    mean, sd = log_chi2_moments(curve.edf)
    w, log_avar, tiny = 1.0 / sd, np.log(curve.avar) - mean, np.finfo(float).tiny
    n_lin = len(combo.terms) + combo.n_gm + combo.n_sin

    def residuals(x):
        return w * (log_avar - np.log(np.maximum(wm.combination_avar(combo, curve.tau, x), tiny)))

    def jacobian(x):
        c, t_f, t_gm, freqs = wm.unpack(combo, x)
        parts = wm._columns(combo, curve.tau, t_f, t_gm, freqs) * c
        jac = np.empty((len(curve.tau), len(x)))
        jac[:, :n_lin] = -w[:, None] * parts / np.maximum(parts.sum(axis=1), tiny)[:, None]
        for k in range(n_lin, len(x)):
            step = np.zeros_like(x)
            step[k] = 1e-6
            jac[:, k] = (residuals(x + step) - residuals(x - step)) / 2e-6
        return jac

    x0 = np.clip(x0, bounds[0] + 1e-9, bounds[1] - 1e-9)
    with np.errstate(divide="ignore", invalid="ignore"):
        sol = optimize.least_squares(residuals, x0, jac=jacobian, bounds=bounds, method="trf", x_scale=1.0,
                                     max_nfev=400)
    return sol.x, float(np.sum(sol.fun**2))


def test_the_compiled_solve_ends_where_scipys_does():
    """Every combination of N (filtered) with the optional terms, up to two processes and one sinusoid, on
    a simulated unit's curve, from the same start: the same (1) to 1e-8 and the same model curve to 1e-4
    (where the combination has more terms than the curve needs, as two processes here, the fit's flat
    directions let the iterates, which differ in the last bits, stop 1e-5 apart; a term the data does not
    need may shrink to a different negligible size)."""
    c = _unit(1, True, True)
    curve = wm.curve_of(c.tau, c.adev[:, 0], c.edf[:, 0], c.ci_low[:, 0], c.ci_high[:, 0], RATE)
    curve.filter_reach_s = wm.filter_reach(curve.tau, np.sqrt(curve.avar))
    t_f = curve.filter_start()
    for extra, n_gm, n_sin in itertools.product([(), ("K",), ("B", "R"), ("Q", "B", "K", "R")], (0, 1, 2),
                                                (0, 1)):
        combo = wm.Combination(("N", *extra), n_gm, True, n_sin, 0.01)
        t_gm = wm._padded(wm.gm_starts(curve, combo.terms, t_f, [6.0] * n_sin), n_gm, curve)
        x0 = list(wm._linear_start(curve, combo, t_f, t_gm, [6.0] * n_sin))
        x0 += [math.log(t_f)] + [math.log(t) for t in t_gm] + [math.log(6.0)] * n_sin
        bounds = wm._bounds(combo, curve)
        fit = wm._solve(curve, combo, np.array(x0), bounds)
        x_ref, chi2_ref = _scipy_solve(curve, combo, np.array(x0), bounds)
        assert fit.chi2 == pytest.approx(chi2_ref, rel=1e-8), combo
        np.testing.assert_allclose(wm.combination_avar(combo, curve.tau, fit.x),
                                   wm.combination_avar(combo, curve.tau, x_ref), rtol=1e-4,
                                   err_msg=str(combo))


@pytest.mark.parametrize("unit", [(1, True, True), (2, False, True)])
def test_combinations_left_unfitted_would_not_be_chosen(unit):
    """Fitting every combination (as before) and fitting only those no simpler describing one rules out
    prefer the same fit; the pruned list is a part of the full one, fit for fit."""
    c = _unit(*unit)
    curve = wm.curve_of(c.tau, c.adev[:, 0], c.edf[:, 0], c.ci_low[:, 0], c.ci_high[:, 0], RATE)
    curve.filter_reach_s = wm.filter_reach(curve.tau, np.sqrt(curve.avar))
    pruned, n_pruned = model._fit_all(curve, True)
    every, n_every = model._fit_all(curve, True, prune=False)
    assert n_pruned == n_every == len(every) == 64 and len(pruned) < len(every)
    by_combo = {f.combo: f for f in every}
    for f in pruned:
        assert f.chi2 == by_combo[f.combo].chi2 and np.array_equal(f.x, by_combo[f.combo].x)

    def choice(fits):
        best = model.preferred([(wm.outside_count(f, curve), f.combo.parameters, f.chi2) for f in fits])
        return fits[best].combo

    assert choice(pruned) == choice(every)
