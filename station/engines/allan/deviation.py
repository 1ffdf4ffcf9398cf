"""Overlapping Allan deviation of IMU rate records, with the EDF and confidence interval of each point.

The record of one axis, ``y_k`` (rate or specific force, sampled every ``tau0 = 1 / rate_hz``), is first
integrated into the demeaned cumulative sum (the "phase" of the frequency-stability literature)

    x_0 = 0,    x_{k+1} = x_k + (y_k - mean(y)) tau0                                     (1)

in float64, and the overlapping Allan variance at ``tau = m tau0`` is (NIST SP 1065, eq. 11)

    sigma^2(tau) = 1 / (2 tau^2 (P - 2m)) * sum_{i=0}^{P-2m-1} (x_{i+2m} - 2 x_{i+m} + x_i)^2   (2)

with ``P = N + 1`` phase points. The sums of eq. (2) are formed block by block by a compiled loop
(:mod:`station.engines.allan._kernel`), each block for every cluster size before the next, so the windows
of ``x`` a block reads stay in the CPU cache between cluster sizes. Block ranges run on a thread pool (the
compiled loop releases the GIL). Rows that are read-only file maps (``np.memmap``) have their pages
released once read, so a day-long record held on disk never becomes resident as a whole.

Uncertainty: each point's equivalent degrees of freedom (Greenhall and Riley 2003) and chi-square
interval (NIST SP 1065, eq. 45) are computed in :mod:`station.engines.allan.uncertainty`; its public
functions are importable from here too, where they were first.
"""

from __future__ import annotations

import math
import mmap
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

# The EDF and interval of each point are the uncertainty module's. Callers import its names from here too
# (the aliases re-export them), and tests/test_allan_engine.py checks the exact white-phase EDF against
# Greenhall's kernels through this module.
from station.engines.allan.uncertainty import ONE_SIGMA as ONE_SIGMA
from station.engines.allan.uncertainty import _basic_sum as _basic_sum
from station.engines.allan.uncertainty import _sz as _sz
from station.engines.allan.uncertainty import alpha_from_slope, confidence_interval, edf_table
from station.engines.allan.uncertainty import greenhall_edf as greenhall_edf
from station.errors import EngineInputError

BLOCK = 131_072  # phase points per block: its windows stay in L2/L3 cache for every m
MIN_SAMPLES = 16
INTEGRATE_ROWS = 1 << 20
_FAULT_AROUND = 1 << 21  # bytes: fault-around (64 kB) or a whole large folio (up to 2 MB)

ProgressCallback = Callable[[int, int], None]


def cluster_sizes(n_samples: int, per_decade: int = 10, max_fraction: float = 0.25) -> np.ndarray:
    """Unique integer cluster sizes ``m``, log-spaced with at least ``per_decade`` per decade, up to N/4.

    Every integer 1..10 is kept (rounding a log grid would merge the first decade's points); above that
    the grid is ``round(10^(k / per_decade))`` with duplicates merged (none for 10 per decade).

    Parameters
    ----------
    n_samples : int
        Samples N of the record.
    per_decade : int
        Least number of sizes per decade.
    max_fraction : float
        Largest m as a fraction of N.

    Returns
    -------
    ndarray of int
    """
    m_max = int(math.floor(n_samples * max_fraction))
    if m_max < 1:
        raise EngineInputError(f"{n_samples} samples are too few for an Allan deviation; record at least "
                               f"{MIN_SAMPLES} samples (in practice hours of still data)")
    k_max = int(math.floor(per_decade * math.log10(m_max))) + 1
    grid = np.round(10.0 ** (np.arange(k_max) / per_decade)).astype(np.int64)
    m = np.unique(np.concatenate([np.arange(1, 11), grid]))
    return m[m <= m_max]


def _workspace(rows: int, cols: int) -> np.ndarray:
    """A float64 array on its own anonymous map, its pages populated at once. numpy asks the kernel for
    huge pages on large arrays, which stalls on compaction where THP defrag is 'madvise' (4x slower to
    fault in, measured); one page fault per small page costs 2x more than populating the map in one call
    (measured: 80 MB in 0.05 s against 0.09 s). The buffer is written once and read in cache-sized blocks,
    so small pages cost nothing after that."""
    size = max(rows * cols * 8, 8)
    flags = mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS | getattr(mmap, "MAP_POPULATE", 0)
    return np.frombuffer(mmap.mmap(-1, size, flags=flags), dtype=np.float64)[:rows * cols].reshape(rows, cols)


def integrate_rates(rates: np.ndarray, rate_hz: float) -> np.ndarray:
    """Demeaned cumulative sums of eq. (1), one contiguous row per axis: shape (axes, N + 1), float64.

    Parameters
    ----------
    rates : ndarray, (N,) or (N, axes)
        Evenly sampled rates.
    rate_hz : float
        Sample rate.

    Returns
    -------
    ndarray, (axes, N + 1)
        x of eq. (1), in the rate unit times seconds.
    """
    y = np.asarray(rates, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    tau0 = 1.0 / float(rate_hz)
    n = y.shape[0]
    phase = _workspace(y.shape[1], n + 1)
    buf = np.empty(min(n, INTEGRATE_ROWS) + 1)
    for j in range(y.shape[1]):
        col = y[:, j]
        mean = np.mean(col)
        phase[j, 0] = 0.0
        carry = 0.0
        # in pieces, each prefixed with the running sum: the sequential float64 sum of the whole column
        # without a second full-length temporary
        for a in range(0, n, INTEGRATE_ROWS):
            length = min(INTEGRATE_ROWS, n - a)
            part = buf[:length + 1]
            part[0] = carry
            np.subtract(col[a:a + length], mean, out=part[1:])
            np.cumsum(part, out=part)
            carry = float(part[-1])
            np.multiply(part[1:], tau0, out=phase[j, 1 + a:1 + a + length])
    return phase


def _mapped(x: np.ndarray) -> mmap.mmap | None:
    """The map of a row read from a read-only file map (``np.memmap`` mode "r"), else None: dropping pages
    of a private or anonymous map would lose their contents."""
    mm = x.base if isinstance(x.base, mmap.mmap) and getattr(x, "mode", None) == "r" else None
    return mm if mm is not None and hasattr(mm, "madvise") else None


def _release(x: np.ndarray, start: int, stop: int) -> None:
    """Drop pages of a file-backed row from this process once read: memory stays bounded on day-long
    records (the pages stay in the page cache, the next read is a cheap minor fault)."""
    mm = _mapped(x)
    if mm is None:
        return
    # a fault maps the pages around it (fault-around, or a whole large folio of the page cache), before
    # the window too: release that much behind the start as well (those pages were read already)
    start = max(start - _FAULT_AROUND // x.itemsize, 0)
    first = (start * x.itemsize) // mmap.PAGESIZE * mmap.PAGESIZE
    last = min(stop * x.itemsize, len(mm))
    if last > first:
        mm.madvise(mmap.MADV_DONTNEED, first, last - first)


def strided_phase(x: np.ndarray, step: int, piece: int = 1 << 21) -> np.ndarray:
    """``x[::step]`` of a phase row, read a piece at a time: the pages of a read-only file map are released
    once read, so a day-long record on disk never becomes resident as a whole.

    Parameters
    ----------
    x : ndarray, (P,)
        A phase row (an ``np.memmap`` row, or in memory).
    step : int
        Stride.
    piece : int
        Elements of the row spanned at a time (every page of the span is read when the stride is below a
        page: bounding the output's length instead made a 48 h record's span 800 MB resident at once).

    Returns
    -------
    ndarray
    """
    out = np.empty((len(x) - 1) // step + 1)
    piece = max(1, piece // step)  # outputs per piece
    for i in range(0, len(out), piece):
        j = min(i + piece, len(out))
        out[i:j] = x[i * step:(j - 1) * step + 1:step]
        _release(x, i * step, (j - 1) * step + 1)
    return out


def _sums(x: np.ndarray, m: np.ndarray, first: int, stop: int, block: int) -> np.ndarray:
    """sum_i v_i^2 of eq. (2) for i in [first, stop) and every m (ascending), block by block.

    Each block of i is done for every m before the next (:func:`station.engines.allan._kernel.add_block`),
    so the windows a block reads stay in cache between cluster sizes: every m up to the block length
    reads the same window of x, and on a log grid the far window x[a + 2 m_k] is close to x[a + m_{k+3}],
    so most far windows come from memory once, not twice. The pages of a read-only file map are released
    once a block has read them.
    """
    from station.engines.allan._kernel import add_block  # numba: only a command computing a deviation

    totals = np.zeros(len(m))
    row = x.view(np.ndarray)  # the compiled loop takes a plain array; a np.memmap row is one
    mapped = _mapped(x)
    near_max = int(m[m <= block].max()) if np.any(m <= block) else 0
    for a in range(first, stop, block):
        length = min(block, stop - a)
        reached = add_block(row, m, a, length, totals)
        if mapped:
            for mk in m[:reached].tolist():
                if mk > block:
                    _release(x, a + mk, a + mk + length)
                    _release(x, a + 2 * mk, a + 2 * mk + length)
            _release(x, a, a + length)
    if mapped:
        _release(x, stop, stop + block + 2 * near_max)  # the near windows' reach past this task's range
    return totals


def overlapping_adev_phase(phase: np.ndarray | Sequence[np.ndarray], rate_hz: float,
                           cluster_sizes: Sequence[int] | np.ndarray, workers: int | None = None,
                           block: int = BLOCK, on_progress: ProgressCallback | None = None) -> np.ndarray:
    """Overlapping Allan deviation, eq. (2), from integrated records (eq. 1).

    Parameters
    ----------
    phase : ndarray, shape (P,) or (axes, P), or a sequence of (P,) arrays
        Cumulative sums ``x`` of eq. (1), in the rate unit times seconds; rows contiguous (``np.memmap``
        rows keep day-long records out of memory).
    rate_hz : float
        Sample rate; ``tau = m / rate_hz``.
    cluster_sizes : sequence of int
        Averaging factors ``m``, each ``1 <= m <= (P - 1) / 2``.
    workers : int, optional
        Threads; default the number of cores.
    block : int
        Buffer length of the blocked second differences.
    on_progress : callable, optional
        ``on_progress(done, total)`` after each task (a range of blocks of one axis), in the calling thread.

    Returns
    -------
    ndarray, shape (len(cluster_sizes),) or (len(cluster_sizes), axes)
        Allan deviation in the rate unit.
    """
    one_axis = isinstance(phase, np.ndarray) and phase.ndim == 1
    x = [phase] if one_axis else list(phase)
    m = np.asarray(cluster_sizes, dtype=np.int64)
    p = len(x[0])
    if any(len(row) != p for row in x):
        raise EngineInputError("every axis must have the same number of samples")
    if len(m) and (m.min() < 1 or 2 * m.max() >= p):
        raise EngineInputError(f"cluster sizes must lie in 1..{(p - 1) // 2} for {p - 1} samples; "
                               f"got {int(m.min())}..{int(m.max())}")
    workers = workers or os.cpu_count() or 1
    order = np.argsort(m, kind="stable")  # the kernel takes m ascending
    n_first = p - 2 * int(m.min()) if len(m) else 0  # second differences of the smallest m
    # contiguous block ranges, a few per worker and axis for balance, block-aligned
    per = max(block, -(-n_first // (4 * workers)) // block * block)
    tasks = [(j, a, min(a + per, n_first)) for j in range(len(x)) for a in range(0, n_first, per)]
    sums = np.zeros((len(m), len(x)))
    done = 0

    def run(task: tuple[int, int, int]) -> tuple[int, np.ndarray]:
        j, a, b = task
        return j, _sums(x[j], m[order], a, b, block)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        for j, part in pool.map(run, tasks):
            sums[order, j] += part
            done += 1
            if on_progress is not None:
                on_progress(done, len(tasks))
    tau = m / float(rate_hz)
    n_terms = p - 2 * m
    adev = np.sqrt(sums / (2.0 * (tau**2 * n_terms))[:, None])
    return adev[:, 0] if one_axis else adev


def overlapping_adev(rates: np.ndarray, rate_hz: float, cluster_sizes: Sequence[int] | np.ndarray,
                     workers: int | None = None) -> np.ndarray:
    """Overlapping Allan deviation of rate records at ``tau = m / rate_hz``, eqs. (1)-(2).

    Parameters
    ----------
    rates : ndarray, shape (N,) or (N, axes)
        Evenly sampled rates (rad/s, m/s^2, or any unit).
    rate_hz : float
        Sample rate in Hz.
    cluster_sizes : sequence of int
        Averaging factors ``m`` (see :func:`cluster_sizes`).
    workers : int, optional
        Threads; default the number of cores.

    Returns
    -------
    ndarray, shape (len(cluster_sizes),) or (len(cluster_sizes), axes)
        Allan deviation, in the unit of ``rates``.
    """
    y = np.asarray(rates)
    if y.ndim not in (1, 2) or len(y) < 2:
        raise EngineInputError("rates must be an (N,) or (N, axes) array with N >= 2")
    adev = overlapping_adev_phase(integrate_rates(y, rate_hz), rate_hz, cluster_sizes, workers=workers)
    return adev[:, 0] if y.ndim == 1 else adev


def nonoverlapping_adev(rates: np.ndarray, rate_hz: float, cluster_sizes: Sequence[int] | np.ndarray
                        ) -> np.ndarray:
    """Non-overlapping Allan deviation (NIST SP 1065, eq. 7) of a 1-D rate record, for comparison.

    ``sigma^2(m tau0) = 1 / (2 tau^2 (K - 2)) sum_{k} (x_{(k+2)m} - 2 x_{(k+1)m} + x_{km})^2`` over the
    ``K = floor((P - 1) / m) + 1`` phase points ``x_0, x_m, x_2m, ...`` of eq. (1).

    Parameters
    ----------
    rates : ndarray, (N,)
        Evenly sampled rates.
    rate_hz : float
        Sample rate.
    cluster_sizes : sequence of int
        Averaging factors m.

    Returns
    -------
    ndarray, (len(cluster_sizes),)
        Allan deviation, in the unit of ``rates``.
    """
    x = integrate_rates(np.asarray(rates, dtype=np.float64).reshape(-1), rate_hz)[0]
    out = np.empty(len(cluster_sizes))
    for i, m in enumerate(np.asarray(cluster_sizes, dtype=np.int64)):
        xs = x[::m]
        if len(xs) < 3:
            raise EngineInputError(f"cluster size {m} is too large for {len(x) - 1} samples")
        v = xs[2:] - 2.0 * xs[1:-1] + xs[:-2]
        tau = m / float(rate_hz)
        out[i] = math.sqrt(float(np.dot(v, v)) / (2.0 * tau**2 * len(v)))
    return out



@dataclass
class AllanCurve:
    """Overlapping Allan deviation of several axes at the same cluster sizes.

    ``adev``, ``edf``, ``ci_low``, ``ci_high`` and ``alpha`` have shape (len(m), axes); ``n`` is the number of
    second differences averaged at each point (P - 2m); the interval is the 68.27 % one.
    """

    axes: tuple[str, ...]
    rate_hz: float
    n_samples: int
    m: np.ndarray
    tau: np.ndarray
    n: np.ndarray
    adev: np.ndarray
    edf: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    alpha: np.ndarray

    @property
    def duration_s(self) -> float:
        """Length of the record, n_samples / rate_hz, s."""
        return self.n_samples / self.rate_hz

    def with_alpha(self, alpha: np.ndarray) -> AllanCurve:
        """The same curve with EDF and intervals recomputed for other noise types (e.g. from a fit).

        Parameters
        ----------
        alpha : ndarray of int, (M, axes)
            Noise type per point and axis.

        Returns
        -------
        AllanCurve
        """
        edf = edf_table(alpha, self.m, self.n_samples + 1)
        lo, hi = confidence_interval(self.adev, edf)
        return AllanCurve(self.axes, self.rate_hz, self.n_samples, self.m, self.tau, self.n, self.adev, edf,
                          lo, hi, np.asarray(alpha, dtype=np.int64))




def allan_curve(phase: np.ndarray | Sequence[np.ndarray], rate_hz: float, axes: Sequence[str],
                m: np.ndarray | None = None, workers: int | None = None,
                on_progress: ProgressCallback | None = None) -> AllanCurve:
    """Allan deviation, EDF and 68 % intervals of integrated records (eq. 1), noise type from the slope.

    Parameters
    ----------
    phase : ndarray, shape (axes, P), or a sequence of (P,) arrays
        Demeaned cumulative sums, see :func:`integrate_rates` (``np.memmap`` rows keep memory bounded).
    rate_hz : float
        Sample rate in Hz.
    axes : sequence of str
        Names of the rows, e.g. ("gx", "gy", "gz", "ax", "ay", "az").
    m : ndarray, optional
        Cluster sizes; default :func:`cluster_sizes` of the record.
    workers, on_progress
        See :func:`overlapping_adev_phase`.
    """
    n_samples = len(phase[0]) - 1
    if n_samples < MIN_SAMPLES:
        raise EngineInputError(f"{n_samples} samples are too few for an Allan deviation; record at least "
                               f"{MIN_SAMPLES} (in practice hours of still data)")
    m = cluster_sizes(n_samples) if m is None else np.asarray(m, dtype=np.int64)
    adev = overlapping_adev_phase(phase, rate_hz, m, workers=workers, on_progress=on_progress)
    tau = m / float(rate_hz)
    alpha = alpha_from_slope(tau, adev)
    edf = edf_table(alpha, m, n_samples + 1)
    lo, hi = confidence_interval(adev, edf)
    return AllanCurve(tuple(axes), float(rate_hz), int(n_samples), m, tau, n_samples + 1 - 2 * m, adev, edf,
                      lo, hi, alpha)
