"""Checks every engine's input object runs once on its sample arrays: shapes, finiteness, rate.

The engines take a time column ``t`` (N,) in s and triads ``acc``/``gyro`` (N, 3); these
checks turn arrays that cannot be calibrated into an :class:`EngineInputError` that says
which array is wrong and where, before any fit sees them.
"""

from __future__ import annotations

import numpy as np

from station.errors import EngineInputError

# Largest relative disagreement between a stated sample rate and the timestamps.
RATE_TOLERANCE = 0.02


def as_samples(t: object, acc: object, gyro: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sample arrays as float arrays, checked for shape and finiteness.

    Parameters
    ----------
    t : array_like, (N,)
        Sample times, s.
    acc, gyro : array_like, (N, 3)
        Raw triad samples, one row per time of ``t``.

    Returns
    -------
    tuple of ndarray
        ``t``, ``acc`` and ``gyro`` as float arrays, the triads column-major (Fortran order).

    Raises
    ------
    EngineInputError
        An array of the wrong shape, or a value that is NaN or infinite (naming the first).
    """
    t = np.asarray(t, float)
    if t.ndim != 1:
        raise EngineInputError(f"the time column has shape {t.shape}; the engines take one time per "
                               "sample, (N,)")
    arrays = {"t": t}
    for name, values in (("acc", acc), ("gyro", gyro)):
        x = np.asarray(values, float)
        if x.shape != (len(t), 3):
            raise EngineInputError(f"{name} has shape {x.shape}; the engines take ({len(t)}, 3): three axes "
                                   "per sample, one row per time")
        # column-major: the engines reduce over samples (each step's mean and variance, axis 0), which
        # on rows of three runs numpy's inner loop three elements at a time (a 45,000-sample step's std:
        # 1.16 ms against 0.08 ms); one copy of each triad
        arrays[name] = np.asfortranarray(x)
    for name, x in arrays.items():
        bad = np.flatnonzero(~np.isfinite(x).reshape(len(t), -1).all(axis=1))
        if len(bad):
            raise EngineInputError(f"{name} is NaN or infinite in {len(bad)} of {len(t)} samples (the first "
                                   f"is sample {bad[0]}): repair or drop those samples before calibrating")
    return arrays["t"], arrays["acc"], arrays["gyro"]


def check_rate(t: np.ndarray, rate_hz: float | None) -> None:
    """Refuse a stated sample rate that the timestamps contradict (median step, 2 % tolerance).

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    rate_hz : float or None
        The rate the device was set to; None checks only that there are two samples.

    Raises
    ------
    EngineInputError
        Fewer than two samples, or a rate more than ``RATE_TOLERANCE`` away from 1 / median(diff t).
    """
    if len(t) < 2:
        raise EngineInputError("the capture has fewer than two samples")
    measured = 1.0 / float(np.median(np.diff(t)))
    if rate_hz is not None and abs(measured - rate_hz) > RATE_TOLERANCE * rate_hz:
        raise EngineInputError(
            f"the stated sample rate {rate_hz:g} Hz disagrees with the timestamps ({measured:.3f} Hz from "
            "the median step): check the device's rate setting or the capture's time column")
