"""Thermal fit, data preparation: still poses, averaging blocks and cross-validation folds.

The thermal bias moves slowly, so the fit sees block means of about a second of still samples
(one pose each) instead of the samples: the block means of the term columns of eq. (1) of
``thermal`` (t^3, t^2, t, dT^2, dT, t dT) and of the raw triads. Cross-validation holds out
interleaved stretches of each pose's blocks.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from station.engines.thermal.model import TERMS


def _axis_name(u: np.ndarray) -> str:
    """'+z' when u is within 10 degrees of a sensor axis, else a numbered name is given later."""
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) > np.cos(np.radians(10.0)):
        return ("+" if u[k] > 0 else "-") + "xyz"[k]
    return ""


def still_poses(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray,
                step: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """Pose index of every sample and the pose names.

    With step labels (capture-csv spec) every static label is a pose and rows between steps
    or in rotation steps are left out. Without labels (or with a step column left empty, as
    an unlabelled recording writes it), one-second windows whose accelerometer
    or gyroscope spread exceeds five times the median spread are motion; still windows with no motion
    between them are one pose, and after a motion a still window joins the pose whose mean specific
    force points within 5 degrees of its own, else starts a new one.

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    acc, gyro : ndarray, (N, 3)
        Raw samples.
    step : ndarray of str, (N,), optional
        Step labels.

    Returns
    -------
    tuple
        Pose index per sample (N,) (-1: moving or unlabelled) and the pose names.
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
    previous = -1
    for i in np.flatnonzero(still):
        # Without motion between two still windows the unit cannot have turned: the same pose, however far
        # the thermal bias (tens of mg over a sweep) has moved the direction of the mean.
        if previous >= 0 and not moving[previous:i].any():
            window_pose[i] = window_pose[previous]
        else:
            for k, c in enumerate(centres):
                if mean_dir[i] @ c > cos_tol:
                    window_pose[i] = k
                    break
            else:
                centres.append(mean_dir[i])
                window_pose[i] = len(centres) - 1
        previous = int(i)
    pose[: nw * w] = np.repeat(window_pose, w)
    names: list[str] = []
    for k, c in enumerate(centres):
        name = _axis_name(c)
        names.append(name if name and name not in names else f"pose{k + 1}")
    return pose, names


# ----------------------------------------------------------------------------- blocks

@dataclass
class Blocks:
    """Block means of one sweep (B blocks): what the fit sees instead of the samples.

    ``count`` samples per block; ``time``, ``temp``, ``dtemp`` means (s, degC, degC/s);
    ``terms`` (B, 7) the block means of the term columns of eq. (1) of ``thermal``; ``acc``,
    ``gyro`` (B, 3) raw means; ``pose`` the pose index of each block.
    """

    count: np.ndarray
    time: np.ndarray
    temp: np.ndarray
    dtemp: np.ndarray
    terms: np.ndarray  # (B, 7) block means of the term columns, TERMS order
    acc: np.ndarray
    gyro: np.ndarray
    pose: np.ndarray


def block_ids(pose: np.ndarray, ok: np.ndarray, length: int) -> np.ndarray:
    """Block index per sample: runs of one pose cut into blocks of about ``length`` samples.

    Parameters
    ----------
    pose : ndarray of int, (N,)
        Pose of each sample (-1: none).
    ok : ndarray of bool, (N,)
        Samples that may be used (a known temperature).
    length : int
        Target block length, samples; runs shorter than half of it are left out.

    Returns
    -------
    ndarray of int, (N,)
        -1 for unused samples.
    """
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


class BlockMeans:
    """Block means of per-sample quantities: what the fit sees instead of the samples."""

    def __init__(self, ids: np.ndarray):
        self.sel = ids >= 0
        self.index = ids[self.sel]
        self.count = np.bincount(self.index).astype(float)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if x.ndim == 2:
            return np.column_stack([self(x[:, j]) for j in range(x.shape[1])])
        return np.bincount(self.index, weights=x[self.sel]) / self.count


def make_blocks(ids: np.ndarray, t: np.ndarray, temp: np.ndarray, t_ref: float, acc: np.ndarray,
                 gyro: np.ndarray, pose: np.ndarray) -> tuple[Blocks, BlockMeans]:
    """Blocks with the temperature terms of eq. (1); the dT terms are filled in by :func:`with_dtemp`.

    Parameters
    ----------
    ids : ndarray of int, (N,)
        Block of each sample (:func:`block_ids`).
    t, temp : ndarray, (N,)
        Times (s) and temperatures (degC).
    t_ref : float
        T_ref of eq. (1).
    acc, gyro : ndarray, (N, 3)
    pose : ndarray of int, (N,)

    Returns
    -------
    tuple
        The :class:`Blocks` and the :class:`BlockMeans` that made them.
    """
    mean = BlockMeans(ids)
    t_rel = np.where(np.isfinite(temp), temp - t_ref, 0.0)
    terms = np.zeros((len(mean.count), len(TERMS)))
    for k, power in ((0, 3), (1, 2), (2, 1)):
        terms[:, k] = mean(t_rel**power)
    terms[:, -1] = 1.0
    first = np.zeros(len(mean.count), dtype=int)
    first[mean.index[::-1]] = np.flatnonzero(mean.sel)[::-1]
    blocks = Blocks(count=mean.count, time=mean(t), temp=mean(temp), dtemp=np.zeros(len(mean.count)),
                     terms=terms, acc=mean(acc), gyro=mean(gyro), pose=pose[first])
    return blocks, mean


def with_dtemp(blocks: Blocks, mean: BlockMeans, temp: np.ndarray, t_ref: float,
                dtemp: np.ndarray) -> Blocks:
    """A copy of ``blocks`` with the block means of dT, dT^2 and t dT (eq. 1) of this dT.

    Parameters
    ----------
    blocks : Blocks
    mean : BlockMeans
        The block means that made ``blocks``.
    temp : ndarray, (N,)
    t_ref : float
    dtemp : ndarray, (N,)
        Filtered dT per sample, degC/s.

    Returns
    -------
    Blocks
    """
    t_rel = np.where(np.isfinite(temp), temp - t_ref, 0.0)
    terms = blocks.terms.copy()
    d = mean(dtemp)
    terms[:, 3], terms[:, 4], terms[:, 5] = mean(dtemp**2), d, mean(t_rel * dtemp)
    return replace(blocks, dtemp=d, terms=terms, pose=blocks.pose.copy())


def stretch_ids(pose: np.ndarray, per_pose: int) -> np.ndarray:
    """Consecutive stretches of each pose's blocks, ``per_pose`` of them (fewer for a short pose),
    numbered across poses.

    Parameters
    ----------
    pose : ndarray of int, (B,)
        Pose of each block (blocks in time order within a pose).
    per_pose : int

    Returns
    -------
    ndarray of int, (B,)
    """
    out = np.zeros(len(pose), dtype=int)
    first = 0
    for p in np.unique(pose):
        idx = np.flatnonzero(pose == p)
        chunk = max(1, len(idx) // per_pose)
        out[idx] = first + np.arange(len(idx)) // chunk
        first = int(out[idx].max()) + 1
    return out


def fold_ids(pose: np.ndarray, folds: int) -> np.ndarray:
    """Interleaved held-out stretches: each pose's blocks in about 8 x ``folds`` runs, dealt round.

    Parameters
    ----------
    pose : ndarray of int, (B,)
        Pose of each block.
    folds : int

    Returns
    -------
    ndarray of int, (B,)
    """
    stretch = stretch_ids(pose, 8 * folds)
    out = np.zeros(len(pose), dtype=int)
    for p in np.unique(pose):
        idx = np.flatnonzero(pose == p)
        out[idx] = (stretch[idx] - stretch[idx[0]] + p) % folds
    return out


def rate_follows_temp(blocks: Blocks) -> float:
    """R^2 of dT regressed on a cubic in T: near 1 when dT is a function of T (one warm-up curve).

    Parameters
    ----------
    blocks : Blocks

    Returns
    -------
    float
    """
    t = blocks.terms[:, :3]
    x = np.column_stack([t, np.ones(len(t))])
    d = blocks.dtemp
    resid = d - x @ np.linalg.lstsq(x, d, rcond=None)[0]
    total = np.sum((d - d.mean()) ** 2)
    return float(1.0 - np.sum(resid**2) / total) if total > 0 else 1.0

