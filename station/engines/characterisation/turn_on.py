"""Turn-on bias repeatability: how much the bias differs from one power-up to the next.

Each of n still records (one per power-up, all in the same pose) gives the mean reading of every axis,
``m_k`` (k = 1..n). In the same pose gravity and the Earth rate are the same in every record, so the
means differ by the turn-on bias and by the in-run noise of each mean. The sample variance of the
means (Bessel-corrected) estimates

    E[s^2] = sigma_to^2 + w,     w = (1/n) sum_k sigma_m,k^2                          (1)

with sigma_to the turn-on repeatability (IEEE Std 952-1997, "bias repeatability"; Groves, *Principles
of GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed., sec. 4.4.1: the turn-on
to turn-on part of the bias, which the Allan deviation of one record does not see) and sigma_m,k the
in-run noise of record k's mean, its Allan deviation at the record's length T_k:

    sigma_m,k^2 = sigma_A^2(T_k) ~ c_N / T_k + c_B + c_K T_k                                   (2)

The Allan variance at tau is half the mean square difference of adjacent tau-means, so for white
noise sigma_A(T)^2 = N^2 / T is exactly the variance of a T-long mean. A record's curve ends at T/4
(two clusters need the record twice over, and a quarter keeps a few of them), and its last points
are the least certain, so it is extrapolated to T with the IEEE Std 952 model of its three main
terms, sigma_A^2(tau) = c_N / tau + c_B + c_K tau (white noise N^2, bias instability
(2 ln 2 / pi) B^2, rate random walk K^2 / 3). Every record's overlapping Allan variance is computed
at five cluster sizes per decade (``allan.overlapping_adev``); the in-run noise is the unit's, so the
n curves are pooled (their mean at each cluster size, n times the degrees of freedom) before the
fit: non-negative least squares, each point weighted by the inverse of its standard error
sqrt(2 / EDF) (``allan.edf_table``, white noise; three passes with the fitted variance). White noise
is always in the model; c_B and c_K only where each lowers the weighted squared misfit by more than
``TERM_PENALTY`` (an information criterion: the scatter of the last, most uncertain points must not
pass for a floor or a random walk). On simulated records of 5 to 20 s, three to twelve of them,
this puts sigma_m within 20 % of the scatter of the means for white noise and a random walk, and
within a factor 1.5 for a Gauss-Markov drift as long as the records. Then

    sigma_to^2 = max(s^2 - w, 0)                                                             (3)

and its confidence interval takes s^2 (n - 1) / (sigma_to^2 + w) as chi-square with n - 1 degrees of
freedom (NIST SP 1065 eq. 45, as ``allan.confidence_interval``), minus w, floored at zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from station.engines.allan.deviation import (
    ONE_SIGMA,
    cluster_sizes,
    confidence_interval,
    edf_table,
    overlapping_adev,
)
from station.errors import EngineInputError

MIN_TURN_ONS = 3
MIN_SAMPLES = 64  # the Allan curve at T/4 needs a few clusters of several samples
MAX_POSE_ANGLE_DEG = 5.0  # records further apart than this are not in the same pose
MAX_RATE_MISMATCH = 0.01  # sample rates that differ by more than 1 %
TERM_PENALTY = 20.0  # misfit a bias-instability or random-walk term must remove to be kept, eq. (2)
MODELS = ((0,), (0, 1), (0, 2), (0, 1, 2))  # terms of eq. (2): c_N, c_B, c_K


@dataclass(frozen=True)
class TurnOnRecord:
    """One power-up's still record, reduced: its mean and the in-run noise of that mean.

    Attributes
    ----------
    source : str
        Where it came from (a file name), for messages.
    acc_mean, gyro_mean : ndarray, (3,)
        Mean readings, m/s^2 and rad/s.
    acc_allan, gyro_allan : AllanPoints
        The record's Allan variance, for sigma_m of eq. (2).
    duration_s, rate_hz : float
    samples : int
    pose : str
        The record's step label where it has one ("" otherwise).
    """

    source: str
    acc_mean: np.ndarray
    gyro_mean: np.ndarray
    acc_allan: AllanPoints
    gyro_allan: AllanPoints
    duration_s: float
    rate_hz: float
    samples: int
    pose: str = ""


@dataclass(frozen=True)
class AllanPoints:
    """The overlapping Allan variance of one record at cluster sizes ``m`` (per axis), its length."""

    m: np.ndarray
    avar: np.ndarray
    samples: int
    rate_hz: float


def allan_points(values: np.ndarray, rate_hz: float) -> AllanPoints:
    """Overlapping Allan variance of each column at five cluster sizes per decade up to N/4.

    Parameters
    ----------
    values : ndarray, (N, axes)
        The record (rates or specific forces).
    rate_hz : float
        Sample rate, Hz.

    Returns
    -------
    AllanPoints
    """
    m = cluster_sizes(len(values), per_decade=5)
    return AllanPoints(m, overlapping_adev(values, rate_hz, m, workers=1) ** 2, len(values), float(rate_hz))


def mean_noise(points: Sequence[AllanPoints]) -> np.ndarray:
    """In-run noise of each record's mean, eq. (2), from the records' pooled Allan variance.

    Parameters
    ----------
    points : sequence of AllanPoints
        One per record of the same unit, same rate (the shorter records' cluster sizes are a prefix
        of the longer ones').

    Returns
    -------
    ndarray, (records, axes)
        sigma_A of the fitted model at each record's length, in the records' unit.
    """
    shortest = min(points, key=lambda p: len(p.m))
    m = shortest.m
    rate_hz = shortest.rate_hz
    avar = np.mean([p.avar[: len(m)] for p in points], axis=0)
    edf = len(points) * edf_table(np.zeros((len(m), 1), dtype=int), m, shortest.samples + 1)[:, 0]
    inverse_rel_error = np.sqrt(edf / 2.0)
    tau = m / rate_hz
    design = np.column_stack([1.0 / tau, np.ones_like(tau), tau])
    lengths = np.array([p.samples / p.rate_hz for p in points])
    at_length = np.column_stack([1.0 / lengths, np.ones_like(lengths), lengths])
    out = np.empty((len(points), avar.shape[1]))
    for axis in range(avar.shape[1]):
        best: tuple[float, np.ndarray] = (np.inf, np.zeros(len(points)))
        for terms in MODELS:
            cols = list(terms)
            coef, misfit = _fit_terms(avar[:, axis], design[:, cols], inverse_rel_error)
            score = misfit + TERM_PENALTY * (len(cols) - 1)
            if score < best[0]:
                best = (score, at_length[:, cols] @ coef)
        out[:, axis] = np.sqrt(best[1])
    return out


def _fit_terms(avar: np.ndarray, design: np.ndarray, inverse_rel_error: np.ndarray
               ) -> tuple[np.ndarray, float]:
    """Non-negative weighted least squares of eq. (2)'s terms; returns them and the weighted misfit."""
    tiny = np.finfo(float).tiny
    reference = np.maximum(avar, tiny)
    coef = np.zeros(design.shape[1])
    for _ in range(3):
        weight = inverse_rel_error / reference
        coef, _ = nnls(design * weight[:, None], avar * weight)
        reference = np.maximum(design @ coef, tiny)
    return coef, float(np.sum(((avar - reference) * inverse_rel_error / reference) ** 2))


def reduce_record(source: str, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray,
                  pose: str = "") -> TurnOnRecord:
    """Mean and Allan variance (for eq. 2) of one still record.

    Parameters
    ----------
    source : str
        Its name in messages.
    t : ndarray, (N,)
        Times, s.
    acc, gyro : ndarray, (N, 3)
        Raw readings.
    pose : str
        The record's step label, if any.

    Returns
    -------
    TurnOnRecord

    Raises
    ------
    EngineInputError
        Fewer than ``MIN_SAMPLES`` samples.
    """
    if len(t) < MIN_SAMPLES:
        raise EngineInputError(f"{source}: {len(t)} samples; a turn-on record needs at least {MIN_SAMPLES} "
                               "still samples (record a few seconds at least)")
    rate_hz = float(1.0 / np.median(np.diff(t)))
    duration_s = float(t[-1] - t[0] + 1.0 / rate_hz)
    return TurnOnRecord(source, acc.mean(axis=0), gyro.mean(axis=0), allan_points(acc, rate_hz),
                        allan_points(gyro, rate_hz), duration_s, rate_hz, len(t), pose)


@dataclass(frozen=True)
class Repeatability:
    """Turn-on repeatability of one triad, per axis.

    Attributes
    ----------
    sigma : ndarray, (3,)
        sigma_to of eq. (3).
    interval : ndarray, (3, 2)
        Its confidence interval (lower, upper) at ``level``.
    spread : ndarray, (3,)
        s, the standard deviation of the turn-on means.
    in_run : ndarray, (3,)
        sqrt(w) of eq. (1).
    level : float
    turn_ons : int
    """

    sigma: np.ndarray
    interval: np.ndarray
    spread: np.ndarray
    in_run: np.ndarray
    level: float
    turn_ons: int


def repeatability(means: np.ndarray, mean_noise_sd: np.ndarray, level: float = ONE_SIGMA) -> Repeatability:
    """Eqs. (1) and (3) and the chi-square interval for n turn-ons.

    Parameters
    ----------
    means : ndarray, (n, 3)
        Each turn-on's mean reading.
    mean_noise_sd : ndarray, (n, 3)
        sigma_m of each mean, eq. (2).
    level : float
        Confidence level of the interval (default one sigma, 0.683).

    Returns
    -------
    Repeatability

    Raises
    ------
    EngineInputError
        Fewer than ``MIN_TURN_ONS`` turn-ons.
    """
    means = np.asarray(means, float)
    n = len(means)
    if n < MIN_TURN_ONS:
        raise EngineInputError(f"{n} turn-on(s): the repeatability needs at least {MIN_TURN_ONS} power-ups "
                               "in the same pose (one still record each)")
    s2 = means.var(axis=0, ddof=1)
    w = np.mean(np.asarray(mean_noise_sd, float) ** 2, axis=0)
    sigma = np.sqrt(np.maximum(s2 - w, 0.0))
    lo, hi = confidence_interval(np.sqrt(s2), np.full(3, n - 1.0), level)
    interval = np.sqrt(np.maximum(np.stack([lo**2 - w, hi**2 - w], axis=1), 0.0))
    return Repeatability(sigma, interval, np.sqrt(s2), np.sqrt(w), level, n)


def check_same_setup(records: Sequence[TurnOnRecord]) -> None:
    """Refuse turn-on records that were not taken alike: another pose or another sample rate.

    Parameters
    ----------
    records : sequence of TurnOnRecord

    Raises
    ------
    EngineInputError
        Naming the record that differs from the first, and how.
    """
    first = records[0]
    up0 = first.acc_mean / np.linalg.norm(first.acc_mean)
    for rec in records[1:]:
        if rec.pose and first.pose and rec.pose != first.pose:
            raise EngineInputError(f"{rec.source}: labelled pose {rec.pose!r}, {first.source} "
                                   f"{first.pose!r}: every turn-on must be recorded in the same pose")
        angle = np.degrees(np.arccos(np.clip(up0 @ rec.acc_mean / np.linalg.norm(rec.acc_mean), -1.0, 1.0)))
        if angle > MAX_POSE_ANGLE_DEG:
            raise EngineInputError(f"{rec.source}: gravity is {angle:.1f} deg away from its direction in "
                                   f"{first.source}: a different pose; every turn-on must be recorded in the "
                                   "same pose")
        if abs(rec.rate_hz / first.rate_hz - 1.0) > MAX_RATE_MISMATCH:
            raise EngineInputError(f"{rec.source}: sampled at {rec.rate_hz:.6g} Hz, {first.source} at "
                                   f"{first.rate_hz:.6g} Hz: record every turn-on at the same rate")


def turn_on_repeatability(records: Sequence[TurnOnRecord], level: float = ONE_SIGMA
                          ) -> tuple[Repeatability, Repeatability]:
    """Accelerometer and gyroscope turn-on repeatability from n records of one pose, eqs. (1)-(3).

    Parameters
    ----------
    records : sequence of TurnOnRecord
        One per power-up.
    level : float
        Confidence level of the intervals.

    Returns
    -------
    tuple of Repeatability
        (accelerometer, gyroscope).

    Raises
    ------
    EngineInputError
        Fewer than three records, or records of different poses or rates.
    """
    if len(records) < MIN_TURN_ONS:
        names = ", ".join(r.source for r in records) or "none"
        raise EngineInputError(f"{len(records)} turn-on record(s) ({names}): the repeatability needs at "
                               f"least {MIN_TURN_ONS} power-ups in the same pose, one still record each")
    check_same_setup(records)
    acc = repeatability(np.array([r.acc_mean for r in records]),
                        mean_noise([r.acc_allan for r in records]), level)
    gyro = repeatability(np.array([r.gyro_mean for r in records]),
                         mean_noise([r.gyro_allan for r in records]), level)
    return acc, gyro
