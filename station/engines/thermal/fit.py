"""Temperature compensation: fit the bias of each axis as a function of T and dT (issue 5).

The model is the one firmware evaluates (``station.engines.thermal.model``), per axis::

    B(T, dT) = a t^3 + b t^2 + c t + e dT^2 + f dT + g t dT + h,   t = T - T_ref      (1)

piecewise over temperature segments, continuous at the joins, T and dT clamped to the
calibrated range. The measured bias is what the static calibration does not explain::

    accel:  B_i = raw_i - (M g u_p + b),   u_p = unit(M^-1 (mean_p raw - b))          (2)
    gyro:   B_i = raw_i - b                                                            (3)

with u_p the mean direction of pose p through the calibration (M = I, b = 0 without one:
absolute biases). Samples are averaged over blocks of about a second (the bias moves slowly)
and fitted by linear least squares with one intercept per pose: constant pose-to-pose
differences (tilt, residual calibration error, Earth rate, g-sensitivity) do not leak into
the thermal curve; the stored constant is the sample-weighted mean of those intercepts. With
several poses an optional scale factor against temperature enters as one more column::

    raw_j - expected_j = B_j(T, dT) + s_j t E_pj,    E_p = M g u_p                      (4)

The terms of (1), the number of segments and the dT filter time constant are chosen by
K-fold cross-validation over interleaved held-out stretches of the sweep, with the
one-standard-error rule (Hastie, Tibshirani & Friedman, The Elements of Statistical Learning,
2nd ed., sec. 7.10): the smallest model whose held-out error is within one standard error of
the best. Continuity at a join T_j is imposed exactly, for every dT, by the equality
constraints B_s(T_j, dT) = B_s+1(T_j, dT) at dT = -1, 0, 1 (a quadratic in dT agrees
everywhere when it agrees at three points), solved in the constraints' null space.

This module holds the entry point :func:`fit_thermal` (a :class:`ThermalSweep` and
:class:`ThermalSettings` in, a :class:`ThermalFit` out) and its stages; the work is done in
``blocks`` (poses, blocks, folds), ``design`` (design and term selection) and
``triad`` (the fit of one triad).

Why this module is long: it holds the engine's input, settings and result types and the
top-level stages over them (hold, blocks, rate terms, tau, segments); the stages' numerics are
already in ``blocks``, ``design`` and ``triad``, and what is left is the pipeline a reader follows.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from station.engines.shared.earth import STANDARD_GRAVITY
from station.engines.shared.samples import as_samples
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.blocks import (
    BlockMeans,
    Blocks,
    block_ids,
    fold_ids,
    make_blocks,
    rate_follows_temp,
    still_poses,
    stretch_ids,
    with_dtemp,
)
from station.engines.thermal.design import VARIABLE_TERMS, cv_sse, design, equal_breaks
from station.engines.thermal.model import TERMS, DtempFilter, ThermalModel, estimate_dtemp
from station.engines.thermal.triad import (
    JACKKNIFE_STRETCHES,
    AxisFit,
    SweepPlan,
    TriadFit,
    expected_raw,
    fit_triad,
)
from station.errors import EngineInputError

# AxisFit, TriadFit and still_poses live in the stage modules; they are part of this module's interface.
__all__ = ["AxisFit", "PreparedSweep", "RateTerms", "ThermalFit", "ThermalSettings", "ThermalSweep",
           "TriadFit", "check_rate_terms", "choose_tau", "dtemp_clamp", "fit_thermal", "hold_last_reading",
           "prepare_blocks", "segment_options", "still_poses"]

TAU_CANDIDATES_S = (2.0, 5.0, 15.0, 40.0)
TAU_WITHOUT_RATE_S = 15.0  # stored when the dT terms are left out; firmware still runs the filter
RATE_FOLLOWS_TEMP_R2 = 0.95
MIN_SPAN_DEGC = 10.0
MIN_SEGMENT_SPAN_DEGC = 5.0
MIN_BLOCKS = 20
TRIADS = ("accel", "gyro")


@dataclass(frozen=True)
class ThermalSweep:
    """A still temperature sweep and the static calibration its bias is relative to, checked once.

    Parameters
    ----------
    t : array_like, (N,)
        Sample times, s.
    temp : array_like, (N,)
        Measured temperatures, degC (NaN where unknown).
    acc, gyro : array_like, (N, 3)
        Raw samples, m/s^2 and rad/s.
    step : array_like of str, (N,) or None
        Step labels of the capture-csv spec, or None to detect still poses.
    accel_cal, gyro_cal : SensorCalibration or None
        The static calibration; the thermal bias is relative to it, eqs. (2)-(3).

    Raises
    ------
    EngineInputError
        Arrays of the wrong shape or with non-finite samples, or no temperature at all.
    """

    t: np.ndarray
    temp: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    step: np.ndarray | None = None
    accel_cal: SensorCalibration | None = None
    gyro_cal: SensorCalibration | None = None

    def __post_init__(self) -> None:
        t, acc, gyro = as_samples(self.t, self.acc, self.gyro)
        temp = np.asarray(self.temp, float)
        if temp.shape != t.shape or not np.any(np.isfinite(temp)):
            raise EngineInputError("the recording has no temperature; record with the temperature channel "
                                   "(capture column 'temp') to fit a thermal model")
        for name, value in (("t", t), ("temp", temp), ("acc", acc), ("gyro", gyro)):
            object.__setattr__(self, name, value)

    def calibration(self, triad: str) -> SensorCalibration | None:
        """The static calibration of ``triad`` ("accel" or "gyro"), or None.

        Parameters
        ----------
        triad : str

        Returns
        -------
        SensorCalibration or None
        """
        return self.accel_cal if triad == "accel" else self.gyro_cal


@dataclass(frozen=True)
class ThermalSettings:
    """How to fit the thermal model; the defaults choose everything by cross-validation.

    Attributes
    ----------
    gravity : float
        Local gravity, m/s^2.
    segments : str, int or sequence of float
        ``"auto"`` (1 to ``max_segments`` equal-width segments chosen by cross-validation), a
        number of equal-width segments, or the join temperatures (degC).
    terms : sequence of str or None
        The terms of eq. (1) to fit on every axis (names of ``TERMS``; the constant is always
        in); None: chosen per axis by cross-validation among all 64 subsets.
    max_segments : int
        Most segments ``"auto"`` tries.
    reference_temp : float or None
        T_ref of eq. (1); None: the middle of the range, rounded to 0.1 degC.
    tau_s : float or None
        dT filter time constant; None: chosen by cross-validation in ``TAU_CANDIDATES_S``.
    fit_scale : bool
        With several poses, try the scale-against-T column of eq. (4).
    block_s : float
        Length of the averaging blocks, s (raised so there are at most 20000 blocks).
    folds : int
        Number of cross-validation folds.
    dtemp_margin : float
        The dT clamp is the observed dT range widened by this fraction of its largest magnitude
        on each side (the dT terms are linear or quadratic and extrapolate modestly; T is
        clamped to exactly the observed range).

    Raises
    ------
    EngineInputError
        Unknown terms, a time constant that is not positive, a segmentation that is neither
        ``"auto"``, a positive number nor join temperatures.
    """

    gravity: float = STANDARD_GRAVITY
    segments: str | int | Sequence[float] = "auto"
    terms: Sequence[str] | None = None
    max_segments: int = 4
    reference_temp: float | None = None
    tau_s: float | None = None
    fit_scale: bool = True
    block_s: float = 1.0
    folds: int = 5
    dtemp_margin: float = 1.0

    def __post_init__(self) -> None:
        if self.terms is not None:
            unknown = sorted(set(self.terms) - set(TERMS))
            if unknown:
                raise EngineInputError(f"unknown terms {unknown}; the model's terms are {list(TERMS)}")
            object.__setattr__(self, "terms", tuple(self.terms))
        if self.tau_s is not None and not self.tau_s > 0:
            raise EngineInputError(f"dT filter time constant {self.tau_s} s must be positive")
        segments = self.segments
        if isinstance(segments, str):
            if segments != "auto":
                raise EngineInputError(f"segments {segments!r}: give 'auto', a number or join temperatures")
        elif isinstance(segments, int | np.integer):
            if segments < 1:
                raise EngineInputError(f"segments {segments}: at least one segment")
        else:
            object.__setattr__(self, "segments", tuple(segments))

    def term_masks(self) -> list[tuple[bool, ...]]:
        """The candidate subsets of ``VARIABLE_TERMS``: all 64, or the one of ``terms``.

        Returns
        -------
        list of tuple of bool
        """
        if self.terms is None:
            return list(itertools.product((False, True), repeat=len(VARIABLE_TERMS)))
        return [tuple(k in self.terms for k in VARIABLE_TERMS)]


@dataclass
class ThermalFit:
    """Result of :func:`fit_thermal`: the ``thermal`` section and the reports behind it."""

    model: ThermalModel
    triads: dict[str, TriadFit]
    block_temp: np.ndarray  # (B,) mean measured temperature of each block, degC
    block_dtemp: np.ndarray  # (B,) mean filtered dT of each block, degC/s
    block_time: np.ndarray  # (B,) mid time, s
    block_pose: np.ndarray  # (B,) pose index into ``poses``
    poses: list[str]
    tau_scores: dict[float, float]  # dT filter tau (s) -> normalised held-out error
    warnings: list[str] = field(default_factory=list)
    block_s: float = 1.0

    def report(self) -> dict:
        """Plain-data summary for ``--json`` and the terminal.

        Returns
        -------
        dict
            Reference temperature, dT filter, ranges, poses, blocks, scores, warnings, and per
            triad its segments and each axis's terms and held-out RMS.
        """
        out = {
            "reference_temp": self.model.reference_temp,
            "dtemp_filter": self.model.dtemp_filter.to_dict(),
            "temp_range": [float(self.block_temp.min()), float(self.block_temp.max())],
            "dtemp_range": [float(self.block_dtemp.min()), float(self.block_dtemp.max())],
            "poses": self.poses,
            "blocks": len(self.block_temp),
            "block_s": self.block_s,
            "tau_scores": {str(k): v for k, v in self.tau_scores.items()},
            "warnings": list(self.warnings),
        }
        for name, tri in self.triads.items():
            out[name + "_segments"] = [[s.t_min, s.t_max] for s in tri.bias_model.segments]
            out[name] = [
                {
                    "axis": "xyz"[j],
                    "terms": a.terms,
                    "scale_per_degc": a.scale_per_degc,
                    "cv_rms_before": a.cv_rms_before,
                    "cv_rms_after": a.cv_rms_after,
                    "cv_rms_before_by_segment": a.cv_rms_before_by_segment,
                    "cv_rms_after_by_segment": a.cv_rms_after_by_segment,
                    "fit_rms": a.fit_rms,
                    "hysteresis": a.hysteresis,
                    "hysteresis_temp": a.hysteresis_temp,
                    "temp_sensitivity_sd": a.temp_sensitivity_sd,
                }
                for j, a in enumerate(tri.axes)
            ]
        return out


# ----------------------------------------------------------------------------- the stages

def hold_last_reading(temp: np.ndarray) -> np.ndarray:
    """Temperatures with each unknown (NaN) reading replaced by the last known one, and leading
    unknowns by the first known one: the dT filter runs on the whole stream, as firmware does.

    Parameters
    ----------
    temp : ndarray, (N,)
        Measured temperatures, degC, with at least one finite value.

    Returns
    -------
    ndarray, (N,)
    """
    finite = np.isfinite(temp)
    last = np.maximum.accumulate(np.where(finite, np.arange(len(temp)), 0))
    filled = temp[last]
    if not finite[0]:
        filled[: np.argmax(finite)] = temp[np.argmax(finite)]
    return filled


@dataclass
class PreparedSweep:
    """The sweep cut into still blocks with their temperature terms; the dT terms wait for a tau."""

    sweep: ThermalSweep
    names: list[str]          # names of the poses that have blocks
    t_ref: float              # T_ref of eq. (1), degC
    block_s: float            # block length used, s
    base: Blocks
    mean: BlockMeans
    temp_filled: np.ndarray   # (N,) temperatures with unknown readings held
    remap: np.ndarray         # pose index of ``still_poses`` -> index into ``names``

    def blocks_for(self, tau: float) -> Blocks:
        """The blocks with the dT terms of eq. (1) from the ``ema`` filter of time constant ``tau``.

        Parameters
        ----------
        tau : float
            dT filter time constant, s.

        Returns
        -------
        Blocks
        """
        dtemp = estimate_dtemp(self.sweep.t, self.temp_filled, DtempFilter("ema", tau))
        blocks = with_dtemp(self.base, self.mean, self.sweep.temp, self.t_ref, dtemp)
        blocks.pose = self.remap[blocks.pose]
        return blocks


def prepare_blocks(sweep: ThermalSweep, settings: ThermalSettings) -> PreparedSweep:
    """Still poses, averaging blocks of about ``settings.block_s`` and T_ref of eq. (1).

    Parameters
    ----------
    sweep : ThermalSweep
        The checked sweep.
    settings : ThermalSettings
        Block length and reference temperature.

    Returns
    -------
    PreparedSweep

    Raises
    ------
    EngineInputError
        No still period, or fewer than ``MIN_BLOCKS`` still blocks with a temperature.
    """
    t, temp = sweep.t, sweep.temp
    finite = np.isfinite(temp)
    temp_filled = hold_last_reading(temp)
    pose, names = still_poses(t, sweep.acc, sweep.gyro, sweep.step)
    if not names:
        raise EngineInputError("no still period found in the recording; a thermal sweep must hold the unit "
                               "still (label the steps with their pose or keep it motionless)")
    rate = 1.0 / np.median(np.diff(t))
    duration = t[-1] - t[0]
    block_s = max(settings.block_s, duration / 20000.0)
    ids = block_ids(pose, finite, max(int(round(block_s * rate)), 1))
    n_blocks = int(ids.max()) + 1 if np.any(ids >= 0) else 0
    if n_blocks < MIN_BLOCKS:
        raise EngineInputError(f"only {n_blocks} still blocks of {block_s:.3g} s with temperature; a thermal "
                               f"fit needs at least {MIN_BLOCKS} (record a longer sweep)")
    used = ids >= 0
    lo, hi = float(np.min(temp[used])), float(np.max(temp[used]))
    reference = settings.reference_temp
    t_ref = float(reference) if reference is not None else round(0.5 * (lo + hi), 1)
    base, block_mean = make_blocks(ids, t, temp, t_ref, sweep.acc, sweep.gyro, pose)
    present = sorted(set(pose[used]))
    remap = np.full(len(names), -1)
    remap[present] = np.arange(len(present))
    return PreparedSweep(sweep, [names[p] for p in present], t_ref, block_s, base, block_mean, temp_filled,
                         remap)


@dataclass
class RateTerms:
    """Whether the dT terms of eq. (1) are determined, and what follows for the terms and tau."""

    masks: list[tuple[bool, ...]]   # candidate term subsets, without dT terms when undetermined
    tau_s: float | None             # fixed tau, s; None: chosen by cross-validation
    probe_tau: float                # the tau ``probe`` was built with
    probe: Blocks
    warnings: list[str]


def check_rate_terms(prep: PreparedSweep, settings: ThermalSettings,
                     masks: list[tuple[bool, ...]]) -> RateTerms:
    """Leave the dT terms out when dT is a function of T (R^2 of dT on a cubic in T of at least
    ``RATE_FOLLOWS_TEMP_R2``, as in a single warm-up): they cannot be told from the T terms.

    Parameters
    ----------
    prep : PreparedSweep
        The blocks.
    settings : ThermalSettings
        Terms and tau asked for.
    masks : list of tuple of bool
        Candidate term subsets.

    Returns
    -------
    RateTerms
        With a warning when dT follows T.
    """
    tau_s = settings.tau_s
    probe_tau = float(tau_s or TAU_CANDIDATES_S[1])
    probe = prep.blocks_for(probe_tau)
    follows = rate_follows_temp(probe)
    warnings: list[str] = []
    if follows >= RATE_FOLLOWS_TEMP_R2:
        why = f"dT follows T in this recording (R^2 {follows:.3f} of dT on a cubic in T)"
        if settings.terms is None:
            masks = [m for m in masks if not any(m[VARIABLE_TERMS.index(k)] for k in ("dt2", "dt", "tdt"))]
            warnings.append(f"{why}, as in a single warm-up: the dT terms cannot be told from the T terms "
                            "and are left out; to model dT, sweep up and down or at two speeds")
        else:
            warnings.append(f"{why}: the dT terms asked for are poorly determined and will not carry to "
                            "other ramp speeds")
        if tau_s is None and settings.terms is None:
            tau_s = TAU_WITHOUT_RATE_S
    return RateTerms(masks, tau_s, probe_tau, probe, warnings)


class _Progress:
    """Calls ``report`` with the fraction of ``steps`` done, for a progress bar."""

    def __init__(self, report: Callable[[float], None] | None, steps: int):
        self.report, self.steps, self.done = report, steps, 0

    def advance(self) -> None:
        self.done += 1
        if self.report is not None:
            self.report(self.done / self.steps)


def _tau_score(blocks: Blocks, prep: PreparedSweep, settings: ThermalSettings) -> float:
    """Held-out error of the full seven-term model relative to pose intercepts alone, summed over
    the six axes, with one segment: the score of one dT filter time constant."""
    fold = fold_ids(blocks.pose, settings.folds)
    n_poses = len(prep.names)
    score = 0.0
    for name, raw in (("accel", blocks.acc), ("gyro", blocks.gyro)):
        raw_mean = np.array([raw[blocks.pose == p].mean(axis=0) for p in range(n_poses)])
        expected, signal = expected_raw(raw_mean, prep.sweep.calibration(name), settings.gravity,
                                        name == "accel")
        y = raw - expected[blocks.pose]
        d = design(blocks, y, fold, settings.folds, [], prep.t_ref, signal, n_poses)
        every = d.columns((True,) * len(VARIABLE_TERMS), None)
        full = cv_sse(d, every, np.eye(len(every)), [0, 1, 2])
        none = cv_sse(d, d.pose_cols, np.eye(len(d.pose_cols)), [0, 1, 2])
        score += float(np.sum(full.sum(axis=0) / np.maximum(none.sum(axis=0), 1e-300)))
    return score


def choose_tau(prep: PreparedSweep, settings: ThermalSettings, rate: RateTerms,
               progress: _Progress) -> tuple[float, Blocks, dict[float, float]]:
    """The dT filter time constant: the fixed one, or the candidate of ``TAU_CANDIDATES_S`` with the
    lowest held-out score (a longer one only when it is better by 0.1 %).

    Parameters
    ----------
    prep : PreparedSweep
        The blocks.
    settings : ThermalSettings
        Folds and gravity.
    rate : RateTerms
        The fixed tau, if any, and the probe blocks.
    progress : _Progress
        Advanced once per candidate.

    Returns
    -------
    tuple
        tau (s), the blocks with its dT terms, and the normalised score of each candidate.
    """
    tau_scores: dict[float, float] = {}
    if rate.tau_s is not None:
        tau = float(rate.tau_s)
        return tau, (rate.probe if tau == rate.probe_tau else prep.blocks_for(tau)), tau_scores
    best: tuple[float, float, Blocks] | None = None
    for tau in TAU_CANDIDATES_S:
        blocks = prep.blocks_for(tau)
        score = _tau_score(blocks, prep, settings)
        tau_scores[tau] = score / 6.0
        progress.advance()
        if best is None or score < best[0] * (1 - 1e-3):
            best = (score, tau, blocks)
    assert best is not None  # TAU_CANDIDATES_S is not empty
    return best[1], best[2], tau_scores


def segment_options(blocks: Blocks, settings: ThermalSettings) -> tuple[list[list[float]], list[str]]:
    """The candidate segmentations (join temperatures) of ``settings.segments`` over the blocks'
    temperature range, each segment holding at least ``MIN_BLOCKS`` blocks.

    Parameters
    ----------
    blocks : Blocks
        The blocks.
    settings : ThermalSettings
        Segments asked for and ``max_segments``.

    Returns
    -------
    tuple
        The candidate join lists and a warning if the span is under ``MIN_SPAN_DEGC``.

    Raises
    ------
    EngineInputError
        Joins outside the range, or a segment asked for that holds too few blocks.
    """
    lo, hi = float(blocks.temp.min()), float(blocks.temp.max())
    span = hi - lo
    warnings = []
    if span < MIN_SPAN_DEGC:
        warnings.append(f"temperature span {span:.1f} degC is under {MIN_SPAN_DEGC:.0f} degC: the model is "
                        f"only fitted on [{lo:.1f}, {hi:.1f}] degC and clamped outside; sweep a wider range")
    segments = settings.segments
    if isinstance(segments, str):
        n_max = max(1, min(settings.max_segments, int(span // MIN_SEGMENT_SPAN_DEGC)))
        options = [equal_breaks(lo, hi, n) for n in range(1, n_max + 1)]
    elif isinstance(segments, int | np.integer):
        options = [equal_breaks(lo, hi, int(segments))]
    else:
        br = sorted(float(v) for v in segments)
        if any(not lo < v < hi for v in br):
            raise EngineInputError(f"segment joins {br} degC must lie inside the fitted range "
                                   f"[{lo:.2f}, {hi:.2f}] degC")
        options = [br]
    for br in options:
        edges = [lo] + br + [hi]
        seg = np.searchsorted(np.asarray(br), blocks.temp, side="right")
        if len(options) == 1 and any(np.sum(seg == s) < MIN_BLOCKS for s in range(len(edges) - 1)):
            raise EngineInputError(f"a segment of {edges} degC holds fewer than {MIN_BLOCKS} blocks of data; "
                                   "use fewer segments")
    options = [br for br in options
               if all(np.sum(np.searchsorted(np.asarray(br), blocks.temp, side="right") == s) >= MIN_BLOCKS
                      for s in range(len(br) + 1))] or options[:1]
    return options, warnings


def dtemp_clamp(blocks: Blocks, margin: float) -> tuple[float, float]:
    """The dT range the model is clamped to: the observed one widened by ``margin`` times its
    largest magnitude on each side.

    Parameters
    ----------
    blocks : Blocks
        The blocks, with their dT.
    margin : float
        Fraction of max |dT| added on each side.

    Returns
    -------
    tuple of float
        (dt_min, dt_max), degC/s.
    """
    dmax = float(np.max(np.abs(blocks.dtemp)))
    return (float(blocks.dtemp.min()) - margin * dmax, float(blocks.dtemp.max()) + margin * dmax)


def fit_thermal(sweep: ThermalSweep, settings: ThermalSettings = ThermalSettings(),
                progress: Callable[[float], None] | None = None) -> ThermalFit:
    """Fit the thermal bias model of eq. (1) to a still temperature sweep.

    Parameters
    ----------
    sweep : ThermalSweep
        The sweep and the static calibration, checked on construction.
    settings : ThermalSettings
        Terms, segments, tau, folds; the defaults choose them by cross-validation.
    progress : callable or None
        Called with the fraction of the work done, for a progress bar.

    Returns
    -------
    ThermalFit
        The ``thermal`` section (:class:`ThermalModel`) and the held-out reports.

    Raises
    ------
    EngineInputError
        No still period, too few blocks, joins outside the range or segments with too few blocks.
    """
    prep = prepare_blocks(sweep, settings)
    rate = check_rate_terms(prep, settings, settings.term_masks())
    tracker = _Progress(progress, (len(TAU_CANDIDATES_S) if rate.tau_s is None else 0) + len(TRIADS))
    tau, blocks, tau_scores = choose_tau(prep, settings, rate, tracker)
    fold = fold_ids(blocks.pose, settings.folds)
    options, span_warnings = segment_options(blocks, settings)
    plan = SweepPlan(blocks, fold, settings.folds, len(prep.names), prep.t_ref, options, rate.masks,
                     dtemp_clamp(blocks, settings.dtemp_margin), settings.gravity, settings.fit_scale,
                     stretch_ids(blocks.pose, JACKKNIFE_STRETCHES))
    warnings = rate.warnings + span_warnings
    triads: dict[str, TriadFit] = {}
    for name in TRIADS:
        triads[name], messages = fit_triad(name, sweep.calibration(name), plan)
        warnings.extend(messages)
        tracker.advance()
    model = ThermalModel(
        reference_temp=prep.t_ref,
        dtemp_filter=DtempFilter("ema", tau),
        accel=triads["accel"].bias_model,
        gyro=triads["gyro"].bias_model,
        extra={"method": "imu-station thermal: seven-term T/dT model, terms and segments by "
                         f"{settings.folds}-fold cross-validation", "poses": prep.names},
    )
    return ThermalFit(model, triads, blocks.temp, blocks.dtemp, blocks.time, blocks.pose, prep.names,
                      tau_scores, warnings, prep.block_s)
