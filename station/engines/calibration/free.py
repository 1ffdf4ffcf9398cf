"""Turntable-free multi-position calibration (Tedaldi, Pretto, Menegatti, ICRA 2014).

The unit is held still in many arbitrary orientations, joined by hand-held moves, after an
initial still period. Static intervals are found by moving variance (``static_detect``).

Accelerometer (paper sec. IV-B, ``calibration_free_accel``): the calibrated specific force
a = T K (x - b) of every static interval must have the magnitude of local gravity,
r = g - |a| (eqs. 8-11). The detector is run for several threshold multipliers and the result
with the lowest cost kept.

Gyroscope (paper sec. IV-C, ``calibration_free_gyro``): bias b_g from the still periods, a full
3x3 correction C fitted so that the calibrated rates, integrated over each move, turn one
interval's gravity direction into the next one's, r_k = R_k^T u_k - u_{k+1} (eq. 15).

:func:`calibrate_free` takes a :class:`FreeCapture` (the arrays, checked once) and
:class:`FreeSettings`, and runs the stages below in turn: the initial still period, the
threshold trials of the accelerometer fit, the gyroscope fit over the moves, the uncertainties.

Why this module is long: the method's stages (still detection, threshold trials,
moves, stage results) share the settings and the capture of one call; the accelerometer and
gyroscope numerics (residuals, Jacobians) are already in ``free_accel`` and ``free_gyro``, and
what is left is the method as the paper lays it out, section by section.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from station.engines.calibration.common import (
    CalibrationReport,
    covariance,
    describe_null,
    dithers,
    drift_budget,
    lost_samples,
    pinned_run,
    stddev_from,
)
from station.engines.calibration.free_accel import (
    ACC_PARAM_NAMES,
    CONVENTIONS,
    AccFit,
    acc_correction,
    fit_accelerometer,
)
from station.engines.calibration.free_gyro import (
    GYRO_PARAM_NAMES,
    GyroBlocks,
    GyroModel,
    bias_covariance,
    direction_covariance,
    fit_gyroscope,
    gyro_blocks,
)
from station.engines.shared.earth import STANDARD_GRAVITY
from station.engines.shared.levenberg_marquardt import LsqResult
from station.engines.shared.samples import as_samples, check_rate
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.shared.static_detect import moving_variance_norm, static_intervals, variance_norm
from station.errors import EngineInputError

# Fewest consecutive samples, and shortest time, pinned at an axis's extreme that count as saturation:
# a quantized rate reads one value for a few samples at the smooth peak of a move (about 30 ms at
# 1 LSB of a 16-bit +-2000 deg/s gyro, 2 rad/s peak); a clipped move stays pinned far longer.
SATURATION_RUN = 5
SATURATION_S = 0.1
# Fewest samples a session needs at all (minutes of data are usual).
MIN_SAMPLES = 100
GYRO_BIAS_MODES = ("intervals", "still")


@dataclass(frozen=True)
class FreeSettings:
    """How to run the free method. The defaults are the station's; :meth:`imu_tk` gives imu_tk's.

    Attributes
    ----------
    gravity : float
        Local gravity magnitude g of eq. (10), m/s^2.
    convention : str
        "lower" (lecture) or "upper" (imu_tk) triangular accelerometer misalignment.
    window_s, window_samples : float, int or None
        Moving-variance window (odd number of samples; samples win).
    multipliers : tuple of float
        Threshold multipliers tried, threshold = k * variance norm of the still period.
    interval_samples : int or None
        None: fit the mean of each static interval (one residual per pose); an integer n: fit
        the first n samples of each interval (imu_tk), intervals with end - start >= n only.
    min_interval_s : float
        Shortest static interval used when fitting means.
    cost : str
        "mean" (mean of r^2, comparable across thresholds) or "half_sum" (1/2 sum r^2, Ceres).
    min_intervals : int
        Fewest static intervals a fit accepts (imu_tk: 12).
    inclusive_still_end : bool
        The still period ends at the sample nearest t0 + S, inclusive (imu_tk's initialInterval),
        rather than before t0 + S.
    gyro_bias : str
        "intervals" (the station's default): each move between static intervals k and k+1
        subtracts the mean of the gyro over those two intervals, following a bias that drifts
        during the session, and the reported bias is the mean over all static intervals (the
        rate is zero in each, so they all measure it); "still": the mean of the initial still
        period (imu_tk).

    Raises
    ------
    ValueError
        An unknown convention or gyro bias mode.
    """

    gravity: float = STANDARD_GRAVITY
    convention: str = "lower"
    window_s: float = 1.0
    window_samples: int | None = None
    multipliers: tuple[float, ...] = (2, 3, 4, 5, 6, 7, 8, 9, 10)
    interval_samples: int | None = None
    min_interval_s: float = 1.0
    cost: str = "mean"
    min_intervals: int = 12
    inclusive_still_end: bool = False
    gyro_bias: str = "intervals"

    def __post_init__(self) -> None:
        if self.convention not in CONVENTIONS:
            raise ValueError(f"convention must be 'lower' or 'upper', got {self.convention!r}")
        if self.gyro_bias not in GYRO_BIAS_MODES:
            raise ValueError(f"gyro_bias must be 'still' or 'intervals', got {self.gyro_bias!r}")

    @classmethod
    def imu_tk(cls, **changes: Any) -> FreeSettings:
        """imu_tk's demo settings: 101-sample window, first 100 samples per interval, Ceres cost,
        gyro bias from the still period; ``changes`` set other fields (gravity, convention).

        Returns
        -------
        FreeSettings
        """
        imu_tk = {"window_samples": 101, "interval_samples": 100, "cost": "half_sum",
                  "inclusive_still_end": True, "gyro_bias": "still"}
        return cls(**{**imu_tk, **changes})

    def window(self, rate_hz: float) -> int:
        """The moving-variance window in samples at ``rate_hz``: odd, at least 11.

        Parameters
        ----------
        rate_hz : float
            The sample rate.

        Returns
        -------
        int
        """
        w = self.window_samples if self.window_samples else int(round(self.window_s * rate_hz))
        return max(11, w + (1 - w % 2))


@dataclass(frozen=True)
class FreeCapture:
    """An unlabelled hand-held session, checked once on construction.

    Parameters
    ----------
    t : array_like, (N,)
        Sample times, s, increasing.
    acc, gyro : array_like, (N, 3)
        Raw samples in any unit (counts, m/s^2, rad/s).
    initial_still_s : float or None
        Length of the initial still period, s; detected when None.
    rate_hz : float or None
        The sample rate the device was set to, checked against the timestamps when given.

    Raises
    ------
    EngineInputError
        Arrays of the wrong shape or with non-finite values, a rate the timestamps contradict,
        fewer than ``MIN_SAMPLES`` samples.
    """

    t: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    initial_still_s: float | None = None
    rate_hz: float | None = None

    def __post_init__(self) -> None:
        t, acc, gyro = as_samples(self.t, self.acc, self.gyro)
        if self.rate_hz is not None:
            check_rate(t, self.rate_hz)
        if len(t) < MIN_SAMPLES:
            raise EngineInputError(f"only {len(t)} samples: a turntable-free calibration needs minutes of "
                                   "data")
        for name, value in (("t", t), ("acc", acc), ("gyro", gyro)):
            object.__setattr__(self, name, value)


@dataclass
class ThresholdTrial:
    """One detector threshold tried: k, the threshold k * base, the static intervals it found and,
    when there were enough, the cost and parameters of the accelerometer fit (eq. 10) on them."""

    multiplier: float
    threshold: float
    n_intervals: int
    cost: float | None
    params: np.ndarray | None = field(default=None, repr=False)
    intervals: np.ndarray | None = field(default=None, repr=False)


def _still_samples(t: np.ndarray, initial_still_s: float, inclusive: bool) -> int:
    """Samples of the still period: those with t - t0 < S, or imu_tk's samples 0..i inclusive with
    i the sample whose timestamp is nearest t0 + S (ties to the later one). On irregular
    timestamps the two differ by a sample, which moves the gyro bias enough to matter."""
    if not inclusive:
        return min(len(t), int(np.searchsorted(t - t[0], initial_still_s, side="left")))
    end_ts = t[0] + initial_still_s
    after = min(len(t) - 1, max(1, int(np.searchsorted(t, end_ts, side="left"))))
    nearest = after - 1 if end_ts - t[after - 1] < t[after] - end_ts else after
    return nearest + 1


def detect_initial_still(t: np.ndarray, acc: np.ndarray, window: int) -> float:
    """Length of the still period at the start: until the moving variance (``static_detect``,
    eq. 1) first exceeds ten times its level over the first second.

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    acc : ndarray, (N, 3)
        Accelerometer samples.
    window : int
        Moving-variance window, samples.

    Returns
    -------
    float
        Seconds.
    """
    vnorm = moving_variance_norm(acc, window)
    rate = 1.0 / np.median(np.diff(t))
    head = vnorm[: max(1, int(rate))]
    level = float(np.median(head))
    above = np.flatnonzero(vnorm > 10 * max(level, np.finfo(float).tiny))
    end = int(above[0]) if len(above) else len(vnorm)
    return float(t[min(end, len(t) - 1)] - t[0])


def _interval_samples(acc: np.ndarray, intervals: np.ndarray, settings: FreeSettings,
                      min_len: int, half: int) -> tuple[np.ndarray, np.ndarray]:
    """The fit's samples and the intervals they come from (imu_tk: first n samples; else means).

    For means, each interval loses ``half // 2`` samples at either end (at most an eighth of it;
    ``half`` the detector's half window), counted once it passes ``min_len``: a move that starts
    or ends smoothly stays below the variance threshold for part of a window, most at high rates
    where the per-sample noise is large (1000 Hz: turning at up to 0.1 rad/s inside the detected
    intervals); those samples then belong to the move, whose integration they complete, and no
    longer bias the interval's means.
    """
    if settings.interval_samples:
        n = settings.interval_samples
        valid = intervals[(intervals[:, 1] - intervals[:, 0]) >= n]
        idx = (valid[:, :1] + np.arange(n)).ravel()
        return acc[idx], valid
    long_enough = intervals[(intervals[:, 1] - intervals[:, 0]) >= min_len]
    # at most an eighth of a short interval each end: its means need the samples
    trim = np.minimum(half // 2, (long_enough[:, 1] - long_enough[:, 0]) // 8)
    valid = long_enough + np.column_stack([trim, -trim])
    means = np.array([acc[a:b + 1].mean(axis=0) for a, b in valid]).reshape(-1, 3)
    return means, valid


def _check_gyro_saturation(t: np.ndarray, gyro: np.ndarray, n_still: int) -> None:
    """Refuse a session where a gyro axis sits at its extreme for several samples: the moves were
    too fast for the range and their integrated rotation is wrong. A still period whose noise does
    not exceed the output's resolution means the check cannot tell clipping from a steady signal, so
    it is skipped then (``calibration_common.dithers``)."""
    noisy = dithers(gyro[:n_still].std(axis=0), gyro[:n_still])
    shortest = max(SATURATION_RUN, int(round(SATURATION_S / float(np.median(np.diff(t))))))
    for i, axis in enumerate("xyz"):
        if not noisy[i]:
            continue
        for extreme in (gyro[:, i].max(), gyro[:, i].min()):
            start, run = pinned_run(gyro[:, i], extreme)
            if run >= shortest:
                raise EngineInputError(
                    f"the gyroscope {axis} axis is saturated at t = {t[start]:.2f} s (held at {extreme:g} "
                    f"for {run} samples): the moves were too fast for its range; move more slowly and "
                    "record again")


def _check_gaps(t: np.ndarray, spans: list[tuple[int, int]]) -> None:
    """Refuse lost samples inside a move: its integrated rotation (eq. 15) would be short. Gaps
    inside static intervals are harmless (nothing turns there)."""
    step = float(np.median(np.diff(t)))
    for a, b in spans:
        lost = lost_samples(t[a:b + 1], step)
        if lost is not None:
            k, size = lost
            raise EngineInputError(
                f"the move at t = {t[a]:.2f}..{t[b]:.2f} s has a gap of {size:.3f} s in its timestamps "
                f"(lost samples after t = {t[a + k]:.3f} s): the rotation integrated over it would be wrong; "
                "record the session again without losing samples")


def _check_rank(jac: np.ndarray, names: list[str], what: str) -> None:
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    # the tall Jacobian's singular values and directions are those of its QR factor R (p x p)
    sv, vt = np.linalg.svd(np.linalg.qr(jac / scale, mode="r"))[1:]
    if sv[-1] < 1e-9 * sv[0]:
        raise EngineInputError(
            f"the {what} poses cannot determine all parameters (rank deficient); the combination "
            f"{describe_null(vt[-1], names)} is free: hold the unit in more varied orientations "
            "(every axis up and down, and tilted between)")


def _coverage_warnings(u: np.ndarray, what: str) -> list[str]:
    """Warn when the static gravity directions do not spread over the sphere."""
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    warnings = []
    for i, axis in enumerate("xyz"):
        if u[:, i].max() < 0.5 or u[:, i].min() > -0.5:
            warnings.append(f"{what}: the {axis} axis was never held near both up and down "
                            f"(its gravity component spans {u[:, i].min():+.2f}..{u[:, i].max():+.2f} g); "
                            "its bias and scale are less certain")
    return warnings


# ----------------------------------------------------------------------------------- the stages

@dataclass
class StillPeriod:
    """The initial still period: the gyro bias's and the detector threshold's reference."""

    seconds: float
    samples: int
    window: int     # moving-variance window, samples
    rate: float     # 1 / median time step, Hz
    base: float     # variance norm of the accelerometer over the still period


def find_still_period(data: FreeCapture, settings: FreeSettings) -> StillPeriod:
    """The initial still period (given, or detected by :func:`detect_initial_still`) and the
    accelerometer's variance norm over it, the unit of the detector thresholds.

    Parameters
    ----------
    data : FreeCapture
        The checked session.
    settings : FreeSettings
        Window and still-period rules.

    Returns
    -------
    StillPeriod

    Raises
    ------
    EngineInputError
        No still period at the start, one shorter than the detector window, or one with no noise.
    """
    t, acc = data.t, data.acc
    rate = 1.0 / float(np.median(np.diff(t)))
    window = settings.window(rate)
    initial_still_s = data.initial_still_s
    if initial_still_s is None:
        initial_still_s = detect_initial_still(t, acc, window)
        # two detector windows: enough samples for the threshold's variance (imu_tk asks for more)
        if initial_still_s < 2 * window / rate:
            raise EngineInputError(
                f"no initial still period found (the unit moved after {initial_still_s:.1f} s): keep it "
                "still for the first 10 s or more, or give its length with --initial-still S")
    n_still = _still_samples(t, initial_still_s, settings.inclusive_still_end)
    _check_starts_still(t, acc, window, n_still, given=data.initial_still_s is not None)
    if n_still < window:
        raise EngineInputError(f"the initial still period ({initial_still_s:g} s, {n_still} samples) is "
                               f"shorter than the detector window ({window} samples); record a longer one")
    base = variance_norm(acc[:n_still])
    if base <= 0:
        raise EngineInputError("the accelerometer does not vary at all during the still period (constant "
                               "values): the variance threshold needs sensor noise; is the stream frozen?")
    return StillPeriod(float(initial_still_s), n_still, window, rate, base)


STILL_FACTOR = 10.0
"""A still period whose moving variance is this many times the record's quietest is a move (the
detector's own factor: a static interval's threshold is 2..10 times the still period's)."""


def _check_starts_still(t: np.ndarray, acc: np.ndarray, window: int, n_still: int, given: bool) -> None:
    """Refuse a session that does not start still: the still period would then be a move, its
    variance the detector's unit, and every threshold would find one "static" interval, the whole
    record, which reads as "too few static intervals" rather than what went wrong."""
    vnorm = moving_variance_norm(acc, window)
    if len(vnorm) < 2:
        return
    rate = 1.0 / float(np.median(np.diff(t)))
    # a detected period is judged on its first second (the detector's own reference), a given one whole
    first = n_still if given else max(window, int(round(rate)))
    level = float(np.median(vnorm[:max(1, first - window + 1)]))
    quiet = max(float(np.percentile(vnorm, 5)), float(np.finfo(float).tiny))
    if level <= STILL_FACTOR * quiet:
        return
    where = f"the given --initial-still period ({n_still / rate:.1f} s)" if given else \
        f"its first {first / rate:.1f} s"
    raise EngineInputError(
        f"the capture does not start still: in {where} the accelerometer varies {level / quiet:.0f} times "
        "as much as in its stillest part. The hand-held method takes the gyroscope bias and the noise level "
        "that tells still from moving from an initial still period: record again with the unit lying "
        f"still for the first 10 s or more (at least {2 * window / rate:.1f} s) before the first move")


@dataclass
class AccelStage:
    """The accelerometer's fit (eqs. 8-11) at the chosen threshold and what the gyroscope needs of it."""

    trials: list[ThresholdTrial]
    trial: ThresholdTrial       # the chosen threshold
    fit: AccFit
    intervals: np.ndarray       # (K, 2) first and last sample of each static interval
    correction: np.ndarray      # C = T K of eq. (8)
    bias: np.ndarray
    cov: np.ndarray             # (9, 9) of ``fit.params``
    directions: np.ndarray      # (K, 3) calibrated mean specific force of each interval
    pose_residual: list[float]  # |a| - g of each interval's mean (measured minus model), m/s^2
    warnings: list[str]


def fit_accelerometer_thresholds(data: FreeCapture, settings: FreeSettings,
                                 still: StillPeriod) -> AccelStage:
    """Eq. (10) fitted on the static intervals of each threshold k * base; the lowest cost wins.

    Parameters
    ----------
    data : FreeCapture
        The checked session.
    settings : FreeSettings
        Thresholds, interval rules, cost, convention and gravity.
    still : StillPeriod
        The initial still period.

    Returns
    -------
    AccelStage
        The chosen fit, its covariance (Gauss-Newton, ``calibration_common.covariance``), the
        gravity directions of its intervals and coverage warnings.

    Raises
    ------
    EngineInputError
        Too few static intervals at every threshold, or poses that leave a parameter free.
    """
    acc = data.acc
    half = still.window // 2
    vnorm = moving_variance_norm(acc, still.window)
    min_len = max(2, int(round(settings.min_interval_s * still.rate)))
    trials: list[ThresholdTrial] = []
    best: tuple[ThresholdTrial, AccFit, np.ndarray, np.ndarray] | None = None
    for k in settings.multipliers:
        intervals = static_intervals(vnorm, k * still.base, half)
        samples, valid = _interval_samples(acc, intervals, settings, min_len, half)
        trial = ThresholdTrial(float(k), float(k * still.base), len(valid), None, intervals=valid)
        trials.append(trial)
        if len(valid) < settings.min_intervals:
            continue
        # thresholds close to each other find nearly the same intervals: start from the best fit so far
        fit = fit_accelerometer(samples, settings.gravity, settings.convention, settings.cost,
                                start=None if best is None else best[1].params)
        fit.n_intervals = len(valid)
        trial.cost, trial.params = fit.cost, fit.params
        if best is None or fit.cost < best[1].cost:
            best = (trial, fit, samples, valid)
    if best is None:
        found = ", ".join(f"k={tr.multiplier:g}: {tr.n_intervals}" for tr in trials)
        raise EngineInputError(
            f"too few static intervals ({found}; at least {settings.min_intervals} needed): hold the unit "
            f"still for {max(settings.interval_samples or 0, min_len) / still.rate:.1f} s or more in each of "
            f"{settings.min_intervals}+ orientations")
    trial, fit, _, intervals = best
    _check_rank(fit.jacobian, ACC_PARAM_NAMES[settings.convention], "accelerometer")
    acc_c = acc_correction(fit.params, settings.convention)
    acc_b = fit.params[6:9]
    cov_a, _ = covariance(fit.jacobian, fit.residual)
    calibrated = (acc - acc_b) @ acc_c.T
    # Gravity directions: means over each whole interval (imu_tk).
    directions = np.array([calibrated[a:b + 1].mean(axis=0) for a, b in intervals])
    warnings = _coverage_warnings(directions, "accelerometer")
    # reported as every residual of the station is: measured minus model (the fit's eq. 10 is the reverse)
    pose_res = [float(r) for r in np.linalg.norm(directions, axis=1) - settings.gravity]
    return AccelStage(trials, trial, fit, intervals, acc_c, acc_b, cov_a, directions, pose_res, warnings)


def move_blocks(data: FreeCapture, settings: FreeSettings, still: StillPeriod,
                accel: AccelStage) -> tuple[GyroBlocks, np.ndarray]:
    """The moves between static intervals, de-biased, as eq. (15) integrates them, and the bias.

    With ``settings.gyro_bias == "intervals"`` each move subtracts the mean gyro of the two
    intervals around it and the bias is the mean over all intervals; with "still", the mean of
    the still period.

    Parameters
    ----------
    data : FreeCapture
        The checked session.
    settings : FreeSettings
        The gyro bias mode.
    still : StillPeriod
        The initial still period.
    accel : AccelStage
        The static intervals and their gravity directions.

    Returns
    -------
    tuple
        The blocks (:class:`GyroBlocks`) and the gyro bias b_g (3,).

    Raises
    ------
    EngineInputError
        A saturated gyro axis or lost samples inside a move.
    """
    t, gyro, intervals = data.t, data.gyro, accel.intervals
    _check_gyro_saturation(t, gyro, still.samples)
    gyro_bias = gyro[:still.samples].mean(axis=0)
    blocks = gyro_blocks(t, gyro - gyro_bias, intervals, accel.directions)
    _check_gaps(t, blocks.spans)
    if settings.gyro_bias == "intervals":
        means = np.array([gyro[a:b + 1].mean(axis=0) for a, b in intervals]) - gyro_bias
        drift = 0.5 * (means[:-1] + means[1:])[:, None, :] * (blocks.dt > 0)[..., None]
        blocks = GyroBlocks(blocks.x0 - drift, blocks.x1 - drift, blocks.dt, blocks.u0, blocks.u1,
                            blocks.spans)
        gyro_bias = gyro_bias + means.mean(axis=0)
    return blocks, gyro_bias


def gyro_bias_sd(data: FreeCapture, settings: FreeSettings, still: StillPeriod,
                 intervals: np.ndarray) -> np.ndarray:
    """1-sigma of the gyro bias: white noise of its mean plus what the bias wandered.

    The rate is zero in every static interval, so the scatter of their gyro means shows how far
    the bias wanders during the session (white noise alone would understate it). With the
    "intervals" bias, drift budget as in ``turntable``:
    D = max(s^2 - w, 0) + s^2 sqrt(2 / d) (``calibration_common.drift_budget``).

    Parameters
    ----------
    data : FreeCapture
        The checked session.
    settings : FreeSettings
        The gyro bias mode.
    still : StillPeriod
        The initial still period.
    intervals : ndarray, (K, 2)
        The static intervals.

    Returns
    -------
    ndarray, (3,)
    """
    gyro, n_still = data.gyro, still.samples
    interval_means = np.array([gyro[a:b + 1].mean(axis=0) for a, b in intervals])
    if settings.gyro_bias == "intervals":
        one_white = np.mean([gyro[a:b + 1].var(axis=0, ddof=1) / (b + 1 - a) for a, b in intervals], axis=0)
        drift = drift_budget(interval_means - interval_means.mean(axis=0), 1, one_white)
        return np.sqrt(one_white / len(intervals) + drift)
    wander = interval_means.std(axis=0, ddof=1)
    return np.sqrt(gyro[:n_still].var(axis=0, ddof=1) / n_still + wander**2)


@dataclass
class GyroStage:
    """The gyroscope's fit of eq. (15) and its covariance."""

    solution: LsqResult    # ``x`` = C row-major
    blocks: GyroBlocks
    correction: np.ndarray      # C (3, 3)
    bias: np.ndarray
    bias_sd: np.ndarray
    cov: np.ndarray             # (9, 9) of C: fit, plus what the gravity directions and bias carry
    warnings: list[str]


def fit_gyroscope_moves(data: FreeCapture, settings: FreeSettings, still: StillPeriod,
                        accel: AccelStage) -> GyroStage:
    """C of eq. (15) by Levenberg-Marquardt over the moves, and its covariance: the fit's own
    (two noisy components per unit-vector residual) plus what it inherits from the accelerometer
    fit through the gravity directions and from the bias subtracted before integration
    (implicit-function theorem, ``calibration_free_gyro``).

    Parameters
    ----------
    data : FreeCapture
        The checked session.
    settings : FreeSettings
        Gyro bias mode and convention.
    still : StillPeriod
        The initial still period.
    accel : AccelStage
        The accelerometer's fit.

    Returns
    -------
    GyroStage
        With a warning for a move that disagrees with the gravity directions by over 0.2 (chord).

    Raises
    ------
    EngineInputError
        Saturation, lost samples in a move, or moves that leave part of C free.
    """
    blocks, gyro_bias = move_blocks(data, settings, still, accel)
    sol = fit_gyroscope(blocks)
    model = GyroModel(blocks)
    jac_g = model.jacobian(sol.x)
    _check_rank(jac_g, GYRO_PARAM_NAMES, "gyroscope")
    # eq. (15) compares unit vectors: two of each block's three residual components carry noise
    cov_g, _ = covariance(jac_g, sol.fun, observations=2 * len(blocks.spans))
    cov_g += direction_covariance(model, sol.x, jac_g, data.acc, accel.intervals, accel.fit.params,
                                  accel.cov, settings.convention)
    bias_sd = gyro_bias_sd(data, settings, still, accel.intervals)
    cov_g += bias_covariance(model, sol.x, jac_g, bias_sd)
    warnings = []
    block_norm = np.linalg.norm(sol.fun.reshape(-1, 3), axis=1)
    if np.max(block_norm) > 0.2:
        worst = int(np.argmax(block_norm))
        a, b = blocks.spans[worst]
        t = data.t
        warnings.append(f"gyroscope: the move between static intervals {worst} and {worst + 1} "
                        f"(t = {t[a]:.2f}..{t[b]:.2f} s) disagrees with the gravity directions by "
                        f"{np.degrees(2 * np.arcsin(min(1.0, block_norm[worst] / 2))):.1f} deg: "
                        "check for saturation or missed samples there")
    return GyroStage(sol, blocks, sol.x.reshape(3, 3), gyro_bias, bias_sd, cov_g, warnings)


def accel_calibration(accel: AccelStage, settings: FreeSettings, method: str) -> SensorCalibration:
    """The accelerometer's :class:`SensorCalibration`, M = C^-1, with its 1-sigma.

    Bias drift during the session is correlated in time, so the pose-to-pose scatter of the
    residuals of eq. (10) is added to the bias uncertainty without dividing it by the number of
    poses (in m/s^2: an offset of that size in the true frame is M times it in raw units).

    Parameters
    ----------
    accel : AccelStage
        The accelerometer's fit.
    settings : FreeSettings
        Convention.
    method : str
        The method string stored in the calibration.

    Returns
    -------
    SensorCalibration
    """
    convention, acc_c, fit = settings.convention, accel.correction, accel.fit

    def acc_forward(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.linalg.inv(acc_correction(p, convention)), p[6:9]

    acc_sd = stddev_from(acc_forward, fit.params, accel.cov)
    acc_sd["bias"] = np.sqrt(acc_sd["bias"] ** 2 + np.mean(np.asarray(accel.pose_residual) ** 2)
                             * np.sum(np.linalg.inv(acc_c) ** 2, axis=1))
    return SensorCalibration(np.linalg.inv(acc_c), accel.bias, method=method,
                             residual_rms=float(np.sqrt(np.mean(fit.residual**2))), stddev=acc_sd,
                             extra={"convention": convention, "residual": "|a| - g (m/s^2)",
                                    "threshold_multiplier": accel.trial.multiplier,
                                    "static_intervals": len(accel.intervals)})


def gyro_calibration(gyro: GyroStage, method: str) -> SensorCalibration:
    """The gyroscope's :class:`SensorCalibration`, M = C^-1, with its 1-sigma.

    Parameters
    ----------
    gyro : GyroStage
        The gyroscope's fit.
    method : str
        The method string stored in the calibration.

    Returns
    -------
    SensorCalibration
    """
    def gyro_forward(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.linalg.inv(p.reshape(3, 3)), gyro.bias

    gyro_sd = stddev_from(gyro_forward, gyro.solution.x, gyro.cov)
    gyro_sd["bias"] = gyro.bias_sd
    return SensorCalibration(np.linalg.inv(gyro.correction), gyro.bias, method=method,
                             residual_rms=float(np.sqrt(np.mean(gyro.solution.fun**2))), stddev=gyro_sd,
                             extra={"residual": "R^T u_k - u_k+1 (unit vectors)",
                                    "blocks": len(gyro.blocks.spans)})


def calibrate_free(data: FreeCapture, settings: FreeSettings = FreeSettings()) -> CalibrationReport:
    """Turntable-free calibration of both triads (Tedaldi et al. 2014, eqs. 8-15).

    Parameters
    ----------
    data : FreeCapture
        The hand-held session, checked on construction.
    settings : FreeSettings
        Gravity, convention, detector and cost settings (``FreeSettings.imu_tk()`` for imu_tk's).

    Returns
    -------
    CalibrationReport
        accel and gyro :class:`SensorCalibration` (forward model raw = M true + b, M = C^-1),
        per-threshold trials, per-pose residuals and warnings.

    Raises
    ------
    EngineInputError
        No usable still period, too few static intervals, saturation, lost samples in a move,
        orientations that leave a parameter free.
    """
    still = find_still_period(data, settings)
    accel = fit_accelerometer_thresholds(data, settings, still)
    gyro = fit_gyroscope_moves(data, settings, still, accel)
    method = f"free (Tedaldi 2014), {settings.convention}-triangular accel misalignment"
    t, fit, sol = data.t, accel.fit, gyro.solution
    block_norm = np.linalg.norm(sol.fun.reshape(-1, 3), axis=1)
    poses = [{"label": f"static {i}", "t0": float(t[a]), "t1": float(t[b]),
              "residual": accel.pose_residual[i],
              "gyro_residual": float(block_norm[i - 1]) if i > 0 else None}
             for i, (a, b) in enumerate(accel.intervals)]
    details: dict[str, Any] = {
        "trials": [{"multiplier": tr.multiplier, "threshold": tr.threshold, "intervals": tr.n_intervals,
                    "cost": tr.cost} for tr in accel.trials],
        "chosen_multiplier": accel.trial.multiplier,
        "acc_params": dict(zip(ACC_PARAM_NAMES[settings.convention], fit.params.tolist(), strict=True)),
        "acc_cost": fit.cost,
        "gyro_cost": float(0.5 * sol.fun @ sol.fun),
        "initial_still_s": still.seconds,
        "still_samples": still.samples,
        "window_samples": still.window,
        "accel_correction": accel.correction,
        "gyro_correction": gyro.correction,
    }
    return CalibrationReport(accel_calibration(accel, settings, method), gyro_calibration(gyro, method),
                             "free", settings.gravity, poses, accel.warnings + gyro.warnings, details)
