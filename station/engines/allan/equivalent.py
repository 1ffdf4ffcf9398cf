"""White noise and random walk equivalent to a whole noise model, for filters that take only N and K.

Kalibr, VINS-Fusion and ORB-SLAM3 model an IMU axis as white noise of density N on the measurement and a
random-walk bias of density K: their Allan variance is N^2 / tau + K^2 tau / 3 (IEEE 952, C.1). A real
unit's model (:mod:`station.engines.allan.model`) has more: Gauss-Markov processes, bias instability, a
rate ramp. The equivalent pair is the smallest one whose Allan variance covers the model's at every
averaging time the filter works over, from its step ``dt`` (the IMU period) to its horizon ``H`` (how
long the filter relies on a bias estimate):

    N_eq^2 = N^2 + sum_{T_k < dt} 2 sigma_k^2 T_k                                                     (1)
    K_eq^2 = max_{dt <= tau <= H} 3 (sigma_c^2(tau) + (N^2 - N_eq^2) / tau) / tau,  at least 0           (2)

(1): a Gauss-Markov process faster than the filter's step is white noise to it, of density sqrt(2 sigma^2 T)
(its Allan variance tends to 2 sigma^2 T / tau). (2): sigma_c^2 is the Allan variance of the correlated terms
(B, K, R and the slower processes); K_eq is the random walk whose line N_eq^2 / tau + K_eq^2 tau / 3 stays on
or above the model everywhere in [dt, H] (it touches it where the bias drifts fastest for its time scale). On
a model of N and K alone it gives N and K back. Bias instability B is the one correlated term whose Allan
variance does not vanish as tau -> 0: (2) would make K_eq cover its floor at the step alone (K_eq^2 = 3 (2 ln
2 / pi) B^2 / dt^2, a random walk thousands of times too large), so with B, N_eq^2 is raised from (1) too: to
the value, up to the one that covers the whole model alone, whose pair (K_eq from (2)) overestimates the model
least at its worst point of [dt, H] (a flat floor over decades of tau is drawn by no pair closely).
Quantization, the sensor's output filter and sinusoids are left out: they are not random walks of the bias,
and a filter that integrates the rate over its step already averages them.
"""

from __future__ import annotations

import math

import numpy as np

from station.engines.allan.estimates import NoiseModel
from station.engines.allan.shapes import B_FACTOR, gauss_markov_avar

GRID = 400  # averaging times between the step and the horizon


def white_walk_equivalent(model: NoiseModel, step_s: float, horizon_s: float) -> tuple[float, float]:
    """N_eq and K_eq of eqs. (1)-(2) for a filter of step ``step_s`` relying on a bias for ``horizon_s``.

    Parameters
    ----------
    model : NoiseModel
        The axis's model.
    step_s : float
        The filter's step (the IMU sample period), s.
    horizon_s : float
        The longest averaging time the filter relies on, s (at least ``step_s``).

    Returns
    -------
    tuple of float
        (N_eq in the unit/sqrt(Hz), K_eq in the unit/s/sqrt(Hz)).
    """
    n2 = model.terms["N"].value ** 2 if "N" in model.terms else 0.0
    slow = []
    n2_eq = n2
    for gm in model.gauss_markov:
        if gm.tau_c.value < step_s:
            n2_eq += 2.0 * gm.sigma.value**2 * gm.tau_c.value
        else:
            slow.append(gm)
    tau = np.geomspace(step_s, max(horizon_s, step_s), GRID)
    correlated = np.zeros_like(tau)
    coeff = {name: est.value**2 for name, est in model.terms.items()}
    correlated += coeff.get("B", 0.0) * B_FACTOR**2 + coeff.get("K", 0.0) * tau / 3.0
    correlated += coeff.get("R", 0.0) * tau**2 / 2.0
    for gm in slow:
        correlated += gm.sigma.value**2 * gauss_markov_avar(tau, gm.tau_c.value)
    if coeff.get("B", 0.0) > 0.0:
        # candidates from (1) to the white noise covering every correlated term alone at every tau
        total = n2 / tau + correlated
        most = float(np.max(correlated * tau))
        candidates = n2_eq + np.concatenate([[0.0], np.geomspace(most * 1e-9, most, 4 * GRID)])
        need = 3.0 * (correlated[None, :] + (n2 - candidates[:, None]) / tau) / tau
        k2s = np.maximum(np.max(need, axis=1), 0.0)
        worst = np.max((candidates[:, None] / tau + k2s[:, None] * tau / 3.0) / total, axis=1)
        best = int(np.argmin(worst))
        return math.sqrt(float(candidates[best])), math.sqrt(float(k2s[best]))
    k2 = float(np.max(3.0 * (correlated + (n2 - n2_eq) / tau) / tau))
    return math.sqrt(n2_eq), math.sqrt(max(k2, 0.0))
