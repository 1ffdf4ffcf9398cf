"""Thermal fit of one triad: measured bias (eqs. 2-3 of ``thermal``), chosen model, held-out report.

For each segmentation the terms of every axis are chosen by cross-validation
(``design``); the triad keeps one segmentation, the one whose held-out error relative
to no model, summed over the axes, is the smallest within one standard error of the best. The
stored constant is the sample-weighted mean of the pose intercepts. Heating and cooling
residuals are compared at equal temperature to report hysteresis the dT terms cannot explain.

The temperature sensitivity's 1-sigma (``temp_sensitivity_sd``) is the jackknife of
``design.temperature_slope_sd`` over five consecutive stretches per pose, of the fullest
candidate model on the chosen segments: shorter stretches keep the bias's slow drifts within a
stretch, and the chosen model's own spread leaves out what choosing it cost (on simulated sweeps the
error over the 1-sigma had an RMS of 3.9 and 1.4-2.3 that way, 1.2 this way; docs/methods/thermal.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.blocks import Blocks
from station.engines.thermal.design import (
    VARIABLE_TERMS,
    Candidate,
    Design,
    candidates,
    cv_sse,
    design,
    fit_and_predict,
    one_se,
    temperature_slope_sd,
)
from station.engines.thermal.model import TERMS, ThermalBias, ThermalSegment

JACKKNIFE_STRETCHES = 5  # per pose: long enough to hold the slow drifts of the bias (module docstring)


@dataclass
class AxisFit:
    """What the fit chose for one axis and how well it does on held-out data.

    RMS values are of block means (about ``block_s`` long) in the triad's unit; ``before`` is
    the held-out residual of a constant bias (no thermal model), ``after`` of the chosen
    model; ``*_by_segment`` split them by the segment the block's temperature falls in.
    """

    terms: list[str]
    scale_per_degc: float | None
    cv_rms_before: float
    cv_rms_after: float
    cv_rms_before_by_segment: list[float]
    cv_rms_after_by_segment: list[float]
    fit_rms: float
    hysteresis: float | None
    hysteresis_temp: float | None
    temp_sensitivity_sd: float


@dataclass
class TriadFit:
    """The fitted model of one triad, its per-axis reports and the data behind it."""

    name: str
    bias_model: ThermalBias
    axes: list[AxisFit]
    pose_offsets: np.ndarray  # (P, 3) intercept of each pose minus the stored constant
    bias: np.ndarray  # (B, 3) measured bias of each block, eq. (2)/(3)
    model: np.ndarray  # (B, 3) fitted bias of each block (all terms, pose offsets included)
    scale_part: np.ndarray  # (B, 3) the part of ``model`` from the scale factor term of eq. (4)



def expected_raw(raw_mean: np.ndarray, cal: SensorCalibration | None, gravity: float, is_accel: bool
              ) -> tuple[np.ndarray, np.ndarray]:
    """Expected raw reading of each pose, eq. (2) (accelerometer) or (3) (gyroscope).

    Parameters
    ----------
    raw_mean : ndarray, (P, 3)
        Mean raw reading of each pose.
    cal : SensorCalibration or None
        The static calibration (None: identity).
    gravity : float
    is_accel : bool

    Returns
    -------
    tuple of ndarray
        The expected reading (P, 3) and its true-signal part M g u_p (P, 3) (zero for the gyro).
    """
    cal = cal or SensorCalibration.identity()
    if not is_accel:
        return np.tile(cal.bias, (len(raw_mean), 1)), np.zeros_like(raw_mean)
    true = (raw_mean - cal.bias) @ cal.correction.T
    u = true / np.linalg.norm(true, axis=1, keepdims=True)
    signal = gravity * u @ cal.matrix.T
    return signal + cal.bias, signal


def segment_rms(resid: np.ndarray, seg: np.ndarray, n_seg: int) -> list[float]:
    """RMS of ``resid`` over the blocks of each segment.

    Parameters
    ----------
    resid : ndarray, (B,)
    seg : ndarray of int, (B,)
        Segment of each block.
    n_seg : int

    Returns
    -------
    list of float
        NaN for a segment without blocks.
    """
    return [float(np.sqrt(np.mean(resid[seg == s] ** 2))) if np.any(seg == s) else float("nan")
            for s in range(n_seg)]


def hysteresis(temp: np.ndarray, dtemp: np.ndarray, resid: np.ndarray, variation: float
                ) -> tuple[float | None, float | None, bool]:
    """Largest gap between heating and cooling residuals at equal T, its T, and whether it matters.

    Blocks with dT beyond a quarter of the 95th-percentile |dT| count as heating or cooling;
    both are binned over their common temperature range. The gap matters when it exceeds
    three standard errors of the bin means, 5 % of the bias variation and three times the
    block-to-block noise (from first differences of the residual): bin means of
    neighbouring blocks share slow noise that their standard errors do not show.

    Parameters
    ----------
    temp, dtemp : ndarray, (B,)
        Block temperature (degC) and dT (degC/s).
    resid : ndarray, (B,)
        Residual of the fitted model.
    variation : float
        1st-99th percentile range of the bias.

    Returns
    -------
    tuple
        (gap, its temperature, whether it matters); (None, None, False) without both heating and cooling.
    """
    thr = 0.25 * np.percentile(np.abs(dtemp), 95)
    if thr <= 0:
        return None, None, False
    heat, cool = dtemp > thr, dtemp < -thr
    if heat.sum() < 10 or cool.sum() < 10:
        return None, None, False
    lo = max(temp[heat].min(), temp[cool].min())
    hi = min(temp[heat].max(), temp[cool].max())
    if hi - lo <= 0:
        return None, None, False
    edges = np.linspace(lo, hi, max(2, min(20, int((hi - lo) / 1.0))) + 1)
    noise = float(np.std(np.diff(resid))) / np.sqrt(2.0)
    worst, worst_t, matters = 0.0, None, False
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        h = resid[heat & (temp >= a) & (temp <= b)]
        c = resid[cool & (temp >= a) & (temp <= b)]
        if len(h) < 3 or len(c) < 3:
            continue
        gap = float(h.mean() - c.mean())
        se = float(np.sqrt(h.var(ddof=1) / len(h) + c.var(ddof=1) / len(c)))
        if abs(gap) > abs(worst):
            worst, worst_t = gap, 0.5 * (a + b)
        matters |= abs(gap) > max(3 * se, 0.05 * variation, 3 * noise)
    if worst_t is None:
        return None, None, False
    return abs(worst), worst_t, matters


@dataclass
class SweepPlan:
    """What the fit of every triad shares: the blocks and folds, the candidate segmentations
    (join temperatures) and term subsets, and the model's fixed parts."""

    blocks: Blocks
    fold: np.ndarray                        # (B,) cross-validation fold of each block
    folds: int
    n_poses: int
    t_ref: float                            # T_ref of eq. (1), degC
    breaks_options: list[list[float]]       # candidate join temperatures, degC
    masks: list[tuple[bool, ...]]           # candidate subsets of ``VARIABLE_TERMS``
    dt_clamp: tuple[float, float]           # dT range the model is clamped to, degC/s
    gravity: float
    fit_scale: bool                         # try the scale column of eq. (4)
    stretch: np.ndarray                     # (B,) jackknife group of each block (JACKKNIFE_STRETCHES)


def measured_bias(name: str, cal: SensorCalibration | None, plan: SweepPlan
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The measured bias of each block, eq. (2) (accelerometer) or (3) (gyroscope), and the
    true-signal part M g u_p of each pose's expected reading.

    Parameters
    ----------
    name : str
        "accel" or "gyro".
    cal : SensorCalibration or None
        The static calibration (None: M = I, b = 0).
    plan : SweepPlan
        The blocks and poses.

    Returns
    -------
    tuple of ndarray
        y (B, 3) and the signal (P, 3).
    """
    blocks = plan.blocks
    raw = blocks.acc if name == "accel" else blocks.gyro
    w = blocks.count
    raw_mean = np.array([np.average(raw[blocks.pose == p], axis=0, weights=w[blocks.pose == p])
                         for p in range(plan.n_poses)])
    expected, signal = expected_raw(raw_mean, cal, plan.gravity, name == "accel")
    return raw - expected[blocks.pose], signal


def choose_segmentation(plan: SweepPlan, y: np.ndarray, signal: np.ndarray, scale_axes: list[bool]
                        ) -> tuple[Design, list[Candidate]]:
    """The segmentation of the triad and the terms of each axis, by cross-validation.

    Per segmentation, each axis's terms by the one-standard-error rule (``design.one_se``);
    then the segmentation whose held-out error relative to no model (pose intercepts only),
    summed over the axes, is the smallest within one standard error of the best, fewest
    segments first.

    Parameters
    ----------
    plan : SweepPlan
        Blocks, folds and candidates.
    y : ndarray, (B, 3)
        Measured bias of each block.
    signal : ndarray, (P, 3)
        True-signal part of each pose's expected reading (the scale column's factor).
    scale_axes : list of bool
        Axes that may take the scale column of eq. (4).

    Returns
    -------
    tuple
        The chosen design and the chosen candidate of each axis.
    """
    n_poses = plan.n_poses
    designs = [design(plan.blocks, y, plan.fold, plan.folds, br, plan.t_ref, signal, n_poses)
               for br in plan.breaks_options]
    per_design = []
    for d in designs:
        cands = candidates(d, scale_axes, plan.masks)
        chosen = [one_se(cands[j], d.nf) for j in range(3)]
        before = [Candidate((False,) * len(VARIABLE_TERMS), False, n_poses,
                            cv_sse(d, d.pose_cols, np.eye(n_poses), [j])[:, 0]) for j in range(3)]
        per_design.append((d, chosen, before))
    if len(per_design) > 1:
        # One segmentation for the triad: held-out error relative to no model, summed over axes.
        nf = per_design[0][0].nf
        scores = [sum(c.sse / np.maximum(b.sse, 1e-300) for c, b in zip(ch, bf, strict=True))
                  for _, ch, bf in per_design]
        best = int(np.argmin([s.mean() for s in scores]))
        limit = scores[best].mean() + scores[best].std(ddof=1) / np.sqrt(len(nf))
        pick = min(i for i, s in enumerate(scores) if s.mean() <= limit)
    else:
        pick = 0
    d, chosen, _ = per_design[pick]
    return d, chosen


@dataclass
class _TriadArrays:
    """Per-block and per-segment outputs that the axes of one triad fill in, column by column."""

    coeffs: np.ndarray       # (S, 3, 7) coefficients of eq. (1), TERMS order
    model: np.ndarray        # (B, 3) fitted bias, pose offsets included
    scale_part: np.ndarray   # (B, 3) the scale term's share of ``model``
    cv_pred: np.ndarray      # (B, 3) held-out prediction of the chosen model
    cv_before: np.ndarray    # (B, 3) held-out prediction of pose intercepts alone
    offsets: np.ndarray      # (P, 3) pose intercepts minus the stored constant


def _model_columns(d: Design, mask: tuple[bool, ...], scale_axis: int | None) -> tuple[list[int], np.ndarray]:
    """The design columns of a model and the basis of its coefficients that keeps it continuous."""
    cols = d.columns(mask, scale_axis)
    z = d.null_basis(cols[: len(cols) - (1 if scale_axis is not None else 0)])
    if scale_axis is not None:
        z = np.block([[z, np.zeros((z.shape[0], 1))], [np.zeros((1, z.shape[1])), np.ones((1, 1))]])
    return cols, z


def _fit_axis(name: str, j: int, c: Candidate, d: Design, y: np.ndarray, plan: SweepPlan,
              out: _TriadArrays) -> tuple[AxisFit, str | None]:
    """Axis ``j``'s chosen model fitted on all blocks (coefficients in ``out``), its held-out
    report and a hysteresis message if heating and cooling disagree beyond what it explains."""
    blocks = plan.blocks
    n_seg = len(d.breaks) + 1
    pose_weight = np.array([blocks.count[blocks.pose == p].sum() for p in range(plan.n_poses)])
    cols, z = _model_columns(d, c.mask, j if c.scale else None)
    beta_s, out.model[:, j] = fit_and_predict(d, cols, z, j, plan.fold, out.cv_pred)
    fit_and_predict(d, d.pose_cols, np.eye(len(d.pose_cols)), j, plan.fold, out.cv_before)
    beta = beta_s / d.col_scale[cols]
    where = {col: i for i, col in enumerate(cols)}
    pose_b = np.array([beta[where[col]] for col in d.pose_cols])
    h = float(np.sum(pose_b * pose_weight) / pose_weight.sum())
    out.offsets[:, j] = pose_b - h
    for s in range(n_seg):
        for k in range(len(VARIABLE_TERMS)):
            col = int(d.term_cols[s, k])
            out.coeffs[s, j, k] = beta[where[col]] if col in where else 0.0
        out.coeffs[s, j, -1] = h + (beta[where[d.const_cols[s - 1]]] if s > 0 else 0.0)
    # the fullest candidate's spread: the chosen model's own would leave out what choosing it cost
    fullest = tuple(any(m[k] for m in plan.masks) for k in range(len(VARIABLE_TERMS)))
    slope = temperature_slope_sd(d, *_model_columns(d, fullest, j if c.scale else None), y[:, j],
                                 plan.stretch, float(blocks.temp.min()), float(blocks.temp.max()))
    scale = None
    if c.scale:
        col = d.scale_cols[j]
        scale = float(beta[where[col]])
        out.scale_part[:, j] = d.x[:, col] * beta_s[-1]
    resid = y[:, j] - out.model[:, j]
    variation = float(np.percentile(y[:, j] - out.offsets[blocks.pose, j], 99)
                      - np.percentile(y[:, j] - out.offsets[blocks.pose, j], 1))
    hyst, hyst_t, matters = hysteresis(blocks.temp, blocks.dtemp, resid, variation)
    message = None
    if matters:
        message = (f"{name} {'xyz'[j]}: heating and cooling disagree by {hyst:.3g} at {hyst_t:.1f} degC "
                   "beyond what the dT terms explain (hysteresis); compensation is limited to about that, "
                   "soak longer or sweep slower")
    axis = AxisFit(
        terms=[t for t, on in zip(VARIABLE_TERMS, c.mask, strict=True) if on] + ["1"],
        scale_per_degc=scale,
        cv_rms_before=float(np.sqrt(np.mean((y[:, j] - out.cv_before[:, j]) ** 2))),
        cv_rms_after=float(np.sqrt(np.mean((y[:, j] - out.cv_pred[:, j]) ** 2))),
        cv_rms_before_by_segment=segment_rms(y[:, j] - out.cv_before[:, j], d.segment, n_seg),
        cv_rms_after_by_segment=segment_rms(y[:, j] - out.cv_pred[:, j], d.segment, n_seg),
        fit_rms=float(np.sqrt(np.mean(resid**2))),
        hysteresis=hyst, hysteresis_temp=hyst_t, temp_sensitivity_sd=slope,
    )
    return axis, message


def fit_triad(name: str, cal: SensorCalibration | None, plan: SweepPlan) -> tuple[TriadFit, list[str]]:
    """The thermal bias model of one triad: eq. (1) per segment, continuous at the joins, with the
    scale term of eq. (4) where the poses span more than half of g along the axis.

    Parameters
    ----------
    name : str
        "accel" or "gyro".
    cal : SensorCalibration or None
        The static calibration the bias is relative to, eqs. (2)-(3).
    plan : SweepPlan
        Blocks, folds and candidates shared by the triads.

    Returns
    -------
    tuple
        The :class:`TriadFit` and the hysteresis warnings of its axes.
    """
    y, signal = measured_bias(name, cal, plan)
    gravity = plan.gravity
    spread = signal.max(axis=0) - signal.min(axis=0) if plan.n_poses > 1 else np.zeros(3)
    scale_axes = [bool(plan.fit_scale and name == "accel" and spread[j] > 0.5 * gravity) for j in range(3)]
    d, chosen = choose_segmentation(plan, y, signal, scale_axes)
    n_seg = len(d.breaks) + 1
    out = _TriadArrays(np.zeros((n_seg, 3, len(TERMS))), np.zeros_like(y), np.zeros_like(y), np.zeros_like(y),
                       np.zeros_like(y), np.zeros((plan.n_poses, 3)))
    axes: list[AxisFit] = []
    messages: list[str] = []
    for j in range(3):
        axis, message = _fit_axis(name, j, chosen[j], d, y, plan, out)
        axes.append(axis)
        if message is not None:
            messages.append(message)
    edges = [float(plan.blocks.temp.min())] + list(d.breaks) + [float(plan.blocks.temp.max())]
    segments = [ThermalSegment(edges[s], edges[s + 1], out.coeffs[s]) for s in range(n_seg)]
    extra = {
        "selected_terms": [a.terms for a in axes],
        "scale_per_degc": [a.scale_per_degc for a in axes],
        "cv_rms_before": [a.cv_rms_before for a in axes],
        "cv_rms_after": [a.cv_rms_after for a in axes],
        "temp_sensitivity_sd": [a.temp_sensitivity_sd for a in axes],
    }
    bias_model = ThermalBias(segments, plan.dt_clamp[0], plan.dt_clamp[1], extra)
    return TriadFit(name, bias_model, axes, out.offsets, y, out.model, out.scale_part), messages
