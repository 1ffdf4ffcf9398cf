"""Pure checks of raw samples during a sequence: stillness, pose, saturation, dropouts, rotation.

Arrays in, small result dataclasses out; the runner calls them on a sliding window at the UI
rate and on each finished step. Values are raw (uncalibrated), so the limits leave room for
the bias, scale and misalignment that the calibration is about to find.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SEQ_MODULUS = 2**32


@dataclass(frozen=True)
class Limits:
    """Thresholds of the checks, in SI units. ``acc_saturation``/``gyro_saturation`` None: detect clipping."""

    still_acc_std: float = 0.08  # m/s^2, per-axis standard deviation over the window
    still_gyro_std: float = 0.03  # rad/s
    still_gyro_mean: float = 0.25  # rad/s: a steady turn has a small spread but a large mean
    still_window_s: float = 0.5
    pose_tolerance_deg: float = 12.0
    rotation_tolerance_deg: float = 10.0
    rotation_tolerance_frac: float = 0.05
    acc_saturation: float | None = None
    gyro_saturation: float | None = None
    max_lost_fraction: float = 0.001


@dataclass(frozen=True)
class Stillness:
    """How still the window was: ``level`` <= 1 is still; ``score`` is 1 when still, towards 0 when moving."""

    acc_std: float
    gyro_std: float
    gyro_mean: float
    level: float

    @property
    def still(self) -> bool:
        """True when every measure is within its limit (level <= 1)."""
        return self.level <= 1.0

    @property
    def score(self) -> float:
        """1 when still, else 1 / level: a bar for the operator."""
        return 1.0 if self.level <= 1.0 else 1.0 / self.level


def stillness(acc: np.ndarray, gyro: np.ndarray, limits: Limits = Limits()) -> Stillness:
    """Largest per-axis standard deviation of acc and gyro, and the mean turn rate, against the limits.

    ``level`` is the largest of std/limit ratios; an empty window is not still (level = inf).

    Parameters
    ----------
    acc, gyro : ndarray, (N, 3)
        The window's samples, m/s^2 and rad/s.
    limits : Limits

    Returns
    -------
    Stillness
    """
    acc = np.asarray(acc, float)
    gyro = np.asarray(gyro, float)
    if len(acc) < 2:
        return Stillness(math.nan, math.nan, math.nan, math.inf)
    acc_std = float(np.max(np.std(acc, axis=0)))
    gyro_std = float(np.max(np.std(gyro, axis=0)))
    gyro_mean = float(np.linalg.norm(np.mean(gyro, axis=0)))
    level = max(acc_std / limits.still_acc_std, gyro_std / limits.still_gyro_std,
                gyro_mean / limits.still_gyro_mean)
    return Stillness(acc_std, gyro_std, gyro_mean, level)


@dataclass(frozen=True)
class PoseCheck:
    """Angle between the measured up direction and the asked one; ``nearest`` names the pose it is in."""

    angle_deg: float
    measured_up: tuple[float, float, float]
    nearest: str
    ok: bool


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two vectors in degrees, stable near 0 and 180 (atan2 of cross and dot).

    Parameters
    ----------
    a, b : ndarray, (3,)

    Returns
    -------
    float
    """
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    return math.degrees(math.atan2(float(np.linalg.norm(np.cross(a, b))), float(np.dot(a, b))))


def _candidate_poses() -> tuple[np.ndarray, list[str]]:
    signs = [np.array([sx, sy, sz], float) for sx in (-1, 0, 1) for sy in (-1, 0, 1) for sz in (-1, 0, 1)]
    signs = [v for v in signs if v.any()]
    labels = ["".join(("+" if c > 0 else "-") + a for c, a in zip(v, "xyz", strict=True) if c) for v in signs]
    return np.array([v / np.linalg.norm(v) for v in signs]), labels


_POSES, _POSE_LABELS = _candidate_poses()


def nearest_pose(up: np.ndarray) -> str:
    """The label nearest to ``up`` among the 26 poses of +-x, +-y, +-z and their diagonals.

    Parameters
    ----------
    up : ndarray, (3,)
        A direction in sensor axes.

    Returns
    -------
    str
    """
    up = np.asarray(up, float)
    return _POSE_LABELS[int(np.argmax(_POSES @ up))]


def pose_check(acc: np.ndarray, up: np.ndarray, tolerance_deg: float) -> PoseCheck:
    """Is the mean specific force of ``acc`` (N, 3) along the asked ``up`` vector, within tolerance?

    A unit at rest reads specific force +g along the axis that points up, so the measured up
    direction is the normalised mean of the accelerometer.

    Parameters
    ----------
    acc : ndarray, (N, 3)
        Accelerometer samples, m/s^2.
    up : ndarray, (3,)
        The asked up vector.
    tolerance_deg : float

    Returns
    -------
    PoseCheck
    """
    acc = np.asarray(acc, float)
    if len(acc) == 0:
        return PoseCheck(math.nan, (math.nan,) * 3, "", False)
    mean = acc.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    if norm == 0.0:
        return PoseCheck(math.nan, (0.0, 0.0, 0.0), "", False)
    measured = mean / norm
    angle = angle_between_deg(measured, up)
    measured_up = (float(measured[0]), float(measured[1]), float(measured[2]))
    return PoseCheck(angle, measured_up, nearest_pose(measured), angle <= tolerance_deg)


def vertical_axis_check(acc: np.ndarray, axis: int, tolerance_deg: float) -> PoseCheck:
    """Is sensor axis ``axis`` vertical (up or down), as a rotation about it asks?

    Parameters
    ----------
    acc : ndarray, (N, 3)
        Accelerometer samples, m/s^2.
    axis : int
        0, 1 or 2.
    tolerance_deg : float

    Returns
    -------
    PoseCheck
    """
    acc = np.asarray(acc, float)
    up = np.zeros(3)
    up[axis] = 1.0
    if len(acc) and acc.mean(axis=0)[axis] < 0:
        up[axis] = -1.0
    return pose_check(acc, up, tolerance_deg)


@dataclass(frozen=True)
class Saturation:
    """Samples at the sensor's limit, per triad; ``ok`` when there are none."""

    acc_samples: int
    gyro_samples: int

    @property
    def ok(self) -> bool:
        """True when no accelerometer or gyroscope sample is clipped."""
        return self.acc_samples == 0 and self.gyro_samples == 0


def clipped_samples(x: np.ndarray, limit: float | None = None, min_run: int = 5,
                    floor: float = 0.0) -> int:
    """Samples of ``x`` (N, 3) that are saturated.

    With a known ``limit``: samples whose magnitude reaches it (within float32 rounding). Without:
    clipping shows as runs of at least ``min_run`` identical samples at the axis's largest
    magnitude in the window (noise never repeats a value that long), above ``floor``.

    Parameters
    ----------
    x : ndarray, (N, 3)
    limit : float, optional
        Full scale, in the unit of ``x``.
    min_run : int
        Shortest run of identical extreme samples that counts as clipping.
    floor : float
        Magnitudes at or below it are never clipped.

    Returns
    -------
    int
    """
    x = np.asarray(x, float)
    if len(x) == 0:
        return 0
    if limit is not None:
        return int(np.count_nonzero(np.any(np.abs(x) >= limit * (1 - 1e-6), axis=1)))
    flagged = np.zeros(len(x), bool)
    for axis in range(x.shape[1]):
        col = x[:, axis]
        peak = np.max(np.abs(col))
        if peak <= floor:
            continue
        at_peak = np.abs(col) == peak
        # Run lengths of consecutive samples at the peak value.
        edges = np.diff(np.concatenate([[0], at_peak.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        for a, b in zip(starts, ends, strict=True):
            if b - a >= min_run:
                flagged[a:b] = True
    return int(np.count_nonzero(flagged))


def saturation(acc: np.ndarray, gyro: np.ndarray, limits: Limits = Limits()) -> Saturation:
    """Saturated samples of both triads; the clipping floors keep rest (1 g) and slow turns out of it.

    Parameters
    ----------
    acc, gyro : ndarray, (N, 3)
        m/s^2 and rad/s.
    limits : Limits
        Full scales, when known.

    Returns
    -------
    Saturation
    """
    return Saturation(
        clipped_samples(acc, limits.acc_saturation, floor=15.0),
        clipped_samples(gyro, limits.gyro_saturation, floor=0.5),
    )


@dataclass(frozen=True)
class Dropouts:
    """Samples lost, from gaps in the device's sequence counter (which wraps at 2^32)."""

    received: int
    lost: int
    gaps: int

    @property
    def lost_fraction(self) -> float:
        """Lost frames over the frames sent (received + lost)."""
        total = self.received + self.lost
        return self.lost / total if total else 0.0


def dropouts(seq: np.ndarray) -> Dropouts:
    """Count the samples missing between consecutive ``seq`` values (u32, wrapping).

    Parameters
    ----------
    seq : ndarray of uint32, (N,)
        Frame sequence numbers.

    Returns
    -------
    Dropouts
    """
    seq = np.asarray(seq, dtype=np.int64)
    if len(seq) < 2:
        return Dropouts(len(seq), 0, 0)
    step = np.mod(np.diff(seq), SEQ_MODULUS)
    missing = step - 1
    # A step of 0 (repeated frame) is not a loss; modulo turns it into 2^32 - 1 missing.
    missing[step == 0] = 0
    gaps = missing > 0
    return Dropouts(len(seq), int(missing[gaps].sum()), int(np.count_nonzero(gaps)))


def integrated_angle_deg(t: np.ndarray, gyro: np.ndarray, axis: int, bias: float = 0.0) -> np.ndarray:
    """Cumulative angle (degrees) turned about sensor ``axis``: trapezoidal integral of (rate - bias).

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    gyro : ndarray, (N, 3)
        rad/s.
    axis : int
    bias : float
        Rate subtracted first, rad/s.

    Returns
    -------
    ndarray, (N,)
        Degrees, starting at 0.
    """
    t = np.asarray(t, float)
    rate = np.asarray(gyro, float)[:, axis] - bias
    if len(t) < 2:
        return np.zeros(len(t))
    steps = 0.5 * (rate[1:] + rate[:-1]) * np.diff(t)
    return np.degrees(np.concatenate([[0.0], np.cumsum(steps)]))


@dataclass(frozen=True)
class RotationCheck:
    """The angle turned against the target, with the tolerance it was held to."""

    angle_deg: float
    target_deg: float
    tolerance_deg: float

    @property
    def error_deg(self) -> float:
        """Integrated angle minus the target angle, deg."""
        return self.angle_deg - self.target_deg

    @property
    def ok(self) -> bool:
        """True when the angle error is within the tolerance."""
        return abs(self.error_deg) <= self.tolerance_deg

    @property
    def fraction(self) -> float:
        """Progress of the turn, 0..1 (clipped), in the target's direction."""
        return float(np.clip(self.angle_deg / self.target_deg, 0.0, 1.0)) if self.target_deg else 0.0


def rotation_tolerance_deg(target_deg: float, limits: Limits = Limits()) -> float:
    """The larger of the fixed and the relative tolerance: raw gyros have scale errors of a few percent.

    Parameters
    ----------
    target_deg : float
    limits : Limits

    Returns
    -------
    float
    """
    return max(limits.rotation_tolerance_deg, limits.rotation_tolerance_frac * abs(target_deg))


def rotation_check(angle_deg: float, target_deg: float, limits: Limits = Limits()) -> RotationCheck:
    """Is the integrated ``angle_deg`` the asked ``target_deg``, within :func:`rotation_tolerance_deg`?

    Parameters
    ----------
    angle_deg, target_deg : float
    limits : Limits

    Returns
    -------
    RotationCheck
    """
    return RotationCheck(float(angle_deg), float(target_deg), rotation_tolerance_deg(target_deg, limits))
