"""White noise N and rate random walk K of a still record by exact Gaussian maximum likelihood on block means.

Model: the rate of one axis is y_k = w_k + r_k, w white of density N (per-sample variance N^2 f_s) and r a
random walk of density K (step variance K^2 / f_s), the two terms N^2 / tau + K^2 tau / 3 of IEEE 952
(C.1). The means of blocks of L samples, ybar_j, differenced once, z_j = ybar_j - ybar_{j-1}, are a
stationary Gaussian moving average of order one, exactly (the white part gives weights 1/L, -1/L; the
random walk the triangle s/L, s = 1..L..1, over two blocks):

    gamma_0 = 2 a / L + b (2 L^2 + 1) / (3 L),    gamma_1 = -a / L + b (L^2 - 1) / (6 L),           (1)

with a = N^2 f_s and b = K^2 / f_s, every other autocovariance zero. The estimate maximises the exact
Gaussian log-likelihood of the n increments, whose covariance Sigma is the tridiagonal Toeplitz matrix of
(1) (e.g. Brockwell and Davis, "Time Series: Theory and Methods", 2nd ed., eq. 8.7.4):

    -2 log L(a, b) = n log(2 pi) + log det Sigma + z^T Sigma^-1 z,                                   (2)

with Sigma = L D L^T factored by LAPACK's tridiagonal dpttrf (log det Sigma = sum log D_jj), in O(n). The
factor's recursion, D_{j+1} = gamma_0 - (gamma_1 / D_j) gamma_1, depends on D_j alone: once two successive
D are equal every later one is too, so dpttrf runs on a prefix and, where D has settled there (within
about 2000 steps near the optimum), the rest is its fixed point, the same numbers dpttrf gives for the
whole length; the buffers are reused between evaluations (fresh ones cost page faults).
Sigma = a T(rho), rho = b / a, so a is profiled out, a = z^T T^-1 z / n, and the search runs over rho
alone. The 1-sigma comes from the observed Fisher information: the Hessian of (2) / 2 in (log a, log b)
at the optimum (central differences), inverted.

Whittle's periodogram likelihood would do in O(n log n) but not here: differencing leaves the end term
(w_n - w_0) in every Fourier ordinate, of variance 2 a / (L n), which swamps the random walk's b L at the
low frequencies that carry K (measured: K 5x too large at L = 20 on the 2 h test record).

The information about K lies below the crossing frequency f_c = K / (2 pi N) = sqrt(3) / (2 pi tau_c) of
the two spectra (its Fisher information density falls as (f / f_c)^-4): blocks of tau_c / 200 (at least
BLOCK_S seconds, at most MAX_BLOCKS of them) lose none of it (checked: the exact Fisher information is the
same for 1 to 400-sample blocks on the 2 h test record), bound the memory and time of day-long records,
and make the estimate blind to quantization and to what the sensor's own filter does near the sample
rate. N is measured from the blocks too, less precisely than from the whole band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize
from scipy.linalg import lapack

from station.engines.allan.deviation import strided_phase
from station.errors import EngineInputError

BLOCK_S = 0.1  # seconds per block mean, at least
BLOCKS_PER_CROSSING = 200  # per crossing tau: block rate > 300 f_c, where K has no information left
MAX_BLOCKS = 1 << 20
MIN_BLOCKS = 64
GRID = 17  # points of the coarse search over the crossing frequency
LOWEST_CROSSING = 1e-3  # the search reaches down to a thousandth of the lowest Fourier frequency
HESSIAN_STEP = 0.02  # in log a and log b
SETTLE = 1 << 14  # steps of the factor's recursion tried before the whole length (see the module's text)


@dataclass
class WhiteWalkML:
    """Maximum-likelihood N and K of one axis with their 1-sigma (observed Fisher information).

    ``covariance`` is that of (log a, log b), a = N^2 f_s, b = K^2 / f_s; ``at_bound`` is true where the
    crossing frequency went to an end of the search (no random walk seen, or nothing but a random walk).
    """

    n: float
    k: float
    n_stddev: float
    k_stddev: float
    block: int
    n_increments: int
    covariance: np.ndarray
    at_bound: bool

    @property
    def crossing_tau_s(self) -> float:
        """tau where the white-noise and random-walk Allan variance lines cross: N^2/tau = K^2 tau/3."""
        return math.sqrt(3.0) * self.n / self.k if self.k > 0 else math.inf


def block_length(n_samples: int, rate_hz: float, crossing_tau_s: float | None = None) -> int:
    """Samples per block mean: BLOCK_S seconds, or a BLOCKS_PER_CROSSING-th of the crossing tau where one
    is known (from the Allan curve's fit) and longer, and at most MAX_BLOCKS blocks.

    Parameters
    ----------
    n_samples : int
        Samples of the record.
    rate_hz : float
        Sample rate.
    crossing_tau_s : float, optional
        Where the fitted N and K terms cross, s.

    Returns
    -------
    int
        L, samples per block.
    """
    seconds = BLOCK_S if crossing_tau_s is None else max(BLOCK_S, crossing_tau_s / BLOCKS_PER_CROSSING)
    return max(1, round(seconds * rate_hz), -(-n_samples // MAX_BLOCKS))


def autocovariance(a: float, b: float, block: int) -> tuple[float, float]:
    """(gamma_0, gamma_1) of the block-mean increments, eq. (1).

    Parameters
    ----------
    a, b : float
        N^2 f_s and K^2 / f_s.
    block : int
        L, samples per block.

    Returns
    -------
    tuple of float
    """
    return (2.0 * a / block + b * (2.0 * block * block + 1.0) / (3.0 * block),
            -a / block + b * (block * block - 1.0) / (6.0 * block))


class _Workspace:
    """Buffers of the factor, the solve and the logarithms for ``n`` increments, reused between
    evaluations of the likelihood."""

    def __init__(self, n: int):
        self.d, self.e, self.x, self.log = np.empty(n), np.empty(n - 1), np.empty(n), np.empty(n)


def _factor(gamma0: float, gamma1: float, work: _Workspace) -> tuple[np.ndarray, np.ndarray] | None:
    """D and L's subdiagonal of Sigma = L D L^T by dpttrf, the settled tail filled in (module text);
    None where Sigma is not positive definite."""
    n = len(work.d)
    k = min(n, SETTLE)
    work.d[:k], work.e[:k - 1] = gamma0, gamma1
    d, e, info = lapack.dpttrf(work.d[:k], work.e[:k - 1], overwrite_d=1, overwrite_e=1)
    if info != 0:
        return None
    work.d[:k], work.e[:k - 1] = d, e
    if k == n:
        return work.d, work.e
    if d[-1] == d[-2]:  # settled: every later D is this one, every later subdiagonal gamma1 / D
        work.d[k:], work.e[k - 1:] = d[-1], e[-1]
        return work.d, work.e
    work.d[:], work.e[:] = gamma0, gamma1
    d, e, info = lapack.dpttrf(work.d, work.e, overwrite_d=1, overwrite_e=1)
    return (d, e) if info == 0 else None


def _logdet_and_form(z: np.ndarray, gamma0: float, gamma1: float, work: _Workspace | None = None
                     ) -> tuple[float, float]:
    """log det Sigma and z^T Sigma^-1 z of eq. (2) for the tridiagonal Toeplitz Sigma."""
    work = work if work is not None else _Workspace(len(z))
    factor = _factor(gamma0, gamma1, work)
    if factor is None:
        return math.inf, math.inf
    d, e = factor
    work.x[:] = z
    x, _ = lapack.dpttrs(d, e, work.x, overwrite_b=1)
    return float(np.sum(np.log(d, out=work.log))), float(np.dot(z, x))


def _profile(log_rho: float, z: np.ndarray, block: int, work: _Workspace | None = None) -> float:
    """Eq. (2) with a at its optimum for b = rho a (a = z^T T^-1 z / n), up to a constant."""
    logdet, form = _logdet_and_form(z, *autocovariance(1.0, math.exp(log_rho), block), work)
    return logdet + len(z) * math.log(form / len(z))


def negative_log_likelihood(log_a: float, log_b: float, z: np.ndarray, block: int,
                            work: _Workspace | None = None) -> float:
    """Half of eq. (2) without its constant, in the log parameters.

    Parameters
    ----------
    log_a, log_b : float
        log a and log b of eq. (1).
    z : ndarray, (n,)
        Differenced block means.
    block : int
        L, samples per block.
    work : _Workspace, optional
        Buffers reused between calls (default fresh ones).

    Returns
    -------
    float
    """
    logdet, form = _logdet_and_form(z, *autocovariance(math.exp(log_a), math.exp(log_b), block), work)
    return 0.5 * (logdet + form)


def _hessian(log_a: float, log_b: float, z: np.ndarray, block: int, work: _Workspace) -> np.ndarray:
    """Observed Fisher information: central second differences of the negative log-likelihood."""
    h = HESSIAN_STEP
    p = np.array([log_a, log_b])

    def f(da: float, db: float) -> float:
        return negative_log_likelihood(p[0] + da, p[1] + db, z, block, work)

    f0 = f(0.0, 0.0)
    out = np.empty((2, 2))
    out[0, 0] = (f(h, 0.0) - 2.0 * f0 + f(-h, 0.0)) / h**2
    out[1, 1] = (f(0.0, h) - 2.0 * f0 + f(0.0, -h)) / h**2
    out[0, 1] = out[1, 0] = (f(h, h) - f(h, -h) - f(-h, h) + f(-h, -h)) / (4.0 * h**2)
    return out


def white_walk_ml(phase: np.ndarray, rate_hz: float, block: int | None = None) -> WhiteWalkML:
    """Maximum-likelihood white noise N and rate random walk K of one axis, eqs. (1)-(2).

    Parameters
    ----------
    phase : ndarray, shape (P,)
        Demeaned cumulative sum of the rates (eq. 1 of :mod:`station.engines.allan.deviation`, rate unit times
        seconds); a read-only ``np.memmap`` row is read in pieces and its pages released.
    rate_hz : float
        Sample rate f_s.
    block : int, optional
        Samples per block mean; default :func:`block_length` without a crossing (BLOCK_S seconds).

    Returns
    -------
    WhiteWalkML
        N (unit/sqrt(Hz)) and K (unit/s/sqrt(Hz)) with 1-sigma from the inverse of the observed Fisher
        information (delta method from the log parameters).
    """
    n_samples = len(phase) - 1
    block = block or block_length(n_samples, rate_hz)
    means = np.diff(strided_phase(phase, block)) * (rate_hz / block)  # ybar_j: x is the sum times tau0
    z = np.diff(means)
    if len(z) < MIN_BLOCKS:
        raise EngineInputError(f"{n_samples} samples make {len(means)} block means of {block}: too few "
                               f"for the likelihood of N and K; record at least {MIN_BLOCKS + 2} blocks")
    if not np.any(z):
        raise EngineInputError("the record's block means do not change: no noise to estimate N and K from")
    n = len(z)
    # search over the crossing frequency lambda_c of the two spectra, a g = b h, i.e. rho = g / h there,
    # with g = (4 / L) sin^2(lambda / 2) and h = L - (2 (L^2 - 1) / (3 L)) sin^2(lambda / 2)
    s2 = np.sin(np.pi / n * np.geomspace(LOWEST_CROSSING, n / 2.0, GRID)) ** 2
    grid = np.log(4.0 * s2 / block / (block - 2.0 * (block * block - 1.0) / (3.0 * block) * s2))
    work = _Workspace(n)
    values = [_profile(float(v), z, block, work) for v in grid]
    best = int(np.argmin(values))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, GRID - 1)]
    found = optimize.minimize_scalar(_profile, bounds=(lo, hi), args=(z, block, work), method="bounded",
                                     options={"xatol": 1e-5})
    rho = math.exp(float(found.x))
    a = _logdet_and_form(z, *autocovariance(1.0, rho, block), work)[1] / n
    b = rho * a
    # pinv: flat at an end of the search
    cov = np.linalg.pinv(_hessian(math.log(a), math.log(b), z, block, work))
    sd_log = np.sqrt(np.maximum(np.diag(cov), 0.0))
    n_density = math.sqrt(a / rate_hz)
    k_density = math.sqrt(b * rate_hz)
    return WhiteWalkML(n=n_density, k=k_density, n_stddev=0.5 * sd_log[0] * n_density,
                       k_stddev=0.5 * sd_log[1] * k_density, block=int(block), n_increments=n,
                       covariance=cov, at_bound=best in (0, GRID - 1))
