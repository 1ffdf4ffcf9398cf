"""The compiled inner loop of the overlapping Allan variance (eq. 2 of
:mod:`station.engines.allan.deviation`).

numpy needs two subtractions and a dot product per cluster size, three passes over each block, each
writing a buffer; one fused loop reads the three windows once and keeps the sum in registers. numba
compiles it on first use (cached on disk beside this module, or in numba's user cache where that is
read-only), so only a command that computes an Allan deviation imports it.

The loop forms each term as ``(x_{i+2m} - x_{i+m}) - (x_{i+m} - x_i)``: two differences of similar size
lose less than ``2 x_{i+m}``. Only the running sum may be reassociated (``fastmath={"reassoc"}``), which
lets the compiler split it over vector lanes; that changes the sum's rounding, not the terms' (checked
against long-double sums to 2e-15 in the tests).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(nogil=True, cache=True, fastmath={"reassoc"}, boundscheck=False)
def add_block(x: np.ndarray, m: np.ndarray, start: int, length: int, totals: np.ndarray) -> int:
    """Add ``sum_i v_i^2`` of eq. (2) over ``i`` in ``[start, start + length)`` to ``totals[k]`` for each
    cluster size ``m[k]``, the range cut at ``P - 2 m`` (``P = len(x)``).

    Parameters
    ----------
    x : ndarray, (P,) float64
        Phase of eq. (1), contiguous.
    m : ndarray of int64
        Cluster sizes, ascending.
    start, length : int
        The block of ``i``.
    totals : ndarray, (len(m),) float64
        Sums, added to in place.

    Returns
    -------
    int
        How many of the cluster sizes reached the block (the others end before ``start``).
    """
    n_phase = len(x)
    for k in range(len(m)):
        mk = m[k]
        count = min(length, n_phase - 2 * mk - start)
        if count <= 0:
            return k
        x0 = x[start:start + count]
        x1 = x[start + mk:start + mk + count]
        x2 = x[start + 2 * mk:start + 2 * mk + count]
        s = 0.0
        for i in range(count):
            v = (x2[i] - x1[i]) - (x1[i] - x0[i])
            s += v * v
        totals[k] += s
    return len(m)
