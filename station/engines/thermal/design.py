"""Thermal fit, model selection: the design of eq. (1) and cross-validated choice of its terms.

One design per segmentation: the variable terms of eq. (1) per temperature segment, segment
constants, one intercept per pose and the scale-against-T columns of eq. (4) of ``thermal``,
column-scaled, with per-fold Gram matrices so that every held-out fit is a small solve.
Continuity at a join T_j is imposed exactly, for every dT, by B_s(T_j, dT) = B_s+1(T_j, dT) at
dT = -1, 0, 1, solved in the constraints' null space. Terms are chosen per axis among the
subsets by K-fold cross-validation with the one-standard-error rule (Hastie, Tibshirani &
Friedman, The Elements of Statistical Learning, 2nd ed., sec. 7.10).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import null_space

from station.engines.thermal.blocks import Blocks
from station.engines.thermal.intrinsics import slope_weights
from station.engines.thermal.model import TERMS, term_matrix

VARIABLE_TERMS = TERMS[:-1]  # every term but the constant, which the pose intercepts carry


@dataclass
class Design:
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
        """Design columns of the terms in ``mask`` in every segment, the segment constants and pose
        intercepts, and the scale column of eq. (4) for axis ``scale_axis`` (None: without it).

        Parameters
        ----------
        mask : tuple of bool
            Subset of ``VARIABLE_TERMS``.
        scale_axis : int or None

        Returns
        -------
        list of int
        """
        cols = [int(c) for s in range(len(self.term_cols)) for k, on in enumerate(mask) if on
                for c in [self.term_cols[s, k]]]
        cols += self.const_cols + self.pose_cols
        if scale_axis is not None:
            cols.append(self.scale_cols[scale_axis])
        return cols

    def null_basis(self, cols: list[int]) -> np.ndarray:
        """Basis of the coefficient space (scaled) that keeps the model continuous at the joins.

        Parameters
        ----------
        cols : list of int
            Columns of the model (without the scale column).

        Returns
        -------
        ndarray, (len(cols), q)
        """
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


def design(blocks: Blocks, y: np.ndarray, fold: np.ndarray, folds: int, breaks: list[float], t_ref: float,
           expected: np.ndarray, n_poses: int) -> Design:
    """The design of eqs. (1) and (4) of ``thermal`` for the segmentation ``breaks``.

    Parameters
    ----------
    blocks : Blocks
        The blocks, with the term means of eq. (1).
    y : ndarray, (B, 3)
        Measured bias of each block, eqs. (2)-(3).
    fold : ndarray, (B,)
        Cross-validation fold of each block, of ``folds``.
    breaks : list of float
        Join temperatures, degC.
    t_ref : float
        T_ref of eq. (1).
    expected : ndarray, (P, 3)
        True-signal part E_p of each pose, the scale column's factor in eq. (4).
    n_poses : int
        Number of poses (one intercept column each).

    Returns
    -------
    Design
        Columns scaled to unit RMS, with each fold's Gram matrix X'X, X'y and y'y.
    """
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
    return Design(breaks, t_ref, seg, x, col_scale, term_cols, const_cols, pose_cols, scale_cols,
                   gram, xty, yy, nf)


def solve(gram: np.ndarray, rhs: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Least squares from normal equations within the basis ``z``; stacks of them solve at once.

    The columns are scaled to unit RMS, so a ridge of 1e-10 of the mean diagonal changes no
    determined coefficient and sets undetermined ones (a pose absent from a fold) to zero.

    Parameters
    ----------
    gram : ndarray, (..., C, C)
        X'X.
    rhs : ndarray, (..., C, k)
        X'y.
    z : ndarray, (C, q)
        Basis of the allowed coefficients (the continuity constraints' null space).

    Returns
    -------
    ndarray, (..., C, k)
    """
    a = z.T @ gram @ z
    m = a.shape[-1]
    ridge = 1e-10 * np.trace(a, axis1=-2, axis2=-1)[..., None, None] / m + 1e-300
    return z @ np.linalg.solve(a + ridge * np.eye(m), z.T @ rhs)


def fit_and_predict(d: Design, cols: list[int], z: np.ndarray, axis: int, fold: np.ndarray,
                     held_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The model on ``cols`` fitted on all blocks, and each fold's prediction from the other folds.

    Parameters
    ----------
    d : Design
    cols : list of int
        Columns of the model.
    z : ndarray
        Basis of the allowed coefficients.
    axis : int
    fold : ndarray of int, (B,)
    held_out : ndarray, (B, 3)
        Filled in column ``axis`` with the held-out predictions.

    Returns
    -------
    tuple of ndarray
        Scaled coefficients and fitted values on all blocks.
    """
    gf = d.gram[:, cols][:, :, cols]
    rf = d.xty[:, cols, axis]
    x = d.x[:, cols]
    beta_f = solve(gf.sum(axis=0) - gf, (rf.sum(axis=0) - rf)[:, :, None], z)[:, :, 0]
    for f in range(len(gf)):
        held_out[fold == f, axis] = x[fold == f] @ beta_f[f]
    beta = solve(gf.sum(axis=0), rf.sum(axis=0), z)
    return beta, x @ beta


def temperature_slope_sd(d: Design, cols: list[int], z: np.ndarray, y: np.ndarray, group: np.ndarray,
                         t_min: float, t_max: float) -> float:
    """1-sigma of the temperature sensitivity (``intrinsics.slope_weights``) of the
    model on ``cols``, by the delete-a-group jackknife over consecutive stretches of blocks.

    The sensitivity is linear in the scaled coefficients, S = g' beta. Each replicate refits without one
    group (its Gram matrix taken out of the whole), and

        var S = (G - 1) / G  sum_k (S_(k) - mean S_(.))^2                                   (6)

    (B. Efron and C. Stein, "The jackknife estimate of variance", Ann. Statist. 9 (1981); deleting
    whole stretches keeps the residuals' correlation within a stretch, as H. R. Kuensch, "The jackknife
    and the bootstrap for general stationary observations", Ann. Statist. 17 (1989), does for blocks).

    Parameters
    ----------
    d : Design
    cols : list of int
        Columns of the model.
    z : ndarray
        Basis of the allowed coefficients.
    y : ndarray, (B,)
        Measured bias of the axis.
    group : ndarray of int, (B,)
        Stretch of each block (:func:`station.engines.thermal.blocks.stretch_ids`).
    t_min, t_max : float
        The model's temperature range, degC.

    Returns
    -------
    float
        In the bias's unit per degC.
    """
    temp, w = slope_weights(t_min, t_max)
    seg = np.searchsorted(np.asarray(d.breaks), temp, side="right")
    phi = term_matrix(temp - d.t_ref, np.zeros_like(temp))
    where = {c: i for i, c in enumerate(cols)}
    g = np.zeros(len(cols))
    # the pose intercepts add a constant, which the weights (summing to zero) take out
    for s in np.unique(seg):
        ws = w[seg == s]
        for k in range(len(VARIABLE_TERMS)):
            c = int(d.term_cols[s, k])
            if c in where:
                g[where[c]] += float(ws @ phi[seg == s, k]) / d.col_scale[c]
        if s > 0:
            c = d.const_cols[s - 1]
            g[where[c]] += float(ws.sum()) / d.col_scale[c]
    x = d.x[:, cols]
    groups = np.unique(group)
    gram = np.stack([x[group == k].T @ x[group == k] for k in groups])
    rhs = np.stack([x[group == k].T @ y[group == k] for k in groups])
    beta = solve(gram.sum(axis=0) - gram, (rhs.sum(axis=0) - rhs)[:, :, None], z)[:, :, 0]
    replicates = beta @ g
    n = len(groups)
    return float(np.sqrt((n - 1) / n * np.sum((replicates - replicates.mean()) ** 2)))


@dataclass
class Candidate:
    """One candidate model of one axis: its terms, whether it has the scale column, its number of
    free parameters and its held-out sum of squares per fold."""

    mask: tuple[bool, ...]
    scale: bool
    params: int
    sse: np.ndarray  # (F,) held-out sum of squares per fold

    def mse(self, nf: np.ndarray) -> float:
        """Held-out mean squared error over all folds (``nf`` blocks per fold).

        Parameters
        ----------
        nf : ndarray, (F,)

        Returns
        -------
        float
        """
        return float(self.sse.sum() / nf.sum())

    def se(self, nf: np.ndarray) -> float:
        """Standard error of the held-out MSE from its spread over the folds.

        Parameters
        ----------
        nf : ndarray, (F,)

        Returns
        -------
        float
        """
        per_fold = self.sse / np.maximum(nf, 1)
        return float(per_fold.std(ddof=1) / np.sqrt(len(nf))) if len(nf) > 1 else 0.0


def cv_sse(d: Design, cols: list[int], z: np.ndarray, axes: list[int]) -> np.ndarray:
    """Held-out sum of squared residuals for the model on ``cols`` within ``z``.

    Fold f is fitted on the Gram matrix of the other folds and scored on its own:
    |y_f - X_f beta|^2 = y_f'y_f - 2 beta'X_f'y_f + beta'X_f'X_f beta.

    Parameters
    ----------
    d : Design
    cols : list of int
    z : ndarray
    axes : list of int

    Returns
    -------
    ndarray, (F, len(axes))
    """
    gf = d.gram[:, cols][:, :, cols]
    rf = d.xty[:, cols][:, :, axes]
    beta = solve(gf.sum(axis=0) - gf, rf.sum(axis=0) - rf, z)
    out = d.yy[:, axes] - 2 * np.sum(beta * rf, axis=1) + np.einsum("fia,fij,fja->fa", beta, gf, beta)
    return np.maximum(out, 0.0)


def candidates(d: Design, scale_axes: list[bool], masks: list[tuple[bool, ...]]) -> list[list[Candidate]]:
    """Each term subset of ``masks``, and with the scale column of eq. (4) where allowed, per axis.

    Parameters
    ----------
    d : Design
    scale_axes : list of bool
        Axes that may take the scale column.
    masks : list of tuple of bool
        Subsets of ``VARIABLE_TERMS``.

    Returns
    -------
    list of list of Candidate
        One list per axis.
    """
    per_axis: list[list[Candidate]] = [[], [], []]
    for mask in masks:
        cols = d.columns(mask, None)
        z = d.null_basis(cols)
        sse = cv_sse(d, cols, z, [0, 1, 2])
        for j in range(3):
            per_axis[j].append(Candidate(mask, False, z.shape[1], sse[:, j]))
        for j in range(3):
            if not scale_axes[j]:
                continue
            cols_s = d.columns(mask, j)
            z_s = np.zeros((z.shape[0] + 1, z.shape[1] + 1))
            z_s[:-1, :-1] = z
            z_s[-1, -1] = 1.0
            per_axis[j].append(Candidate(mask, True, z_s.shape[1], cv_sse(d, cols_s, z_s, [j])[:, 0]))
    return per_axis


def one_se(cands: list[Candidate], nf: np.ndarray) -> Candidate:
    """The one-standard-error rule (Hastie, Tibshirani & Friedman 2009, sec. 7.10): the candidate
    with fewest parameters whose held-out MSE is within one standard error of the best's.

    Parameters
    ----------
    cands : list of Candidate
    nf : ndarray, (F,)
        Blocks per fold.

    Returns
    -------
    Candidate
    """
    best = min(cands, key=lambda c: c.mse(nf))
    limit = best.mse(nf) + best.se(nf)
    return min((c for c in cands if c.mse(nf) <= limit), key=lambda c: (c.params, c.mse(nf)))


def equal_breaks(lo: float, hi: float, n: int) -> list[float]:
    """The joins of ``n`` equal-width segments of [lo, hi].

    Parameters
    ----------
    lo, hi : float
        degC.
    n : int

    Returns
    -------
    list of float
        n - 1 joins.
    """
    return [float(v) for v in np.linspace(lo, hi, n + 1)[1:-1]]

