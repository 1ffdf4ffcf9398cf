"""What the Allan fits report: each noise term's estimate, an axis's IEEE 952 fit, the chosen noise model.

:class:`AxisNoise` is one axis's result (:func:`station.engines.allan.fit.identify_noise`): its IEEE 952
terms (:class:`TermEstimate`, value and 1-sigma or the reason there is none) and the model that describes
its curve (:class:`NoiseModel`, :func:`station.engines.allan.model.choose_model`), each of whose terms is
an :class:`Estimate`. Each can draw its own Allan deviation (the shapes of
:mod:`station.engines.allan.shapes`), which is what the plots and the parameter file read.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from station.engines.allan.shapes import gauss_markov_avar, model_avar, sinusoid_avar, term_avar


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
    # terms the model carries that are not reported (an IEEE fit's K that is not significant): named as
    # such, so that a model "with K" never stands beside a K reported as not resolved
    unresolved: tuple[str, ...] = ()

    def describe(self) -> str:
        """The model's terms in words, e.g. ``N (filtered) + K + 2 Gauss-Markov + 1 sinusoid``; a term
        in ``unresolved`` reads ``K (modelled, not resolved)``."""
        parts = [f"{name} (filtered)" if name == "N" and self.filter_s is not None
                 else f"{name} (modelled, not resolved)" if name in self.unresolved else name
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
        out = {name: est.value**2 * term_avar(name, tau, t_f, self.dt_s) for name, est in self.terms.items()}
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

