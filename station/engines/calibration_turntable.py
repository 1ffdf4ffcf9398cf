"""Calibration from a labelled capture of known poses and rotations (turntable, fixture, or the
station's guided sequences): checks the data, then runs ``calibration_static`` (accelerometer,
eq. 2 there) and ``calibration_rotation`` (gyroscope, eqs. 1-2 there).

Uncertainty. Each 1-sigma comes from the fit's covariance with the variance of one pose mean (or
one rotation's integral) taken as the larger of its white noise and the scatter of the residuals
about the fit, pooled over the three axes and Student-corrected (``pooled_scatter``): the bias
wanders from pose to pose (bias instability, rate random walk), and only the scatter shows it.
The bias needs one more term, the drift budget: the bias moved during the session, so the poses
measure the session's mean bias, which differs from the unit's long-run (static) bias by a
session-common offset that no single capture can see. It is budgeted as large as the drift
seen from pose to pose (``calibration_common.drift_budget``):

    sigma_b^2 = sigma_b,fit^2 + D,   D = max(s^2 - w, 0) + s^2 sqrt(2 / d)

with s^2 the pose values' scatter pooled over the axes (d degrees of freedom) and w their white
noise (accelerometer: the residuals of eq. 2 of ``calibration_static``; gyroscope: the static
steps' mean rates about their mean, since the true rate is zero in every one of them).
"""

from __future__ import annotations

import numpy as np

from station.engines.calibration_common import (
    CalibrationReport,
    dithers,
    drift_budget,
    lost_samples,
    pinned_run,
    pose_vector,
    rotation_of,
    segments,
    stddev_from,
)
from station.engines.calibration_rotation import fit_rotations, integrate
from station.engines.calibration_static import SIX, fit_poses, six_position, six_position_cov
from station.engines.earth import earth_rate_vertical
from station.engines.sensor_model import SensorCalibration
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
# Largest relative disagreement between a stated sample rate and the timestamps.
RATE_TOLERANCE = 0.02


# A static pose whose calibrated gravity direction is further than this from its label's is mislabelled
# (the nearest distinct labels of the spec are 35 deg apart; fixture errors are a few degrees).
LABEL_ANGLE_DEG = 10.0
# A rotation step whose axis is further than this from the vertical was not the labelled axis.
AXIS_ANGLE_DEG = 20.0
# A rotation whose calibrated angle misses its label by more than this (deg, or fraction of the angle).
ROTATION_ERROR_DEG = 5.0
ROTATION_ERROR_FRACTION = 0.02


def _span(t: np.ndarray, sl: slice) -> str:
    return f"t = {t[sl.start]:.2f}..{t[sl.stop - 1]:.2f} s"


def check_rate(t: np.ndarray, rate_hz: float | None) -> None:
    if len(t) < 2:
        raise EngineInputError("the capture has fewer than two samples")
    measured = 1.0 / float(np.median(np.diff(t)))
    if rate_hz is not None and abs(measured - rate_hz) > RATE_TOLERANCE * rate_hz:
        raise EngineInputError(
            f"the stated sample rate {rate_hz:g} Hz disagrees with the timestamps ({measured:.3f} Hz from "
            "the median step): check the device's rate setting or the capture's time column")


def _check_saturation(x: np.ndarray, name: str, t: np.ndarray, sl: slice, label: str,
                      noisy: np.ndarray) -> None:
    """Refuse a step where an axis sits at the capture's extreme value for several samples.

    Only axes that show noise in the static steps (``noisy``) are checked: there a run of
    identical samples at the extreme is a clipped signal, not a steady one.
    """
    seg = x[sl]
    for i, axis in enumerate("xyz"):
        if not noisy[i]:
            continue
        for extreme in (x[:, i].max(), x[:, i].min()):
            _, run = pinned_run(seg[:, i], extreme)
            if run >= SATURATION_RUN:
                raise EngineInputError(
                    f"step '{label}' ({_span(t, sl)}): the {name} {axis} axis is saturated (held at "
                    f"{extreme:g} for {run} samples); lower the rotation rate or raise the range")


def _shows_noise(x: np.ndarray, statics: list[tuple[str, slice]]) -> np.ndarray:
    """Per axis: do the static steps scatter by more than the output's resolution
    (``calibration_common.dithers``)?"""
    spread = np.median([x[sl].std(axis=0) for _, sl in statics], axis=0)
    return dithers(spread, np.concatenate([x[sl] for _, sl in statics]))


def nearest_label(direction: np.ndarray) -> str:
    """The pose label (``shared/specs/capture-csv.md``) nearest a direction: +x, -y+z, ..."""
    v = np.asarray(direction, float)
    big = np.abs(v) > 0.5 * np.abs(v).max()
    return "".join(f"{'+' if v[i] > 0 else '-'}{axis}" for i, axis in enumerate("xyz") if big[i])


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (deg) between the rows of a and of b (rows of any length, non-zero)."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _check_pose_labels(means: np.ndarray, up: np.ndarray, gravity: float, m_acc: np.ndarray,
                       b_acc: np.ndarray, statics: list[tuple[str, slice]], t: np.ndarray) -> None:
    """Refuse static steps whose readings contradict their labels (eq. 1 of ``calibration_static``).

    An accelerometer axis that reads -g under its '+' label means the '+' and '-' steps of that
    axis were swapped (the spec's labels name the axes that point up, where the accelerometer
    reads +g). Otherwise the calibrated gravity direction of every pose must lie within
    ``LABEL_ANGLE_DEG`` of its label's; where it does not, the step named is the one that
    disagrees most with a fit of the other poses (leave-one-out), so that a single mislabelled
    step is named even though it distorted the fit of all of them.
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
        f"static step '{label}' ({_span(t, sl)}) disagrees with its label: its gravity direction is "
        f"{max(loo[worst], angles[worst]):.0f} deg from '{label}' up (it reads nearest "
        f"'{nearest_label(direction)}' up); check the step labels (after calibration the poses' directions "
        f"differ from their labels by up to {angles.max():.0f} deg, {LABEL_ANGLE_DEG:g} deg allowed)")


def _check_rotation_axes(acc: np.ndarray, rotations: list[tuple[str, slice]], axes: np.ndarray,
                         m_acc: np.ndarray, b_acc: np.ndarray, t: np.ndarray) -> None:
    """Refuse a rotation step whose labelled axis was not vertical (the spec: it is, during the step),
    as the calibrated accelerometer shows it."""
    correction = np.linalg.inv(m_acc)
    for (label, sl), axis in zip(rotations, axes, strict=True):
        up = correction @ (acc[sl].mean(axis=0) - b_acc)
        tilt = min(float(_angle_deg(up, axis)), float(_angle_deg(up, -axis)))
        if tilt > AXIS_ANGLE_DEG:
            raise EngineInputError(
                f"rotation step '{label}' ({_span(t, sl)}): its axis was {tilt:.0f} deg from the vertical "
                f"(the accelerometer reads nearest '{nearest_label(up)}' up), so it was not a turn about the "
                f"labelled axis; check the step labels")


def _check_rotation_angles(angle_error: np.ndarray, angles: np.ndarray,
                           rotations: list[tuple[str, slice]], t: np.ndarray) -> None:
    """Refuse rotations whose calibrated angles contradict their labels (the fit of eq. 1 of
    ``calibration_rotation`` cannot make them agree: a wrong sign or angle in a label)."""
    limit = np.maximum(np.radians(ROTATION_ERROR_DEG), ROTATION_ERROR_FRACTION * np.abs(angles))
    excess = np.abs(angle_error) / limit
    worst = int(np.argmax(excess))
    if excess[worst] > 1:
        label, sl = rotations[worst]
        raise EngineInputError(
            f"rotation step '{label}' ({_span(t, sl)}): the calibrated gyroscope turned "
            f"{np.degrees(angles[worst] + angle_error[worst]):.1f} deg where the label says "
            f"{np.degrees(angles[worst]):.1f} deg, and no scale and misalignment make the rotations agree: "
            "check the rotation labels (sign, axis and angle)")


def calibrate_turntable(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray, step: np.ndarray | None,
                        gravity: float, latitude_deg: float | None = None,
                        rate_hz: float | None = None) -> CalibrationReport:
    """Accelerometer and gyroscope from a capture labelled per ``shared/specs/capture-csv.md``.

    Parameters
    ----------
    t : (N,) s.  acc, gyro : (N, 3) raw, any unit.  step : (N,) labels ("" between steps).
    gravity : local g (m/s^2) of eq. (1) in ``calibration_static``.
    latitude_deg : if given, the Earth rate's vertical part Omega sin(phi) is compensated
        (``calibration_rotation`` eqs. 1-2); the horizontal part is not (heading unknown).
    rate_hz : the sample rate the device was set to, checked against the timestamps.

    Returns
    -------
    CalibrationReport with accel (poses) and gyro (rotations) and per-step residuals.

    Raises
    ------
    EngineInputError for data that cannot determine the parameters: too few or degenerate
    poses, missing rotations, motion during a static step, saturation, a wrong sample rate.
    """
    t = np.asarray(t, float)
    acc = np.asarray(acc, float)
    gyro = np.asarray(gyro, float)
    if step is None or not any(str(s).strip() for s in step):
        raise EngineInputError("the capture has no step labels: the turntable method needs labelled poses "
                               "and rotations (a 'step' column); use --method free for unlabelled "
                               "hand-held data")
    check_rate(t, rate_hz)
    statics, rotations, unknown = [], [], []
    for label, sl in segments(step):
        if sl.stop - sl.start < 2:
            continue
        if pose_vector(label) is not None:
            statics.append((label, sl))
        elif rotation_of(label) is not None:
            rotations.append((label, sl))
        else:
            unknown.append(label)
    warnings = []
    if unknown:
        warnings.append(f"steps with labels that are neither poses nor rotations were ignored: "
                        f"{', '.join(sorted(set(unknown)))}")
    if not statics:
        raise EngineInputError("no static pose steps (labels such as +x, -x, +x+y): the accelerometer needs "
                               "at least the six poses +x -x +y -y +z -z")

    # --- static steps: motion and saturation checks, means --------------------------------------
    spread = np.array([acc[sl].std(axis=0).max() for _, sl in statics])
    typical = float(np.median(spread))
    level = float(np.median([np.linalg.norm(acc[sl].mean(axis=0)) for _, sl in statics]))
    acc_noisy = _shows_noise(acc, statics)
    gyro_noisy = _shows_noise(gyro, statics)
    for (label, sl), s in zip(statics, spread, strict=True):
        if s > MOTION_FACTOR * typical and s > MOTION_FLOOR * level:
            raise EngineInputError(
                f"the unit moved during static step '{label}' ({_span(t, sl)}): its accelerometer scatter "
                f"{s:.4g} is {s / max(typical, 1e-300):.0f} times that of the other static steps; repeat the "
                "step holding the unit still")
        if s > MOTION_ABSOLUTE * level:
            raise EngineInputError(
                f"the unit moved during static step '{label}' ({_span(t, sl)}): its accelerometer scatter "
                f"{s:.4g} is {s / level:.1%} of the gravity reading; repeat the step holding the unit still, "
                "or check that the step labels cover only the holds (not the moves between them)")
        _check_saturation(acc, "accelerometer", t, sl, label, acc_noisy)
    for label, sl in rotations:
        _check_saturation(gyro, "gyroscope", t, sl, label, gyro_noisy)

    labels = [lab for lab, _ in statics]
    up = np.array([pose_vector(lab) for lab in labels])
    means = np.array([acc[sl].mean(axis=0) for _, sl in statics])
    counts = np.array([sl.stop - sl.start for _, sl in statics])
    mean_var = np.array([acc[sl].var(axis=0, ddof=1) for _, sl in statics]) / counts[:, None]
    pose = fit_poses(means, up, gravity, mean_var, labels)
    m_acc, b_acc, acc_cov = pose.matrix, pose.bias, pose.cov
    six = sorted(labels) == sorted(SIX)
    if six:
        by_label = dict(zip(labels, means, strict=True))
        m_acc, b_acc = six_position(by_label, gravity)
        acc_cov = six_position_cov(by_label, gravity, pose.sigma2)
    _check_pose_labels(means, up, gravity, m_acc, b_acc, statics, t)
    for i, axis in enumerate("xyz"):
        if up[:, i].max() < 0.5 or up[:, i].min() > -0.5:
            warnings.append(f"accelerometer: the {axis} axis was never held near both up and down; its bias "
                            "and scale rest on tilted poses only")
    if pose.condition > 50:
        warnings.append(f"accelerometer: the poses determine the parameters poorly (condition number "
                        f"{pose.condition:.0f}); add opposite poses")

    def acc_parts(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return p[:9].reshape(3, 3), p[9:12]

    p_acc = np.concatenate([m_acc.ravel(), b_acc])
    acc_sd = stddev_from(acc_parts, p_acc, acc_cov)
    # Drift budget (module docstring): what the bias drifted from pose to pose.
    acc_sd["bias"] = np.sqrt(acc_sd["bias"] ** 2 + drift_budget(pose.residual, 4, np.mean(mean_var, axis=0)))
    calibrated = (means - b_acc) @ np.linalg.inv(m_acc).T
    norm_err = np.linalg.norm(calibrated, axis=1) - gravity
    residual_si = (means - (gravity * up @ m_acc.T + b_acc)) @ np.linalg.inv(m_acc).T
    acc_method = ("turntable: six-position analytic (Ferraris)" if six
                  else f"turntable: {len(labels)}-pose least squares")
    accel = SensorCalibration(m_acc, b_acc, method=acc_method,
                              residual_rms=float(np.sqrt(np.mean(residual_si**2))), stddev=acc_sd,
                              extra={"poses": len(labels), "residual": "mean reading - (M g u + b), m/s^2"})
    poses = [{"label": lab, "t0": float(t[sl.start]), "t1": float(t[sl.stop - 1]), "kind": "static",
              "residual": residual_si[k].tolist(), "norm_error": float(norm_err[k])}
             for k, (lab, sl) in enumerate(statics)]

    # --- gyroscope --------------------------------------------------------------------------------
    omega_v = earth_rate_vertical(latitude_deg) if latitude_deg is not None else 0.0
    static_gyro = np.concatenate([gyro[sl] for _, sl in statics])
    gyro_mean = static_gyro.mean(axis=0)
    gyro_cal = None
    if rotations:
        rot_labels = [lab for lab, _ in rotations]
        integrals = np.array([integrate(t[sl], gyro[sl]) for _, sl in rotations])
        durations = np.array([t[sl.stop - 1] - t[sl.start] for _, sl in rotations])
        info = [r for r in map(rotation_of, rot_labels) if r is not None]  # every label is a rotation's
        axes = np.array([i[0] for i in info])
        angles = np.array([i[1] for i in info])
        period = float(np.median(np.diff(t)))
        for label, sl in rotations:
            lost = lost_samples(t[sl], period)
            if lost is not None:
                raise EngineInputError(f"rotation step '{label}' ({_span(t, sl)}) has a gap of "
                                       f"{lost[1]:.3f} s in its timestamps (lost samples): the integrated "
                                       "angle would be wrong; repeat the rotation")
        _check_rotation_axes(acc, rotations, axes, m_acc, b_acc, t)
        static_var = static_gyro.var(axis=0, ddof=1)
        noise_var = np.array([static_var * np.sum(np.diff(t[sl]) ** 2) for _, sl in rotations])
        earth = None
        if latitude_deg is not None:
            correction = np.linalg.inv(m_acc)
            up_rot = np.array([correction @ (acc[sl].mean(axis=0) - b_acc) for _, sl in rotations])
            up_rot /= np.linalg.norm(up_rot, axis=1, keepdims=True)
            earth = omega_v * durations[:, None] * up_rot
        up_static = up[np.repeat(np.arange(len(statics)), counts)].mean(axis=0)
        rot, bias_solved = fit_rotations(integrals, angles, axes, durations, noise_var, rot_labels,
                                         gyro_mean, earth)
        if latitude_deg is not None:
            # eq. (2) needs M; one refinement with the fitted M is enough (the Earth term is tiny)
            gyro_mean = static_gyro.mean(axis=0) - rot.matrix @ (omega_v * up_static)
            if not bias_solved:
                rot, _ = fit_rotations(integrals, angles, axes, durations, noise_var, rot_labels,
                                       gyro_mean, earth)
        _check_rotation_angles(rot.angle_error, angles, rotations, t)
        m_g = rot.matrix
        for i, axis in enumerate("xyz"):
            if m_g[i, i] < 0:
                warnings.append(f"gyroscope: the {axis} axis turns opposite to the labels (scale "
                                f"{m_g[i, i]:.4g}): mounted reversed (the correction undoes it), unless the "
                                f"steps rot+{axis} and rot-{axis} were swapped")
        if not bias_solved:
            warnings.append("gyroscope: the rotations turn one way only about each axis, so the bias does "
                            "not cancel; the static bias was subtracted instead (add the opposite turns)")
        # Drift budget (module docstring): the step means scatter about their mean as the bias drifts
        # (the rate is zero in every static step).
        step_means = np.array([gyro[sl].mean(axis=0) for _, sl in statics])
        step_white = np.mean([gyro[sl].var(axis=0, ddof=1) / (sl.stop - sl.start) for _, sl in statics],
                             axis=0)
        drift = drift_budget(step_means - step_means.mean(axis=0), 1, step_white)
        b_sd = np.sqrt(static_var / len(static_gyro) + drift)

        def gyro_parts(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return p[:9].reshape(3, 3), gyro_mean

        gyro_sd = stddev_from(gyro_parts, np.concatenate([m_g.ravel(), rot.bias_rotation]), rot.cov)
        gyro_sd["bias"] = b_sd
        if rot.condition > 50:
            warnings.append(f"gyroscope: the rotations determine the parameters poorly (condition number "
                            f"{rot.condition:.0f}); turn about each axis both ways")
        gyro_cal = SensorCalibration(
            m_g, gyro_mean, method="turntable: rotations by integrated angle, bias from static steps",
            residual_rms=float(np.sqrt(np.mean(rot.angle_error**2))), stddev=gyro_sd,
            extra={"rotations": len(rotations), "residual": "integrated angle error, rad",
                   "earth_rate_compensated": latitude_deg is not None,
                   "bias_from_rotations": rot.bias_rotation.tolist()})
        poses += [{"label": lab, "t0": float(t[sl.start]), "t1": float(t[sl.stop - 1]), "kind": "rotation",
                   "angle_error_deg": float(np.degrees(rot.angle_error[k]))}
                  for k, (lab, sl) in enumerate(rotations)]
    else:
        warnings.append("no rotation steps: the gyroscope gets its bias only (scale and misalignment need "
                        "rot+x rot-x rot+y rot-y rot+z rot-z); its section is not written")
    details = {"poses": labels, "rotations": [lab for lab, _ in rotations],
               "gyro_bias_static": gyro_mean.tolist(), "latitude_deg": latitude_deg}
    return CalibrationReport(accel, gyro_cal, "turntable", gravity, poses, warnings, details)
