"""Static-interval detection by moving variance (Tedaldi, Pretto, Menegatti, ICRA 2014, sec. IV-A).

For every sample i with a full centred window of w = 2h + 1 samples, the variance of each axis
over the window (unbiased, 1/(w-1)) is taken and its Euclidean norm over the three axes,

    v_i = || var(x_{i-h} .. x_{i+h}) ||                                            (1)

is compared with a threshold: a static interval starts at the first i with v_i < threshold
and ends just before the first later i with v_i >= threshold (``end`` is the last static
index, inclusive); an interval still open at the last window centre ends there. These are
imu_tk's ``staticIntervalsDetector`` semantics (upstream version), so its results can be
reproduced.
The threshold is a multiple of (1) computed over the initial still period.
"""

from __future__ import annotations

import numpy as np

# Rows per chunk of the windowed variance: keeps the running sums small.
_CHUNK = 4096


def moving_variance_norm(x: np.ndarray, window: int) -> np.ndarray:
    """Eq. (1) for every window centre h .. N-h-1.

    Windowed sums from cumulative sums, taken chunk by chunk about each chunk's mean so the
    sums stay small (raw counts around 32768 lose nothing): var = (S2 - S1^2 / w) / (w - 1).

    Parameters
    ----------
    x : ndarray, (N, 3)
        Samples.
    window : int
        Window length w = 2h + 1, samples.

    Returns
    -------
    ndarray, (N - 2h,)
    """
    x = np.asarray(x, float)
    n = len(x)
    if window < 3 or window % 2 == 0:
        raise ValueError(f"moving-variance window must be odd and >= 3 samples, got {window}")
    if n < window:
        return np.zeros(0)
    out = np.empty(n - window + 1)
    for start in range(0, n - window + 1, _CHUNK):
        stop = min(start + _CHUNK, n - window + 1)
        part = x[start:stop + window - 1]
        part = part - part.mean(axis=0)
        c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(part, axis=0)])
        c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(part * part, axis=0)])
        s1 = c1[window:] - c1[:-window]
        s2 = c2[window:] - c2[:-window]
        var = np.clip((s2 - s1 * s1 / window) / (window - 1), 0.0, None)
        out[start:stop] = np.linalg.norm(var, axis=1)
    return out


def variance_norm(x: np.ndarray) -> float:
    """Eq. (1) over all of ``x`` (the initial still period): || var(x) ||, unbiased.

    Parameters
    ----------
    x : ndarray, (N, 3)

    Returns
    -------
    float
    """
    x = np.asarray(x, float)
    if len(x) < 2:
        raise ValueError("the still period needs at least two samples")
    return float(np.linalg.norm(x.var(axis=0, ddof=1)))


def static_intervals(vnorm: np.ndarray, threshold: float, half: int) -> np.ndarray:
    """Intervals of sample indices where eq. (1) stays under ``threshold``.

    Parameters
    ----------
    vnorm : ndarray
        :func:`moving_variance_norm`'s output (index 0 is sample ``half``).
    threshold : float
        Variance-norm threshold.
    half : int
        Half window h.

    Returns
    -------
    ndarray, (K, 2)
        [start, end] of each interval, both inclusive.
    """
    still = np.asarray(vnorm) < threshold
    if len(still) == 0:
        return np.zeros((0, 2), dtype=int)
    edges = np.diff(still.astype(np.int8))
    starts = [int(i) for i in np.flatnonzero(edges == 1) + 1]
    ends = [int(i) for i in np.flatnonzero(edges == -1)]
    if still[0]:
        starts.insert(0, 0)
    if still[-1]:
        ends.append(len(still) - 1)
    return np.column_stack([starts, ends]).astype(int) + half if starts else np.zeros((0, 2), dtype=int)
