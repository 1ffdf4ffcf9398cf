"""Temperature compensation: fit the bias of each axis as a function of T and dT (issue 5).

The model is the one firmware evaluates (``station.engines.thermal_model``), per axis::

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
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import null_space

from station.engines.sensor_model import SensorCalibration
from station.engines.thermal_model import (
    TERMS,
    DtempFilter,
    ThermalBias,
    ThermalModel,
    ThermalSegment,
    estimate_dtemp,
    term_matrix,
)
from station.errors import EngineInputError

STANDARD_GRAVITY = 9.80665
VARIABLE_TERMS = TERMS[:-1]  # every term but the constant, which the pose intercepts carry
TAU_CANDIDATES_S = (2.0, 5.0, 15.0, 40.0)
TAU_WITHOUT_RATE_S = 15.0  # stored when the dT terms are left out; firmware still runs the filter
RATE_FOLLOWS_TEMP_R2 = 0.95
MIN_SPAN_DEGC = 10.0
MIN_SEGMENT_SPAN_DEGC = 5.0
MIN_BLOCKS = 20
TRIADS = ("accel", "gyro")


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
        """Plain-data summary for ``--json`` and the terminal."""
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
                }
                for j, a in enumerate(tri.axes)
            ]
        return out


# ----------------------------------------------------------------------------- still poses

def _axis_name(u: np.ndarray) -> str:
    """'+z' when u is within 10 degrees of a sensor axis, else a numbered name is given later."""
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) > np.cos(np.radians(10.0)):
        return ("+" if u[k] > 0 else "-") + "xyz"[k]
    return ""


def still_poses(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray,
                step: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """Pose index of every sample (-1: moving or unlabelled) and the pose names.

    With step labels (capture-csv spec) every static label is a pose and rows between steps
    or in rotation steps are left out. Without labels (or with a step column left empty, as
    an unlabelled recording writes it), one-second windows whose accelerometer
    or gyroscope spread exceeds five times the median spread are motion; still windows are
    grouped by the direction of their mean specific force (within 5 degrees).
    """
    n = len(t)
    pose = np.full(n, -1, dtype=int)
    labels = np.asarray(step).astype(str) if step is not None else np.array([], dtype=str)
    if np.any(labels != ""):
        static = (labels != "") & ~np.char.startswith(labels, "rot")
        labelled, pose[static] = np.unique(labels[static], return_inverse=True)
        return pose, [str(label) for label in labelled]
    rate = 1.0 / np.median(np.diff(t)) if n > 1 else 1.0
    w = max(int(round(rate)), 5)
    nw = n // w
    if nw == 0:
        return pose, []
    a = acc[: nw * w].reshape(nw, w, 3)
    g = gyro[: nw * w].reshape(nw, w, 3)
    spread = np.column_stack([a.std(axis=1).max(axis=1), g.std(axis=1).max(axis=1)])
    moving = np.any(spread > 5.0 * np.median(spread, axis=0) + 1e-12, axis=1)
    # The windows beside a moving one hold part of the motion too.
    still = ~(moving | np.concatenate([[False], moving[:-1]]) | np.concatenate([moving[1:], [False]]))
    mean_dir = a.mean(axis=1)
    mean_dir /= np.linalg.norm(mean_dir, axis=1, keepdims=True)
    centres: list[np.ndarray] = []
    window_pose = np.full(nw, -1)
    cos_tol = np.cos(np.radians(5.0))
    for i in np.flatnonzero(still):
        for k, c in enumerate(centres):
            if mean_dir[i] @ c > cos_tol:
                window_pose[i] = k
                break
        else:
            centres.append(mean_dir[i])
            window_pose[i] = len(centres) - 1
    pose[: nw * w] = np.repeat(window_pose, w)
    names: list[str] = []
    for k, c in enumerate(centres):
        name = _axis_name(c)
        names.append(name if name and name not in names else f"pose{k + 1}")
    return pose, names


# ----------------------------------------------------------------------------- blocks

@dataclass
class _Blocks:
    count: np.ndarray
    time: np.ndarray
    temp: np.ndarray
    dtemp: np.ndarray
    terms: np.ndarray  # (B, 7) block means of the term columns, TERMS order
    acc: np.ndarray
    gyro: np.ndarray
    pose: np.ndarray


def _block_ids(pose: np.ndarray, ok: np.ndarray, length: int) -> np.ndarray:
    """Block index per sample (-1: unused): runs of one pose cut into blocks of about ``length``."""
    use = (pose >= 0) & ok
    ids = np.full(len(pose), -1)
    edges = np.flatnonzero(np.diff(np.concatenate([[-2], np.where(use, pose, -1), [-2]])) != 0)
    next_id = 0
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if not use[a] or b - a < max(length // 2, 2):
            continue
        n = b - a
        nb = max(1, int(round(n / length)))
        ids[a:b] = next_id + np.minimum(np.arange(n) * nb // n, nb - 1)
        next_id += nb
    return ids


class _BlockMeans:
    """Block means of per-sample quantities: what the fit sees instead of the samples."""

    def __init__(self, ids: np.ndarray):
        self.sel = ids >= 0
        self.index = ids[self.sel]
        self.count = np.bincount(self.index).astype(float)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if x.ndim == 2:
            return np.column_stack([self(x[:, j]) for j in range(x.shape[1])])
        return np.bincount(self.index, weights=x[self.sel]) / self.count


def _make_blocks(ids: np.ndarray, t: np.ndarray, temp: np.ndarray, t_ref: float, acc: np.ndarray,
                 gyro: np.ndarray, pose: np.ndarray) -> tuple[_Blocks, _BlockMeans]:
    """Blocks with the temperature terms; the dT terms are filled in by :func:`_with_dtemp`."""
    mean = _BlockMeans(ids)
    t_rel = np.where(np.isfinite(temp), temp - t_ref, 0.0)
    terms = np.zeros((len(mean.count), len(TERMS)))
    for k, power in ((0, 3), (1, 2), (2, 1)):
        terms[:, k] = mean(t_rel**power)
    terms[:, -1] = 1.0
    first = np.zeros(len(mean.count), dtype=int)
    first[mean.index[::-1]] = np.flatnonzero(mean.sel)[::-1]
    blocks = _Blocks(count=mean.count, time=mean(t), temp=mean(temp), dtemp=np.zeros(len(mean.count)),
                     terms=terms, acc=mean(acc), gyro=mean(gyro), pose=pose[first])
    return blocks, mean


def _with_dtemp(blocks: _Blocks, mean: _BlockMeans, temp: np.ndarray, t_ref: float,
                dtemp: np.ndarray) -> _Blocks:
    """A copy of ``blocks`` with the block means of dT, dT^2 and t dT (eq. 1) of this dT."""
    t_rel = np.where(np.isfinite(temp), temp - t_ref, 0.0)
    terms = blocks.terms.copy()
    d = mean(dtemp)
    terms[:, 3], terms[:, 4], terms[:, 5] = mean(dtemp**2), d, mean(t_rel * dtemp)
    return replace(blocks, dtemp=d, terms=terms, pose=blocks.pose.copy())


def _fold_ids(pose: np.ndarray, folds: int) -> np.ndarray:
    """Interleaved held-out stretches: each pose's blocks in about 8 x ``folds`` runs, dealt round."""
    out = np.zeros(len(pose), dtype=int)
    for p in np.unique(pose):
        idx = np.flatnonzero(pose == p)
        n = len(idx)
        chunk = max(1, n // (8 * folds))
        out[idx] = (np.arange(n) // chunk + p) % folds
    return out


# ----------------------------------------------------------------------------- design

@dataclass
class _Design:
    """Columns of one segmentation (column-scaled) and their per-fold Gram matrices."""

    breaks: list[float]
    t_ref: float
    segment: np.ndarray  # (B,) segment of each block
    x: np.ndarray  # (B, C) scaled design
    col_scale: np.ndarray
    term_cols: np.ndarray  # (S, 6) column of variable term k in segment s
    const_cols: list[int]  # segment constants of segments 1..S-1 (segment 0: the pose intercepts)
    pose_cols: list[int]
    scale_cols: list[int]  # per axis j
    gram: np.ndarray  # (F, C, C)
    xty: np.ndarray  # (F, C, 3)
    yy: np.ndarray  # (F, 3)
    nf: np.ndarray  # (F,)

    def columns(self, mask: tuple[bool, ...], scale_axis: int | None) -> list[int]:
        cols = [int(c) for s in range(len(self.term_cols)) for k, on in enumerate(mask) if on
                for c in [self.term_cols[s, k]]]
        cols += self.const_cols + self.pose_cols
        if scale_axis is not None:
            cols.append(self.scale_cols[scale_axis])
        return cols

    def null_basis(self, cols: list[int]) -> np.ndarray:
        """Basis of the coefficient space (scaled) that keeps the model continuous at the joins."""
        if not self.breaks:
            return np.eye(len(cols))
        where = {c: i for i, c in enumerate(cols)}
        rows = []
        for s, tb in enumerate(self.breaks):
            for d in (-1.0, 0.0, 1.0):
                phi = term_matrix(np.array([tb - self.t_ref]), np.array([d]))[0]
                row = np.zeros(len(cols))
                for k in range(len(VARIABLE_TERMS)):
                    for seg, sign in ((s, -1.0), (s + 1, 1.0)):
                        c = int(self.term_cols[seg, k])
                        if c in where:
                            row[where[c]] += sign * phi[k] / self.col_scale[c]
                for seg, sign in ((s, -1.0), (s + 1, 1.0)):
                    if seg > 0:
                        c = self.const_cols[seg - 1]
                        row[where[c]] += sign / self.col_scale[c]
                rows.append(row)
        return null_space(np.array(rows), rcond=1e-10)


def _design(blocks: _Blocks, y: np.ndarray, fold: np.ndarray, folds: int, breaks: list[float], t_ref: float,
            expected: np.ndarray, n_poses: int) -> _Design:
    nb = len(blocks.temp)
    seg = np.searchsorted(np.asarray(breaks), blocks.temp, side="right")
    n_seg = len(breaks) + 1
    cols: list[np.ndarray] = []
    term_cols = np.zeros((n_seg, len(VARIABLE_TERMS)), dtype=int)
    for s in range(n_seg):
        in_s = seg == s
        for k in range(len(VARIABLE_TERMS)):
            term_cols[s, k] = len(cols)
            cols.append(np.where(in_s, blocks.terms[:, k], 0.0))
    const_cols = []
    for s in range(1, n_seg):
        const_cols.append(len(cols))
        cols.append((seg == s).astype(float))
    pose_cols = []
    for p in range(n_poses):
        pose_cols.append(len(cols))
        cols.append((blocks.pose == p).astype(float))
    scale_cols = []
    t_col = blocks.terms[:, TERMS.index("t")]
    for j in range(3):
        scale_cols.append(len(cols))
        cols.append(t_col * expected[blocks.pose, j])
    x = np.column_stack(cols) if cols else np.zeros((nb, 0))
    col_scale = np.sqrt(np.mean(x**2, axis=0))
    col_scale[col_scale == 0] = 1.0
    x = x / col_scale
    gram = np.stack([x[fold == f].T @ x[fold == f] for f in range(folds)])
    xty = np.stack([x[fold == f].T @ y[fold == f] for f in range(folds)])
    yy = np.stack([np.sum(y[fold == f] ** 2, axis=0) for f in range(folds)])
    nf = np.array([np.sum(fold == f) for f in range(folds)], dtype=float)
    return _Design(breaks, t_ref, seg, x, col_scale, term_cols, const_cols, pose_cols, scale_cols,
                   gram, xty, yy, nf)


def _solve(gram: np.ndarray, rhs: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Least squares from normal equations within the basis ``z``; stacks of them solve at once.

    The columns are scaled to unit RMS, so a ridge of 1e-10 of the mean diagonal changes no
    determined coefficient and sets undetermined ones (a pose absent from a fold) to zero.
    """
    a = z.T @ gram @ z
    m = a.shape[-1]
    ridge = 1e-10 * np.trace(a, axis1=-2, axis2=-1)[..., None, None] / m + 1e-300
    return z @ np.linalg.solve(a + ridge * np.eye(m), z.T @ rhs)


def _fit_and_predict(d: _Design, cols: list[int], z: np.ndarray, axis: int, fold: np.ndarray,
                     held_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scaled coefficients and fitted values on all blocks; fills ``held_out[:, axis]`` with each
    fold's prediction from the model fitted on the other folds."""
    gf = d.gram[:, cols][:, :, cols]
    rf = d.xty[:, cols, axis]
    x = d.x[:, cols]
    beta_f = _solve(gf.sum(axis=0) - gf, (rf.sum(axis=0) - rf)[:, :, None], z)[:, :, 0]
    for f in range(len(gf)):
        held_out[fold == f, axis] = x[fold == f] @ beta_f[f]
    beta = _solve(gf.sum(axis=0), rf.sum(axis=0), z)
    return beta, x @ beta


@dataclass
class _Candidate:
    mask: tuple[bool, ...]
    scale: bool
    params: int
    sse: np.ndarray  # (F,) held-out sum of squares per fold

    def mse(self, nf: np.ndarray) -> float:
        return float(self.sse.sum() / nf.sum())

    def se(self, nf: np.ndarray) -> float:
        per_fold = self.sse / np.maximum(nf, 1)
        return float(per_fold.std(ddof=1) / np.sqrt(len(nf))) if len(nf) > 1 else 0.0


def _cv_sse(d: _Design, cols: list[int], z: np.ndarray, axes: list[int]) -> np.ndarray:
    """Held-out sum of squared residuals, (F, len(axes)), for the model on ``cols`` within ``z``.

    Fold f is fitted on the Gram matrix of the other folds and scored on its own:
    |y_f - X_f beta|^2 = y_f'y_f - 2 beta'X_f'y_f + beta'X_f'X_f beta.
    """
    gf = d.gram[:, cols][:, :, cols]
    rf = d.xty[:, cols][:, :, axes]
    beta = _solve(gf.sum(axis=0) - gf, rf.sum(axis=0) - rf, z)
    out = d.yy[:, axes] - 2 * np.sum(beta * rf, axis=1) + np.einsum("fia,fij,fja->fa", beta, gf, beta)
    return np.maximum(out, 0.0)


def _candidates(d: _Design, scale_axes: list[bool], masks: list[tuple[bool, ...]]) -> list[list[_Candidate]]:
    """Each term subset of ``masks`` (and with the scale column where allowed), per axis."""
    per_axis: list[list[_Candidate]] = [[], [], []]
    for mask in masks:
        cols = d.columns(mask, None)
        z = d.null_basis(cols)
        sse = _cv_sse(d, cols, z, [0, 1, 2])
        for j in range(3):
            per_axis[j].append(_Candidate(mask, False, z.shape[1], sse[:, j]))
        for j in range(3):
            if not scale_axes[j]:
                continue
            cols_s = d.columns(mask, j)
            z_s = np.zeros((z.shape[0] + 1, z.shape[1] + 1))
            z_s[:-1, :-1] = z
            z_s[-1, -1] = 1.0
            per_axis[j].append(_Candidate(mask, True, z_s.shape[1], _cv_sse(d, cols_s, z_s, [j])[:, 0]))
    return per_axis


def _one_se(cands: list[_Candidate], nf: np.ndarray) -> _Candidate:
    best = min(cands, key=lambda c: c.mse(nf))
    limit = best.mse(nf) + best.se(nf)
    return min((c for c in cands if c.mse(nf) <= limit), key=lambda c: (c.params, c.mse(nf)))


# ----------------------------------------------------------------------------- fit one triad

def _expected(raw_mean: np.ndarray, cal: SensorCalibration | None, gravity: float, is_accel: bool
              ) -> tuple[np.ndarray, np.ndarray]:
    """Expected raw of each pose (P, 3), eq. (2)/(3), and the true-signal part M g u_p of it."""
    cal = cal or SensorCalibration.identity()
    if not is_accel:
        return np.tile(cal.bias, (len(raw_mean), 1)), np.zeros_like(raw_mean)
    true = (raw_mean - cal.bias) @ cal.correction.T
    u = true / np.linalg.norm(true, axis=1, keepdims=True)
    signal = gravity * u @ cal.matrix.T
    return signal + cal.bias, signal


def _segment_rms(resid: np.ndarray, seg: np.ndarray, n_seg: int) -> list[float]:
    return [float(np.sqrt(np.mean(resid[seg == s] ** 2))) if np.any(seg == s) else float("nan")
            for s in range(n_seg)]


def _hysteresis(temp: np.ndarray, dtemp: np.ndarray, resid: np.ndarray, variation: float
                ) -> tuple[float | None, float | None, bool]:
    """Largest gap between heating and cooling residuals at equal T, its T, and whether it matters.

    Blocks with dT beyond a quarter of the 95th-percentile |dT| count as heating or cooling;
    both are binned over their common temperature range. The gap matters when it exceeds
    three standard errors of the bin means, 5 % of the bias variation and three times the
    block-to-block noise (from first differences of the residual): bin means of
    neighbouring blocks share slow noise that their standard errors do not show.
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


def _fit_triad(name: str, blocks: _Blocks, fold: np.ndarray, folds: int, n_poses: int, t_ref: float,
               cal: SensorCalibration | None, gravity: float, breaks_options: list[list[float]],
               fit_scale: bool, dt_clamp: tuple[float, float], masks: list[tuple[bool, ...]]
               ) -> tuple[TriadFit, list[str]]:
    raw = blocks.acc if name == "accel" else blocks.gyro
    w = blocks.count
    raw_mean = np.array([np.average(raw[blocks.pose == p], axis=0, weights=w[blocks.pose == p])
                         for p in range(n_poses)])
    expected, signal = _expected(raw_mean, cal, gravity, name == "accel")
    y = raw - expected[blocks.pose]
    spread = signal.max(axis=0) - signal.min(axis=0) if n_poses > 1 else np.zeros(3)
    scale_axes = [bool(fit_scale and name == "accel" and spread[j] > 0.5 * gravity) for j in range(3)]

    designs = [_design(blocks, y, fold, folds, br, t_ref, signal, n_poses) for br in breaks_options]
    per_design = []
    for d in designs:
        cands = _candidates(d, scale_axes, masks)
        chosen = [_one_se(cands[j], d.nf) for j in range(3)]
        before = [_Candidate((False,) * len(VARIABLE_TERMS), False, n_poses,
                             _cv_sse(d, d.pose_cols, np.eye(n_poses), [j])[:, 0]) for j in range(3)]
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
    d, chosen, before = per_design[pick]

    n_seg = len(d.breaks) + 1
    coeffs = np.zeros((n_seg, 3, len(TERMS)))
    model = np.zeros_like(y)
    scale_part = np.zeros_like(y)
    cv_pred = np.zeros_like(y)
    cv_before = np.zeros_like(y)
    offsets = np.zeros((n_poses, 3))
    axes: list[AxisFit] = []
    pose_weight = np.array([w[blocks.pose == p].sum() for p in range(n_poses)])
    segments_edges = [float(blocks.temp.min())] + list(d.breaks) + [float(blocks.temp.max())]
    messages: list[str] = []
    for j in range(3):
        c = chosen[j]
        cols = d.columns(c.mask, j if c.scale else None)
        z = d.null_basis(cols[: len(cols) - (1 if c.scale else 0)])
        if c.scale:
            z = np.block([[z, np.zeros((z.shape[0], 1))], [np.zeros((1, z.shape[1])), np.ones((1, 1))]])
        beta_s, model[:, j] = _fit_and_predict(d, cols, z, j, fold, cv_pred)
        _fit_and_predict(d, d.pose_cols, np.eye(len(d.pose_cols)), j, fold, cv_before)
        beta = beta_s / d.col_scale[cols]
        where = {col: i for i, col in enumerate(cols)}
        pose_b = np.array([beta[where[col]] for col in d.pose_cols])
        h = float(np.sum(pose_b * pose_weight) / pose_weight.sum())
        offsets[:, j] = pose_b - h
        for s in range(n_seg):
            for k in range(len(VARIABLE_TERMS)):
                col = int(d.term_cols[s, k])
                coeffs[s, j, k] = beta[where[col]] if col in where else 0.0
            coeffs[s, j, -1] = h + (beta[where[d.const_cols[s - 1]]] if s > 0 else 0.0)
        scale = None
        if c.scale:
            col = d.scale_cols[j]
            scale = float(beta[where[col]])
            scale_part[:, j] = d.x[:, col] * beta_s[-1]
        resid = y[:, j] - model[:, j]
        variation = float(np.percentile(y[:, j] - offsets[blocks.pose, j], 99)
                          - np.percentile(y[:, j] - offsets[blocks.pose, j], 1))
        hyst, hyst_t, matters = _hysteresis(blocks.temp, blocks.dtemp, resid, variation)
        if matters:
            messages.append(
                f"{name} {'xyz'[j]}: heating and cooling disagree by {hyst:.3g} at {hyst_t:.1f} degC beyond "
                "what the dT terms explain (hysteresis); compensation is limited to about that, soak longer "
                "or sweep slower")
        axes.append(AxisFit(
            terms=[t for t, on in zip(VARIABLE_TERMS, c.mask, strict=True) if on] + ["1"],
            scale_per_degc=scale,
            cv_rms_before=float(np.sqrt(np.mean((y[:, j] - cv_before[:, j]) ** 2))),
            cv_rms_after=float(np.sqrt(np.mean((y[:, j] - cv_pred[:, j]) ** 2))),
            cv_rms_before_by_segment=_segment_rms(y[:, j] - cv_before[:, j], d.segment, n_seg),
            cv_rms_after_by_segment=_segment_rms(y[:, j] - cv_pred[:, j], d.segment, n_seg),
            fit_rms=float(np.sqrt(np.mean(resid**2))),
            hysteresis=hyst, hysteresis_temp=hyst_t,
        ))
    segments = [ThermalSegment(segments_edges[s], segments_edges[s + 1], coeffs[s]) for s in range(n_seg)]
    extra = {
        "selected_terms": [a.terms for a in axes],
        "scale_per_degc": [a.scale_per_degc for a in axes],
        "cv_rms_before": [a.cv_rms_before for a in axes],
        "cv_rms_after": [a.cv_rms_after for a in axes],
    }
    bias_model = ThermalBias(segments, dt_clamp[0], dt_clamp[1], extra)
    return TriadFit(name, bias_model, axes, offsets, y, model, scale_part), messages


# ----------------------------------------------------------------------------- entry point

def _rate_follows_temp(blocks: _Blocks) -> float:
    """R^2 of dT regressed on a cubic in T: near 1 when dT is a function of T (one warm-up curve)."""
    t = blocks.terms[:, :3]
    x = np.column_stack([t, np.ones(len(t))])
    d = blocks.dtemp
    resid = d - x @ np.linalg.lstsq(x, d, rcond=None)[0]
    total = np.sum((d - d.mean()) ** 2)
    return float(1.0 - np.sum(resid**2) / total) if total > 0 else 1.0


def _equal_breaks(lo: float, hi: float, n: int) -> list[float]:
    return [float(v) for v in np.linspace(lo, hi, n + 1)[1:-1]]


def fit_thermal(
    t: np.ndarray,
    temp: np.ndarray,
    acc: np.ndarray,
    gyro: np.ndarray,
    step: np.ndarray | None = None,
    *,
    accel_cal: SensorCalibration | None = None,
    gyro_cal: SensorCalibration | None = None,
    gravity: float = STANDARD_GRAVITY,
    segments: str | int | Sequence[float] = "auto",
    terms: Sequence[str] | None = None,
    max_segments: int = 4,
    reference_temp: float | None = None,
    tau_s: float | None = None,
    fit_scale: bool = True,
    block_s: float = 1.0,
    folds: int = 5,
    dtemp_margin: float = 1.0,
    progress: Callable[[float], None] | None = None,
) -> ThermalFit:
    """Fit the thermal bias model of eq. (1) to a still temperature sweep.

    Parameters
    ----------
    t, temp : (N,) sample times (s) and measured temperatures (degC, NaN where unknown).
    acc, gyro : (N, 3) raw samples (m/s^2, rad/s).
    step : (N,) step labels of the capture-csv spec, or None to detect still poses.
    accel_cal, gyro_cal : the static calibration; the thermal bias is relative to it, eq. (2)-(3).
    gravity : local gravity, m/s^2.
    segments : ``"auto"`` (1 to ``max_segments`` equal-width segments chosen by
        cross-validation), a number of equal-width segments, or the join temperatures (degC).
    terms : the terms of eq. (1) to fit on every axis (names of ``TERMS``; the constant is
        always in); default: chosen per axis by cross-validation among all 64 subsets.
    reference_temp : T_ref of eq. (1); default the middle of the range, rounded to 0.1 degC.
    tau_s : dT filter time constant; default chosen by cross-validation in ``TAU_CANDIDATES_S``.
    fit_scale : with several poses, try the scale-against-T column of eq. (4).
    block_s : length of the averaging blocks, s (raised so there are at most 20000 blocks).
    folds : number of cross-validation folds.
    dtemp_margin : the dT clamp is the observed dT range widened by this fraction of its
        largest magnitude on each side (the dT terms are linear or quadratic and extrapolate
        modestly; T is clamped to exactly the observed range).
    progress : called with the fraction of the work done, for a progress bar.

    Returns
    -------
    ThermalFit
        The ``thermal`` section (:class:`ThermalModel`) and the held-out reports.
    """
    if terms is None:
        masks = list(itertools.product((False, True), repeat=len(VARIABLE_TERMS)))
    else:
        unknown = sorted(set(terms) - set(TERMS))
        if unknown:
            raise EngineInputError(f"unknown terms {unknown}; the model's terms are {list(TERMS)}")
        masks = [tuple(k in terms for k in VARIABLE_TERMS)]
    t = np.asarray(t, float)
    temp = np.asarray(temp, float)
    acc = np.asarray(acc, float)
    gyro = np.asarray(gyro, float)
    if temp.shape != t.shape or not np.any(np.isfinite(temp)):
        raise EngineInputError("the recording has no temperature; record with the temperature channel "
                               "(capture column 'temp') to fit a thermal model")
    if tau_s is not None and not tau_s > 0:
        raise EngineInputError(f"dT filter time constant {tau_s} s must be positive")
    # The filter runs on the whole stream, as firmware does; unknown readings hold the last one.
    finite = np.isfinite(temp)
    last = np.maximum.accumulate(np.where(finite, np.arange(len(temp)), 0))
    temp_filled = temp[last]
    if not finite[0]:
        temp_filled[: np.argmax(finite)] = temp[np.argmax(finite)]

    pose, names = still_poses(t, acc, gyro, step)
    if not names:
        raise EngineInputError("no still period found in the recording; a thermal sweep must hold the unit "
                               "still (label the steps with their pose or keep it motionless)")
    rate = 1.0 / np.median(np.diff(t))
    duration = t[-1] - t[0]
    block_s = max(block_s, duration / 20000.0)
    ids = _block_ids(pose, finite, max(int(round(block_s * rate)), 1))
    n_blocks = int(ids.max()) + 1 if np.any(ids >= 0) else 0
    if n_blocks < MIN_BLOCKS:
        raise EngineInputError(f"only {n_blocks} still blocks of {block_s:.3g} s with temperature; a thermal "
                               f"fit needs at least {MIN_BLOCKS} (record a longer sweep)")
    used = ids >= 0
    lo, hi = float(np.min(temp[used])), float(np.max(temp[used]))
    t_ref = float(reference_temp) if reference_temp is not None else round(0.5 * (lo + hi), 1)
    warnings: list[str] = []

    base, block_mean = _make_blocks(ids, t, temp, t_ref, acc, gyro, pose)

    def blocks_for(tau: float) -> _Blocks:
        dtemp = estimate_dtemp(t, temp_filled, DtempFilter("ema", tau))
        return _with_dtemp(base, block_mean, temp, t_ref, dtemp)

    present = sorted(set(pose[used]))
    remap = np.full(len(names), -1)
    remap[present] = np.arange(len(present))
    names = [names[p] for p in present]

    def remapped(b: _Blocks) -> _Blocks:
        b.pose = remap[b.pose]
        return b

    probe_tau = float(tau_s or TAU_CANDIDATES_S[1])
    probe = remapped(blocks_for(probe_tau))
    follows = _rate_follows_temp(probe)
    rate_usable = follows < RATE_FOLLOWS_TEMP_R2
    if not rate_usable:
        why = f"dT follows T in this recording (R^2 {follows:.3f} of dT on a cubic in T)"
        if terms is None:
            masks = [m for m in masks if not any(m[VARIABLE_TERMS.index(k)] for k in ("dt2", "dt", "tdt"))]
            warnings.append(f"{why}, as in a single warm-up: the dT terms cannot be told from the T terms "
                            "and are left out; to model dT, sweep up and down or at two speeds")
        else:
            warnings.append(f"{why}: the dT terms asked for are poorly determined and will not carry to "
                            "other ramp speeds")
        if tau_s is None and terms is None:
            tau_s = TAU_WITHOUT_RATE_S
    steps = (len(TAU_CANDIDATES_S) if tau_s is None else 0) + len(TRIADS)
    done = 0

    def advance() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done / steps)

    tau_scores: dict[float, float] = {}
    if tau_s is None:
        best: tuple[float, float, _Blocks] | None = None
        for tau in TAU_CANDIDATES_S:
            b = remapped(blocks_for(tau))
            fold = _fold_ids(b.pose, folds)
            score = 0.0
            for name, raw in (("accel", b.acc), ("gyro", b.gyro)):
                cal = accel_cal if name == "accel" else gyro_cal
                raw_mean = np.array([raw[b.pose == p].mean(axis=0) for p in range(len(names))])
                expected, signal = _expected(raw_mean, cal, gravity, name == "accel")
                y = raw - expected[b.pose]
                d = _design(b, y, fold, folds, [], t_ref, signal, len(names))
                full = _cv_sse(d, d.columns((True,) * len(VARIABLE_TERMS), None), np.eye(len(d.columns(
                    (True,) * len(VARIABLE_TERMS), None))), [0, 1, 2])
                none = _cv_sse(d, d.pose_cols, np.eye(len(d.pose_cols)), [0, 1, 2])
                score += float(np.sum(full.sum(axis=0) / np.maximum(none.sum(axis=0), 1e-300)))
            tau_scores[tau] = score / 6.0
            advance()
            if best is None or score < best[0] * (1 - 1e-3):
                best = (score, tau, b)
        assert best is not None  # TAU_CANDIDATES_S is not empty
        _, tau, blocks = best
    else:
        tau = float(tau_s)
        blocks = probe if tau == probe_tau else remapped(blocks_for(tau))
    fold = _fold_ids(blocks.pose, folds)

    lo, hi = float(blocks.temp.min()), float(blocks.temp.max())
    span = hi - lo
    if span < MIN_SPAN_DEGC:
        warnings.append(f"temperature span {span:.1f} degC is under {MIN_SPAN_DEGC:.0f} degC: the model is "
                        f"only fitted on [{lo:.1f}, {hi:.1f}] degC and clamped outside; sweep a wider range")
    if isinstance(segments, str):
        if segments != "auto":
            raise EngineInputError(f"segments {segments!r}: give 'auto', a number or join temperatures")
        n_max = max(1, min(max_segments, int(span // MIN_SEGMENT_SPAN_DEGC)))
        options = [_equal_breaks(lo, hi, n) for n in range(1, n_max + 1)]
    elif isinstance(segments, int | np.integer):
        if segments < 1:
            raise EngineInputError(f"segments {segments}: at least one segment")
        options = [_equal_breaks(lo, hi, int(segments))]
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

    dmax = float(np.max(np.abs(blocks.dtemp)))
    dt_clamp = (float(blocks.dtemp.min()) - dtemp_margin * dmax,
                float(blocks.dtemp.max()) + dtemp_margin * dmax)
    triads: dict[str, TriadFit] = {}
    for name in TRIADS:
        cal = accel_cal if name == "accel" else gyro_cal
        fit, messages = _fit_triad(name, blocks, fold, folds, len(names), t_ref, cal, gravity, options,
                                   fit_scale, dt_clamp, masks)
        triads[name] = fit
        warnings.extend(messages)
        advance()
    model = ThermalModel(
        reference_temp=t_ref,
        dtemp_filter=DtempFilter("ema", tau),
        accel=triads["accel"].bias_model,
        gyro=triads["gyro"].bias_model,
        extra={"method": "imu-station thermal: seven-term T/dT model, terms and segments by "
                         f"{folds}-fold cross-validation", "poses": names},
    )
    return ThermalFit(model, triads, blocks.temp, blocks.dtemp, blocks.time, blocks.pose, names, tau_scores,
                      warnings, block_s)
