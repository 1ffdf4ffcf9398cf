"""The turntable method's refusals: data whose steps contradict their labels or cannot be trusted.

Each check raises :class:`EngineInputError` naming the step (label and time span) and what to
do: motion during a static step, a saturated axis, lost samples inside a rotation, a static
pose whose gravity direction is not its label's (eq. 1 of ``calibration_static``), a rotation
about another axis or by another angle than its label says (eq. 1 of ``calibration_rotation``).
"""

from __future__ import annotations

import numpy as np

from station.engines.calibration.common import dithers, lost_samples, pinned_run
from station.errors import EngineInputError

# A static step whose scatter exceeds this many times the typical static scatter has moved.
MOTION_FACTOR = 4.0
# ... and by at least this fraction of the accelerometer's gravity reading (ignores tiny noise).
MOTION_FLOOR = 0.005
# A static step whose scatter exceeds this fraction of the gravity reading has moved, whatever the
# other steps do (labels that all reach into the moves; MEMS noise is below 0.01 even at 1 kHz).
MOTION_ABSOLUTE = 0.03
# Fewest consecutive samples pinned at an axis's extreme that count as saturation.
SATURATION_RUN = 5
# A static pose whose calibrated gravity direction is further than this from its label's is mislabelled
# (the nearest distinct labels of the spec are 35 deg apart; fixture errors are a few degrees).
LABEL_ANGLE_DEG = 10.0
# A rotation step whose axis is further than this from the vertical was not the labelled axis.
AXIS_ANGLE_DEG = 20.0
# A rotation whose calibrated angle misses its label by more than this (deg, or fraction of the angle).
ROTATION_ERROR_DEG = 5.0
ROTATION_ERROR_FRACTION = 0.02

Steps = list[tuple[str, slice]]


def span(t: np.ndarray, sl: slice) -> str:
    """The time span of a step for messages.

    Parameters
    ----------
    t : ndarray, (N,)
    sl : slice

    Returns
    -------
    str
        ``t = 1.00..9.99 s``.
    """
    return f"t = {t[sl.start]:.2f}..{t[sl.stop - 1]:.2f} s"


def _check_saturation(x: np.ndarray, extremes: np.ndarray, name: str, t: np.ndarray, sl: slice, label: str,
                      noisy: np.ndarray) -> None:
    """Refuse a step where an axis sits at the capture's extreme value (``extremes``: (2, 3), the
    capture's maxima and minima, found once for every step) for several samples.

    Only axes that show noise in the static steps (``noisy``) are checked: there a run of
    identical samples at the extreme is a clipped signal, not a steady one.
    """
    seg = x[sl]
    for i, axis in enumerate("xyz"):
        if not noisy[i]:
            continue
        for extreme in extremes[:, i]:
            _, run = pinned_run(seg[:, i], extreme)
            if run >= SATURATION_RUN:
                raise EngineInputError(
                    f"step '{label}' ({span(t, sl)}): the {name} {axis} axis is saturated (held at "
                    f"{extreme:g} for {run} samples); lower the rotation rate or raise the range")


def _shows_noise(x: np.ndarray, statics: Steps) -> np.ndarray:
    """Per axis: do the static steps scatter by more than the output's resolution
    (``calibration_common.dithers``)?"""
    spread = np.median([x[sl].std(axis=0) for _, sl in statics], axis=0)
    return dithers(spread, np.concatenate([x[sl] for _, sl in statics]))


def check_steady_steps(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray, statics: Steps,
                       rotations: Steps) -> None:
    """Refuse motion during a static step and saturation in any step.

    A static step moved when its accelerometer scatter exceeds ``MOTION_FACTOR`` times the
    median static scatter (and ``MOTION_FLOOR`` of the gravity reading), or ``MOTION_ABSOLUTE``
    of the gravity reading whatever the others do.

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    acc, gyro : ndarray, (N, 3)
        Raw samples.
    statics, rotations : list of (label, slice)
        The static pose steps and the rotation steps.

    Raises
    ------
    EngineInputError
        Names the first step that moved or saturated.
    """
    spread = np.array([acc[sl].std(axis=0).max() for _, sl in statics])
    typical = float(np.median(spread))
    level = float(np.median([np.linalg.norm(acc[sl].mean(axis=0)) for _, sl in statics]))
    acc_noisy = _shows_noise(acc, statics)
    gyro_noisy = _shows_noise(gyro, statics)
    acc_extremes, gyro_extremes = (np.stack([x.max(axis=0), x.min(axis=0)]) for x in (acc, gyro))
    for (label, sl), s in zip(statics, spread, strict=True):
        if s > MOTION_FACTOR * typical and s > MOTION_FLOOR * level:
            raise EngineInputError(
                f"the unit moved during static step '{label}' ({span(t, sl)}): its accelerometer scatter "
                f"{s:.4g} is {s / max(typical, 1e-300):.0f} times that of the other static steps; repeat the "
                "step holding the unit still")
        if s > MOTION_ABSOLUTE * level:
            raise EngineInputError(
                f"the unit moved during static step '{label}' ({span(t, sl)}): its accelerometer scatter "
                f"{s:.4g} is {s / level:.1%} of the gravity reading; repeat the step holding the unit still, "
                "or check that the step labels cover only the holds (not the moves between them)")
        _check_saturation(acc, acc_extremes, "accelerometer", t, sl, label, acc_noisy)
    for label, sl in rotations:
        _check_saturation(gyro, gyro_extremes, "gyroscope", t, sl, label, gyro_noisy)


def check_rotation_gaps(t: np.ndarray, rotations: Steps) -> None:
    """Refuse lost samples inside a rotation step: its integrated angle (eq. 1 of
    ``calibration_rotation``) would be short.

    Parameters
    ----------
    t : ndarray, (N,)
        Sample times, s.
    rotations : list of (label, slice)
        The rotation steps.

    Raises
    ------
    EngineInputError
        Names the rotation and the size of its gap.
    """
    period = float(np.median(np.diff(t)))
    for label, sl in rotations:
        lost = lost_samples(t[sl], period)
        if lost is not None:
            raise EngineInputError(f"rotation step '{label}' ({span(t, sl)}) has a gap of "
                                   f"{lost[1]:.3f} s in its timestamps (lost samples): the integrated "
                                   "angle would be wrong; repeat the rotation")


def nearest_label(direction: np.ndarray) -> str:
    """The pose label (``shared/specs/capture-csv.md``) nearest a direction.

    Parameters
    ----------
    direction : ndarray, (3,)
        A direction in the sensor frame, any length.

    Returns
    -------
    str
        The axes whose component exceeds half the largest one, with their signs: ``+x``, ``-y+z``.
    """
    v = np.asarray(direction, float)
    big = np.abs(v) > 0.5 * np.abs(v).max()
    return "".join(f"{'+' if v[i] > 0 else '-'}{axis}" for i, axis in enumerate("xyz") if big[i])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (deg) between the rows of a and of b (rows of any length, non-zero)."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def check_pose_labels(means: np.ndarray, up: np.ndarray, gravity: float, m_acc: np.ndarray,
                      b_acc: np.ndarray, statics: Steps, t: np.ndarray) -> None:
    """Refuse static steps whose readings contradict their labels (eq. 1 of ``calibration_static``).

    An accelerometer axis that reads -g under its '+' label means the '+' and '-' steps of that
    axis were swapped (the spec's labels name the axes that point up, where the accelerometer
    reads +g). Otherwise the calibrated gravity direction of every pose must lie within
    ``LABEL_ANGLE_DEG`` of its label's; where it does not, the step named is the one that
    disagrees most with a fit of the other poses (leave-one-out), so that a single mislabelled
    step is named even though it distorted the fit of all of them.

    Parameters
    ----------
    means : ndarray, (P, 3)
        Mean raw accelerometer reading of each pose.
    up : ndarray, (P, 3)
        Unit up vector of each pose's label.
    gravity : float
        Local g, m/s^2.
    m_acc, b_acc : ndarray
        The fitted M (3, 3) and b (3,) of eq. (1).
    statics : list of (label, slice)
        The static steps, in the order of ``means``.
    t : ndarray, (N,)
        Sample times, s (for the message).

    Raises
    ------
    EngineInputError
        Names the swapped axis or the mislabelled step.
    """
    labels = [lab for lab, _ in statics]
    scale = np.diag(m_acc)
    for i, axis in enumerate("xyz"):
        if scale[i] < 0:
            on_axis = [lab for lab, u in zip(labels, up, strict=True) if abs(u[i]) > 0.5]
            raise EngineInputError(
                f"the accelerometer {axis} axis reads -g where the labels put +{axis} up (steps "
                f"{', '.join(on_axis)}): the steps +{axis} and -{axis} are swapped, or the {axis} axis is "
                f"mounted reversed; check the step labels (they name the axes that point up)")
    correction = np.linalg.pinv(m_acc)
    seen = (means - b_acc) @ correction.T     # calibrated gravity per pose; leave-one-out below
    angles = _angle_deg(seen, up)
    if angles.max() <= LABEL_ANGLE_DEG:
        return
    design = np.hstack([gravity * up, np.ones((len(up), 1))])
    loo = np.zeros(len(up))
    for p in range(len(up)):
        keep = np.arange(len(up)) != p
        if np.linalg.matrix_rank(design[keep], tol=1e-9) < 4:
            continue
        theta, *_ = np.linalg.lstsq(design[keep], means[keep], rcond=None)
        seen[p] = np.linalg.pinv(theta[:3].T) @ (means[p] - theta[3])
        loo[p] = _angle_deg(seen[p], up[p])
    worst = int(np.argmax(loo)) if loo.max() > LABEL_ANGLE_DEG else int(np.argmax(angles))
    label, sl = statics[worst]
    direction = seen[worst]
    raise EngineInputError(
        f"static step '{label}' ({span(t, sl)}) disagrees with its label: its gravity direction is "
        f"{max(loo[worst], angles[worst]):.0f} deg from '{label}' up (it reads nearest "
        f"'{nearest_label(direction)}' up); check the step labels (after calibration the poses' directions "
        f"differ from their labels by up to {angles.max():.0f} deg, {LABEL_ANGLE_DEG:g} deg allowed)")


def check_rotation_axes(acc: np.ndarray, rotations: Steps, axes: np.ndarray, m_acc: np.ndarray,
                        b_acc: np.ndarray, t: np.ndarray) -> None:
    """Refuse a rotation step whose labelled axis was not vertical (the spec: it is, during the
    step), as the calibrated accelerometer shows it.

    Parameters
    ----------
    acc : ndarray, (N, 3)
        Raw accelerometer samples.
    rotations : list of (label, slice)
        The rotation steps.
    axes : ndarray, (R, 3)
        The labelled axis of each rotation.
    m_acc, b_acc : ndarray
        The accelerometer's M (3, 3) and b (3,).
    t : ndarray, (N,)
        Sample times, s (for the message).

    Raises
    ------
    EngineInputError
        Names the rotation whose axis was more than ``AXIS_ANGLE_DEG`` from the vertical.
    """
    correction = np.linalg.inv(m_acc)
    for (label, sl), axis in zip(rotations, axes, strict=True):
        up = correction @ (acc[sl].mean(axis=0) - b_acc)
        tilt = min(float(_angle_deg(up, axis)), float(_angle_deg(up, -axis)))
        if tilt > AXIS_ANGLE_DEG:
            raise EngineInputError(
                f"rotation step '{label}' ({span(t, sl)}): its axis was {tilt:.0f} deg from the vertical "
                f"(the accelerometer reads nearest '{nearest_label(up)}' up), so it was not a turn about the "
                f"labelled axis; check the step labels")


def check_rotation_angles(angle_error: np.ndarray, angles: np.ndarray, rotations: Steps,
                          t: np.ndarray) -> None:
    """Refuse rotations whose calibrated angles contradict their labels (the fit of eq. 1 of
    ``calibration_rotation`` cannot make them agree: a wrong sign or angle in a label).

    Parameters
    ----------
    angle_error : ndarray, (R,)
        Calibrated minus labelled angle of each rotation, rad.
    angles : ndarray, (R,)
        Labelled angles, rad.
    rotations : list of (label, slice)
        The rotation steps.
    t : ndarray, (N,)
        Sample times, s (for the message).

    Raises
    ------
    EngineInputError
        Names the rotation furthest beyond ``ROTATION_ERROR_DEG`` or ``ROTATION_ERROR_FRACTION``.
    """
    limit = np.maximum(np.radians(ROTATION_ERROR_DEG), ROTATION_ERROR_FRACTION * np.abs(angles))
    excess = np.abs(angle_error) / limit
    worst = int(np.argmax(excess))
    if excess[worst] > 1:
        label, sl = rotations[worst]
        raise EngineInputError(
            f"rotation step '{label}' ({span(t, sl)}): the calibrated gyroscope turned "
            f"{np.degrees(angles[worst] + angle_error[worst]):.1f} deg where the label says "
            f"{np.degrees(angles[worst]):.1f} deg, and no scale and misalignment make the rotations agree: "
            "check the rotation labels (sign, axis and angle)")
