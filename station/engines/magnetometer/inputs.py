"""What a magnetometer fit may use of a capture: readings that move and are not clipped, the still
samples that give the down direction, and the stretches a magnetic disturbance spoiled.

Each check turns data that cannot be calibrated into an :class:`EngineInputError` that says what is
wrong and what to do. A disturbance (a magnet, a steel desk leg, a motor near the unit) adds a
field of its own for a while: the measured magnitude leaves the level the rest of the capture
holds. Against the magnitude residual r_i = |C (m_i - b)| - F of a first, outlier-resistant fit,
with the robust scatter sigma = 1.4826 median|r - median r|,

    disturbed:  |r_i - median r| > max(k sigma, f F)                                           (1)

(k = ``DISTURBANCE_SIGMAS``, f = ``DISTURBANCE_SHARE``); disturbed samples closer in time than
``DISTURBANCE_JOIN_S`` make one stretch, widened by that much on each side (the field builds up
before it crosses the threshold), and the stretch is left out of the fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.shared.static_detect import moving_variance_norm
from station.errors import EngineInputError

DISTURBANCE_SIGMAS = 6.0
DISTURBANCE_SHARE = 0.01
DISTURBANCE_JOIN_S = 0.25
# A pinned axis: this share of samples (and at least MIN_PINNED) at one extreme while the field's
# direction changes by more than PINNED_MOVE of its size.
PINNED_SHARE, MIN_PINNED, PINNED_MOVE = 0.005, 5, 0.05
# Still: the accelerometer's moving variance (eq. (1) of static_detect) under this multiple of its
# tenth percentile, and |a| within STILL_NORM of its median.
STILL_MULTIPLIER, STILL_NORM = 4.0, 0.02
# Still: turning slower than this, where a gyroscope is given (rad/s, about 6 deg/s; an
# uncalibrated gyro's bias stays well below it).
STILL_RATE = 0.1
# Samples a still stretch needs to count in the gravity check.
MIN_STRETCH = 5


def usable_rows(mag: np.ndarray) -> np.ndarray:
    """Rows holding a magnetometer sample (a magnetometer slower than the IMU leaves NaN rows).

    Parameters
    ----------
    mag : ndarray, (N, 3)
        Raw field, microtesla, NaN where the row has no magnetometer sample.

    Returns
    -------
    ndarray of bool, (N,)

    Raises
    ------
    EngineInputError
        The array is not (N, 3), or no row has a sample.
    """
    mag = np.asarray(mag, float)
    if mag.ndim != 2 or mag.shape[1] != 3:
        raise EngineInputError(f"the magnetometer samples have shape {mag.shape}; the engine takes (N, 3)")
    rows = np.isfinite(mag).all(axis=1)
    if not rows.any():
        raise EngineInputError("the capture holds no magnetometer sample (mx, my, mz are empty): capture "
                               "again from a unit whose magnetometer is switched on and reported")
    return rows


def check_moving(mag: np.ndarray) -> None:
    """Refuse readings that do not move: an axis constant over the capture (stuck, or the zeros of a
    magnetometer that is not running).

    Parameters
    ----------
    mag : ndarray, (n, 3)
        Raw field, microtesla.

    Raises
    ------
    EngineInputError
        Naming the constant axes and their value.
    """
    spread = np.ptp(mag, axis=0)
    size = max(float(np.max(np.abs(mag))), 1e-30)
    stuck = [i for i in range(3) if spread[i] <= 1e-9 * size]
    if stuck:
        axes = ", ".join(f"m{'xyz'[i]} = {mag[0, i]:g} uT" for i in stuck)
        raise EngineInputError(
            f"the magnetometer reads a constant value over the whole capture ({axes}): it is not measuring "
            "(switched off, stuck, or a unit that fills the columns with a fixed value); check that the "
            "unit reports a live magnetometer and capture again while turning it")


def check_not_saturated(mag: np.ndarray) -> None:
    """Refuse readings clipped at the sensor's range: an axis pinned at its largest or smallest value
    while the others show the unit turning.

    Parameters
    ----------
    mag : ndarray, (n, 3)
        Raw field, microtesla.

    Raises
    ------
    EngineInputError
        Naming the axis, the value and how many samples.
    """
    n = len(mag)
    size = float(np.median(np.linalg.norm(mag - np.median(mag, axis=0), axis=1))) or 1.0
    for i in range(3):
        for extreme in (mag[:, i].max(), mag[:, i].min()):
            pinned = mag[:, i] == extreme
            count = int(pinned.sum())
            if count < max(MIN_PINNED, PINNED_SHARE * n):
                continue
            others = np.delete(mag[pinned], i, axis=1)
            if np.ptp(others, axis=0).max() > PINNED_MOVE * size:
                raise EngineInputError(
                    f"the magnetometer's {'xyz'[i]} axis is pinned at {extreme:g} uT in {count} of {n} "
                    "samples while the other axes show the unit turning: it saturated (a magnet, a motor or "
                    "steel too close, or too small a range setting); move the unit away from them, or set "
                    "a larger range, and capture again")


def check_directions(centred: np.ndarray) -> None:
    """Refuse field directions that lie in a plane (the unit turned about one axis only).

    Parameters
    ----------
    centred : ndarray, (n, 3)
        Readings less a first estimate of the hard iron.

    Raises
    ------
    EngineInputError
        When the smallest spread across the directions is under 5 % of the largest.
    """
    unit = centred / np.maximum(np.linalg.norm(centred, axis=1), 1e-300)[:, None]
    sv = np.linalg.svd(unit - unit.mean(axis=0), compute_uv=False)
    if sv[-1] < 0.05 * sv[0]:
        raise EngineInputError(
            "the field directions the capture saw lie nearly in one plane: the unit was turned about one "
            "axis only, which leaves the hard iron and the soft iron along that axis undetermined; capture "
            "again turning the unit about all its axes (tilt it, roll it, and turn it around)")


def still_samples(acc: np.ndarray, gyro: np.ndarray | None, rate_hz: float, window_s: float) -> np.ndarray:
    """Samples at which the unit is still: the accelerometer then measures gravity alone.

    Parameters
    ----------
    acc : ndarray, (N, 3)
        Accelerometer, any unit.
    gyro : ndarray, (N, 3), optional
        Gyroscope, rad/s; also required slow where given.
    rate_hz : float
        Sample rate.
    window_s : float
        Moving-variance window.

    Returns
    -------
    ndarray of bool, (N,)
    """
    acc = np.asarray(acc, float)
    n = len(acc)
    window = max(3, int(round(window_s * rate_hz)) | 1)
    still = np.zeros(n, bool)
    if n < window:
        return still
    v = moving_variance_norm(acc, window)
    floor = float(np.percentile(v, 10))
    half = window // 2
    still[half:n - half] = v <= STILL_MULTIPLIER * max(floor, 1e-300)
    norm = np.linalg.norm(acc, axis=1)
    still &= np.abs(norm - np.median(norm)) <= STILL_NORM * np.median(norm)
    if gyro is not None:
        still &= np.linalg.norm(np.asarray(gyro, float), axis=1) <= STILL_RATE
    return still


def gravity_spread(acc: np.ndarray, still: np.ndarray) -> float | None:
    """Relative scatter of |a| between the still stretches: std / median of each stretch's mean.

    A calibrated accelerometer reads the same |g| at every pose (scatter of a few 1e-4); an
    uncalibrated one, whose bias and scale errors also tilt the down direction by up to degrees,
    scatters by 1e-3 to 1e-2.

    Parameters
    ----------
    acc : ndarray, (N, 3)
        Accelerometer.
    still : ndarray of bool, (N,)
        :func:`still_samples`.

    Returns
    -------
    float or None
        None with fewer than three stretches of at least ``MIN_STRETCH`` samples.
    """
    means = [float(np.linalg.norm(acc[a:b], axis=1).mean()) for a, b in still_stretches(still)]
    if len(means) < 3:
        return None
    return float(np.std(means) / np.median(means))


def still_stretches(still: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of ``still`` at least ``MIN_STRETCH`` samples long.

    Parameters
    ----------
    still : ndarray of bool, (N,)
        :func:`still_samples`.

    Returns
    -------
    list of (int, int)
    """
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= MIN_STRETCH]


def still_noise(mag: np.ndarray, still: np.ndarray) -> float | None:
    """The magnetometer's noise, microtesla: the median over the still stretches of the per-axis
    standard deviation (pooled over the axes), the field being constant while the unit is still.

    Parameters
    ----------
    mag : ndarray, (N, 3)
        Raw field.
    still : ndarray of bool, (N,)
        :func:`still_samples`.

    Returns
    -------
    float or None
        None without a still stretch.
    """
    sds = [float(np.sqrt(np.mean(np.var(mag[a:b], axis=0, ddof=1)))) for a, b in still_stretches(still)]
    return float(np.median(sds)) if sds else None


@dataclass(frozen=True)
class Disturbance:
    """A stretch left out by eq. (1): first and last time (s) and the largest |r| (microtesla)."""

    t0: float
    t1: float
    peak_ut: float

    def describe(self) -> str:
        """``12.3-15.0 s (field off by 4.2 uT)``."""
        return f"{self.t0:.1f}-{self.t1:.1f} s (field off by {self.peak_ut:.2g} uT)"


def disturbed(t: np.ndarray, residual: np.ndarray, field: float) -> tuple[np.ndarray, list[Disturbance]]:
    """Eq. (1): the samples in disturbed stretches, and the stretches.

    Parameters
    ----------
    t : ndarray, (n,)
        Sample times, s.
    residual : ndarray, (n,)
        |C (m - b)| - F of a first fit, microtesla.
    field : float
        F, microtesla.

    Returns
    -------
    tuple
        Boolean mask (n,) of the samples to leave out, and the stretches in time order.
    """
    r = residual - np.median(residual)
    sigma = 1.4826 * float(np.median(np.abs(r)))
    bad = np.abs(r) > max(DISTURBANCE_SIGMAS * sigma, DISTURBANCE_SHARE * field)
    out = np.zeros(len(t), bool)
    stretches: list[Disturbance] = []
    if not bad.any():
        return out, stretches
    times = t[bad]
    splits = np.flatnonzero(np.diff(times) > DISTURBANCE_JOIN_S) + 1
    for group in np.split(np.arange(len(times)), splits):
        t0 = times[group[0]] - DISTURBANCE_JOIN_S
        t1 = times[group[-1]] + DISTURBANCE_JOIN_S
        inside = (t >= t0) & (t <= t1)
        out |= inside
        stretches.append(Disturbance(float(max(t0, t[0])), float(min(t1, t[-1])),
                                     float(np.max(np.abs(r[inside])))))
    return out, stretches
