"""The uncertainty of an overlapping Allan deviation point: its equivalent degrees of freedom, its
confidence interval, and the distribution of its logarithm.

Equivalent degrees of freedom: C. A. Greenhall and W. J. Riley, "Uncertainty of stability variances based
on finite differences", Proc. 35th PTTI Meeting (2003), eqs. (7)-(13) and tables 2-3, for the unmodified
(F = m), overlapping (S = m) Allan variance (d = 2). They depend on the noise type at each point (the
power-law exponent alpha of the rate's spectrum), read from the curve's slope (:func:`alpha_from_slope`)
or from a fit's dominant term. The confidence interval is the chi-square interval of NIST SP 1065,
eq. 45. An estimate of edf degrees of freedom is sigma^2 X / edf with X chi-square: the mean and spread of
its logarithm (:func:`log_chi2_moments`) weight the log-domain fit of the noise model
(:mod:`station.engines.allan.model`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from station.errors import EngineInputError

ONE_SIGMA = float(special.erf(1.0 / math.sqrt(2.0)))  # 0.6827: the "68 %" interval

# Greenhall & Riley (2003), d = 2 (Allan), F = m, S = m
_J_MAX = 100
# Table 2 (unmodified variances, d = 2): 1/edf ~ (a0 - a1 / r) / r for large J; alpha -> (a0, a1)
_TABLE2 = {1: (790.0, 410.0), 0: (2.0 / 3.0, 1.0 / 3.0), -1: (0.852, 0.375), -2: (1.079, 0.368)}
_TABLE3_ALPHA1 = (15.23, 12.0)  # Table 3, alpha = +1, d = 2: (b0, b1)


def _sw(t: np.ndarray, alpha: int) -> np.ndarray:
    """Eq. (7): the generalized autocovariance kernel of power-law noise ``S_x ~ f^(alpha - 2)``."""
    t = np.asarray(t, dtype=np.float64)
    a = np.abs(t)
    if alpha % 2 == 0:
        return -a if alpha == 2 else a ** (3 - alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = t ** (2 - (alpha - 1)) * np.log(a)
    return np.where(a == 0, 0.0, out)


def _sx(t: np.ndarray, f: float, alpha: int) -> np.ndarray:
    """Eq. (8): the kernel after the averaging filter of factor F (F = inf: its limit)."""
    if math.isinf(f):
        return _sw(t, alpha + 2)
    return f * f * (2.0 * _sw(t, alpha) - _sw(t - 1.0 / f, alpha) - _sw(t + 1.0 / f, alpha))


def _sz(t: np.ndarray, f: float, alpha: int) -> np.ndarray:
    """Eq. (9), d = 2: the kernel after the second difference."""
    return (6.0 * _sx(t, f, alpha) - 4.0 * _sx(t - 1.0, f, alpha) - 4.0 * _sx(t + 1.0, f, alpha)
            + _sx(t - 2.0, f, alpha) + _sx(t + 2.0, f, alpha))


def _basic_sum(j_terms: int, m_terms: float, s: float, f: float, alpha: int) -> float:
    """Eq. (10): sz(0)^2 + (1 - J/M) sz(J/S)^2 + 2 sum_{j=1}^{J-1} (1 - j/M) sz(j/S)^2."""
    j = np.arange(1, j_terms, dtype=np.float64)
    first = float(_sz(np.array(0.0), f, alpha)) ** 2
    second = (1.0 - j_terms / m_terms) * float(_sz(np.array(j_terms / s), f, alpha)) ** 2
    third = 2.0 * float(np.sum((1.0 - j / m_terms) * _sz(j / s, f, alpha) ** 2))
    return first + second + third


def greenhall_edf(alpha: int, m: int, n_phase: int) -> float:
    """Equivalent degrees of freedom of one overlapping Allan variance point.

    Greenhall & Riley (2003), d = 2, unmodified (F = m), overlapping (S = m): eqs. (10)-(13) with
    L = m/F + m d, M = 1 + floor(S (N - L) / m), J = min(M, (d + 1) S), r = M / S; cases 2 (alpha <= 0)
    and 3 (alpha = 1) with J_max = 100 and tables 2-3. For alpha = 2 (white phase noise: quantization)
    the second differences are correlated at lags 0, m, 2m only (covariances 6, -4, 1), which gives
    exactly ``edf = 36 M^2 / (36 M + 32 (M - m)+ + 2 (M - 2m)+)``; for r > d this is Greenhall's case 4.

    Parameters
    ----------
    alpha : int
        Power-law exponent of the fractional-frequency (rate) spectrum, S_y ~ f^alpha: 2 white phase
        (quantization), 1 flicker phase, 0 white rate (N), -1 flicker rate (B), -2 random walk (K).
    m : int
        Averaging factor.
    n_phase : int
        Number of phase points P (samples + 1).

    Returns
    -------
    float
        Equivalent degrees of freedom.
    """
    m = int(m)
    big_m = n_phase - 2 * m  # M = 1 + floor(m (P - 1 - 2m) / m)
    if big_m < 1:
        raise EngineInputError(f"cluster size {m} is too large for {n_phase - 1} samples")
    if alpha == 2:
        return 36.0 * big_m**2 / (36.0 * big_m + 32.0 * max(big_m - m, 0) + 2.0 * max(big_m - 2 * m, 0))
    if alpha not in _TABLE2:
        raise ValueError(f"alpha must be one of 2, 1, 0, -1, -2 for the Allan variance, got {alpha}")
    s = float(m)
    j_terms = min(big_m, 3 * m)
    r = big_m / s
    if alpha == 1:  # case 3
        b0, b1 = _TABLE3_ALPHA1
        if j_terms <= _J_MAX:
            inv = _basic_sum(j_terms, big_m, s, float(m), 1) / (float(_sz(np.array(0.0), float(m), 1)) ** 2
                                                                 * big_m)
        elif r > 3:
            a0, a1 = _TABLE2[1]
            inv = (a0 - a1 / r) / ((b0 + b1 * math.log(m)) ** 2 * r)
        else:
            mp = _J_MAX / r
            inv = _basic_sum(_J_MAX, _J_MAX, mp, mp, 1) / ((b0 + b1 * math.log(m)) ** 2 * _J_MAX)
        return 1.0 / inv
    # case 2: unmodified, alpha <= 0
    if j_terms <= _J_MAX:
        f = float(m) if 3 * m <= _J_MAX else math.inf
        inv = _basic_sum(j_terms, big_m, s, f, alpha) / (float(_sz(np.array(0.0), f, alpha)) ** 2 * big_m)
    elif r > 3:
        a0, a1 = _TABLE2[alpha]
        inv = (a0 - a1 / r) / r
    else:
        mp = _J_MAX / r
        inv = _basic_sum(_J_MAX, _J_MAX, mp, math.inf, alpha) / (
            float(_sz(np.array(0.0), math.inf, alpha)) ** 2 * _J_MAX)
    return 1.0 / inv


def edf_table(alpha: np.ndarray, m: np.ndarray, n_phase: int) -> np.ndarray:
    """Greenhall EDF for every (cluster size, axis); equal (alpha, m) pairs are computed once.

    Parameters
    ----------
    alpha : ndarray of int, (M, axes)
        Noise type per point and axis.
    m : ndarray of int, (M,)
        Cluster sizes.
    n_phase : int
        Phase points of the record (N + 1).

    Returns
    -------
    ndarray, (M, axes)
    """
    alpha = np.asarray(alpha, dtype=np.int64)
    out = np.empty(alpha.shape, dtype=np.float64)
    cache: dict[tuple[int, int], float] = {}
    for (i, j), a in np.ndenumerate(alpha):
        key = (int(a), int(m[i]))
        if key not in cache:
            cache[key] = greenhall_edf(key[0], key[1], n_phase)
        out[i, j] = cache[key]
    return out


def confidence_interval(adev: np.ndarray, edf: np.ndarray, level: float = ONE_SIGMA
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Chi-square confidence interval of Allan deviations (NIST SP 1065, eq. 45).

    ``sigma_lo = sigma sqrt(edf / chi2_{(1+level)/2}(edf))``,
    ``sigma_hi = sigma sqrt(edf / chi2_{(1-level)/2}(edf))``.

    Parameters
    ----------
    adev : ndarray
        Allan deviations.
    edf : ndarray
        Their equivalent degrees of freedom (same shape).
    level : float
        Confidence level (default one sigma, 0.683).

    Returns
    -------
    tuple of ndarray
        (sigma_lo, sigma_hi).
    """
    adev = np.asarray(adev, dtype=np.float64)
    edf = np.asarray(edf, dtype=np.float64)
    tail = (1.0 - level) / 2.0
    # chi2.ppf(q, k) = 2 P^-1(k/2, q), the inverse regularised lower incomplete gamma: scipy.special
    # alone, where scipy.stats would cost half a second of the command's start.
    lo = adev * np.sqrt(edf / (2.0 * special.gammaincinv(edf / 2.0, 1.0 - tail)))
    hi = adev * np.sqrt(edf / (2.0 * special.gammaincinv(edf / 2.0, tail)))
    return lo, hi


def alpha_from_slope(tau: np.ndarray, adev: np.ndarray) -> np.ndarray:
    """Power-law noise type at each point from the local log-log slope mu of sigma^2 ~ tau^mu.

    mu = -2: alpha = 2 (white phase; the Allan variance cannot tell it from flicker phase), mu = -1:
    alpha = 0, mu = 0: alpha = -1, mu >= +1: alpha = -2 (rate ramp has no finite-difference EDF at d = 2
    and takes the random-walk one). Columns of ``adev`` are axes.

    Parameters
    ----------
    tau : ndarray, (M,)
        Averaging times, s.
    adev : ndarray, (M, axes)
        Allan deviations.

    Returns
    -------
    ndarray of int, (M, axes)
        alpha per point and axis.
    """
    logt = np.log(np.asarray(tau, dtype=np.float64))
    logv = 2.0 * np.log(np.asarray(adev, dtype=np.float64))
    if len(logt) < 2:
        return np.zeros(logv.shape, dtype=np.int64)
    mu = np.gradient(logv, logt, axis=0)
    return np.select([mu < -1.5, mu < -0.5, mu < 0.5], [2, 0, -1], default=-2).astype(np.int64)


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
