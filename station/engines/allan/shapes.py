"""The Allan variance each noise process draws, and the weighted least squares that fits their sum.

Every noise model of this package is a sum of non-negative coefficients times fixed shapes in tau
(IEEE Std 952-1997, Annex C):

    sigma^2(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2      (C.1)

(:func:`basis`, :func:`model_avar`), a first-order Gauss-Markov process of correlation time T_c
(:func:`gauss_markov_avar`), a sinusoid (:func:`sinusoid_avar`, C.7) and white noise seen through a
sensor's first-order output filter (:func:`filtered_white_avar`). For fixed time constants the sum is
linear in the coefficients, which :func:`weighted_nnls` fits with the weights of the curve's EDF. The
IEEE 952 fit (:mod:`station.engines.allan.fit`) and the model selection
(:mod:`station.engines.allan.model`) both build on these.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy import optimize

from station.engines.allan.terms import TERMS

B_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.66428


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


def model_avar(tau: np.ndarray, coeffs: Mapping[str, float | None]) -> np.ndarray:
    """Allan variance of eq. (C.1) for the terms given (None or missing terms count as zero).

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    coeffs : mapping of str to float or None
        Q, N, B, K, R in their units.

    Returns
    -------
    ndarray, (M,)
    """
    c = np.array([(coeffs.get(t) or 0.0) ** 2 for t in TERMS])
    return basis(tau) @ c


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


def term_avar(name: str, tau: np.ndarray, t_f: float | None, dt: float) -> np.ndarray:
    """Allan variance of IEEE 952 term ``name`` of unit coefficient (C.1), N through the filter if any.

    Parameters
    ----------
    name : str
        A key of ``TERMS``.
    tau : ndarray, (M,)
        Averaging times, s.
    t_f : float or None
        The output filter's time constant, s (None: no filter).
    dt : float
        Sample period, s (see :func:`filtered_white_avar`).

    Returns
    -------
    ndarray, (M,)
    """
    if name == "N":
        return filtered_white_avar(tau, t_f, dt)
    return {"Q": 3.0 / tau**2, "B": np.full_like(tau, B_FACTOR**2), "K": tau / 3.0, "R": tau**2 / 2.0}[name]


def weighted_nnls(a: np.ndarray, avar: np.ndarray, edf: np.ndarray, iterations: int = 6
                  ) -> tuple[np.ndarray, np.ndarray, float]:
    """EDF-weighted non-negative least squares of ``a c = avar``, iteratively re-weighted.

    An Allan variance estimate of edf degrees of freedom has variance 2 sigma^4 / edf; the weights take
    sigma^2 from the model itself, refitted until it stops moving (at most ``iterations`` times).

    Parameters
    ----------
    a : ndarray, (M, P)
        Columns of the shapes (e.g. :func:`basis`), one per coefficient.
    avar : ndarray, (M,)
        The measured Allan variances.
    edf : ndarray, (M,)
        Their equivalent degrees of freedom.
    iterations : int
        Most re-weightings.

    Returns
    -------
    tuple
        (c, covariance of c, weighted chi-square); the covariance is NaN in the rows and columns of the
        coefficients at zero.
    """
    c, chi2, an, scale, w2 = _reweighted_nnls(a, avar, edf, iterations)
    active = c > 0
    cov = np.full((a.shape[1], a.shape[1]), np.nan)
    if active.any():
        aa = an[:, active]  # normalised columns keep the Fisher matrix well conditioned
        fisher = aa.T @ (aa * w2[:, None])
        with np.errstate(all="ignore"):
            cov_active = np.linalg.pinv(fisher) / np.outer(scale[active], scale[active])
        cov[np.ix_(active, active)] = cov_active
    return c, cov, chi2


def weighted_nnls_fit(a: np.ndarray, avar: np.ndarray, edf: np.ndarray, iterations: int = 6
                      ) -> tuple[np.ndarray, float]:
    """:func:`weighted_nnls` without the covariance (the starts of the model selection need none):
    (c, weighted chi-square), the same numbers.

    Parameters
    ----------
    a : ndarray, (M, P)
        Columns of the shapes, one per coefficient.
    avar, edf : ndarray, (M,)
        The measured Allan variances and their equivalent degrees of freedom.
    iterations : int
        Most re-weightings.

    Returns
    -------
    tuple
        (c, weighted chi-square).
    """
    c, chi2, _, _, _ = _reweighted_nnls(a, avar, edf, iterations)
    return c, chi2


def _reweighted_nnls(a: np.ndarray, avar: np.ndarray, edf: np.ndarray, iterations: int
                     ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """The iterations of :func:`weighted_nnls`: (c, chi2, normalised columns, their scale, final weights)."""
    scale = np.max(np.abs(a), axis=0)  # columns span many decades: normalise before NNLS
    an = a / scale
    model = avar.copy()
    c = np.zeros(a.shape[1])
    root_edf = np.sqrt(edf / 2.0)
    tiny = np.finfo(float).tiny
    for _ in range(iterations):
        w = root_edf / np.maximum(model, tiny)
        cn, _ = optimize.nnls(an * w[:, None], avar * w, maxiter=50 * a.shape[1])
        c = cn / scale
        new_model = a @ c
        # variances are tiny: no absolute floor (np.allclose(new_model, model, rtol=1e-9, atol=0.0))
        if np.all(np.abs(new_model - model) <= 1e-9 * np.abs(model)):
            break
        model = np.where(new_model > 0, new_model, avar)
    w2 = (edf / 2.0) / np.maximum(model, tiny) ** 2
    chi2 = float(np.sum(w2 * (avar - model) ** 2))
    return c, chi2, an, scale, w2
