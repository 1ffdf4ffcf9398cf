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

:func:`calibrate_turntable` takes a :class:`TurntableCapture` (the arrays, checked once) and
:class:`TurntableSettings`, and runs the stages below in turn.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from station.engines.calibration._rotation import RotationFit, fit_rotations, integrate
from station.engines.calibration._static import SIX, PoseFit, fit_poses, six_position, six_position_cov
from station.engines.calibration.common import (
    CalibrationReport,
    drift_budget,
    pose_vector,
    rotation_of,
    segments,
    stddev_from,
)
from station.engines.calibration.turntable_checks import (
    Steps,
    check_pose_labels,
    check_rotation_angles,
    check_rotation_axes,
    check_rotation_gaps,
    check_steady_steps,
)
from station.engines.calibration.turntable_gsens import g_sensitivity_from_poses
from station.engines.shared.earth import STANDARD_GRAVITY, earth_rate_vertical
from station.engines.shared.samples import as_samples, check_rate
from station.engines.shared.sensor_model import SensorCalibration
from station.errors import EngineInputError


@dataclass(frozen=True)
class TurntableSettings:
    """How to run the turntable method.

    Attributes
    ----------
    gravity : float
        Local g (m/s^2) of eq. (1) in ``calibration_static``.
    latitude_deg : float or None
        If given, the Earth rate's vertical part Omega sin(phi) is compensated
        (``calibration_rotation`` eqs. 1-2); the horizontal part is not (heading unknown).
    """

    gravity: float = STANDARD_GRAVITY
    latitude_deg: float | None = None


@dataclass(frozen=True)
class TurntableCapture:
    """A capture labelled per ``shared/specs/capture-csv.md``, checked once on construction.

    Parameters
    ----------
    t : array_like, (N,)
        Sample times, s.
    acc, gyro : array_like, (N, 3)
        Raw samples, any unit.
    step : array_like of str, (N,) or None
        Step labels ("" between steps).
    rate_hz : float or None
        The sample rate the device was set to, checked against the timestamps.

    Attributes
    ----------
    statics, rotations : list of (label, slice)
        The static pose steps and the rotation steps, in capture order (steps of one sample
        are left out).
    ignored : list of str
        Labels that are neither poses nor rotations.

    Raises
    ------
    EngineInputError
        Arrays of the wrong shape or with non-finite values, no step labels, a rate the
        timestamps contradict, no static pose step.
    """

    t: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    step: np.ndarray | None
    rate_hz: float | None = None
    statics: Steps = field(init=False, repr=False)
    rotations: Steps = field(init=False, repr=False)
    ignored: list[str] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t, acc, gyro = as_samples(self.t, self.acc, self.gyro)
        step = self.step
        if step is None or not any(str(s).strip() for s in step):
            raise EngineInputError("the capture has no step labels: the turntable method needs labelled "
                                   "poses and rotations (a 'step' column); use --method free for "
                                   "unlabelled hand-held data")
        if len(step) != len(t):
            raise EngineInputError(f"the step column has {len(step)} labels for {len(t)} samples; give one "
                                   "label per sample")
        check_rate(t, self.rate_hz)
        statics, rotations, ignored = [], [], []
        for label, sl in segments(step):
            if sl.stop - sl.start < 2:
                continue
            if pose_vector(label) is not None:
                statics.append((label, sl))
            elif rotation_of(label) is not None:
                rotations.append((label, sl))
            else:
                ignored.append(label)
        if not statics:
            raise EngineInputError("no static pose steps (labels such as +x, -x, +x+y): the accelerometer "
                                   "needs at least the six poses +x -x +y -y +z -z")
        for name, value in (("t", t), ("acc", acc), ("gyro", gyro), ("statics", statics),
                            ("rotations", rotations), ("ignored", ignored)):
            object.__setattr__(self, name, value)


@dataclass
class AccelStage:
    """The accelerometer's pose fit (eqs. 1-3 of ``calibration_static``) and what it rests on."""

    labels: list[str]
    up: np.ndarray          # (P, 3) unit up vector of each pose
    means: np.ndarray       # (P, 3) mean raw reading of each pose
    counts: np.ndarray      # (P,) samples of each pose
    mean_var: np.ndarray    # (P, 3) white-noise variance of each pose mean
    fit: PoseFit
    matrix: np.ndarray
    bias: np.ndarray
    cov: np.ndarray
    six: bool               # the six-position analytic solution, eq. (3)
    warnings: list[str]


def fit_accelerometer(data: TurntableCapture, gravity: float) -> AccelStage:
    """M and b of the accelerometer from the static poses: eq. (2) of ``calibration_static``, or
    eq. (3) there (Ferraris et al. 1995, eqs. 19-23) for exactly the six poses +-x, +-y, +-z.

    Parameters
    ----------
    data : TurntableCapture
        The checked capture.
    gravity : float
        Local g, m/s^2.

    Returns
    -------
    AccelStage
        The fit, with warnings about axes held only tilted or a poorly conditioned design.

    Raises
    ------
    EngineInputError
        Degenerate poses (``fit_poses``) or poses that contradict their labels.
    """
    statics = data.statics
    labels = [lab for lab, _ in statics]
    up = np.array([pose_vector(lab) for lab in labels])
    means = np.array([data.acc[sl].mean(axis=0) for _, sl in statics])
    counts = np.array([sl.stop - sl.start for _, sl in statics])
    mean_var = np.array([data.acc[sl].var(axis=0, ddof=1) for _, sl in statics]) / counts[:, None]
    pose = fit_poses(means, up, gravity, mean_var, labels)
    m_acc, b_acc, acc_cov = pose.matrix, pose.bias, pose.cov
    six = sorted(labels) == sorted(SIX)
    if six:
        by_label = dict(zip(labels, means, strict=True))
        m_acc, b_acc = six_position(by_label, gravity)
        acc_cov = six_position_cov(by_label, gravity, pose.sigma2)
    check_pose_labels(means, up, gravity, m_acc, b_acc, statics, data.t)
    warnings = []
    for i, axis in enumerate("xyz"):
        if up[:, i].max() < 0.5 or up[:, i].min() > -0.5:
            warnings.append(f"accelerometer: the {axis} axis was never held near both up and down; its bias "
                            "and scale rest on tilted poses only")
    if pose.condition > 50:
        warnings.append(f"accelerometer: the poses determine the parameters poorly (condition number "
                        f"{pose.condition:.0f}); add opposite poses")
    return AccelStage(labels, up, means, counts, mean_var, pose, m_acc, b_acc, acc_cov, six, warnings)


def accel_calibration(stage: AccelStage, data: TurntableCapture,
                      gravity: float) -> tuple[SensorCalibration, list[dict[str, Any]]]:
    """The accelerometer's :class:`SensorCalibration` with its 1-sigma and drift budget (module
    docstring), and the per-pose report: residual of eq. (1) in m/s^2 and the error of |g|.

    Parameters
    ----------
    stage : AccelStage
        The pose fit.
    data : TurntableCapture
        The checked capture.
    gravity : float
        Local g, m/s^2.

    Returns
    -------
    tuple
        The calibration and one dict per static pose.
    """
    m_acc, b_acc = stage.matrix, stage.bias

    def acc_parts(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return p[:9].reshape(3, 3), p[9:12]

    p_acc = np.concatenate([m_acc.ravel(), b_acc])
    acc_sd = stddev_from(acc_parts, p_acc, stage.cov)
    # Drift budget (module docstring): what the bias drifted from pose to pose.
    acc_sd["bias"] = np.sqrt(acc_sd["bias"] ** 2
                             + drift_budget(stage.fit.residual, 4, np.mean(stage.mean_var, axis=0)))
    calibrated = (stage.means - b_acc) @ np.linalg.inv(m_acc).T
    norm_err = np.linalg.norm(calibrated, axis=1) - gravity
    residual_si = (stage.means - (gravity * stage.up @ m_acc.T + b_acc)) @ np.linalg.inv(m_acc).T
    acc_method = ("turntable: six-position analytic (Ferraris)" if stage.six
                  else f"turntable: {len(stage.labels)}-pose least squares")
    accel = SensorCalibration(m_acc, b_acc, method=acc_method,
                              residual_rms=float(np.sqrt(np.mean(residual_si**2))), stddev=acc_sd,
                              extra={"poses": len(stage.labels),
                                     "residual": "mean reading - (M g u + b), m/s^2"})
    t = data.t
    poses = [{"label": lab, "t0": float(t[sl.start]), "t1": float(t[sl.stop - 1]), "kind": "static",
              "residual": residual_si[k].tolist(), "norm_error": float(norm_err[k])}
             for k, (lab, sl) in enumerate(data.statics)]
    return accel, poses


@dataclass
class GyroStage:
    """The gyroscope's result: its calibration (None without rotations), the static bias of eq. (2)
    of ``calibration_rotation``, the per-rotation report and warnings."""

    calibration: SensorCalibration | None
    bias_static: np.ndarray
    poses: list[dict[str, Any]]
    warnings: list[str]


def fit_gyroscope(data: TurntableCapture, accel: AccelStage, settings: TurntableSettings) -> GyroStage:
    """M of the gyroscope from the rotations (eq. 1 of ``calibration_rotation``), b from the static
    steps (eq. 2 there), with the Earth rate's vertical part when ``settings.latitude_deg`` is set.

    Parameters
    ----------
    data : TurntableCapture
        The checked capture.
    accel : AccelStage
        The accelerometer's fit (it shows which way is up during each rotation).
    settings : TurntableSettings
        Gravity and latitude.

    Returns
    -------
    GyroStage
        Without rotation steps: no calibration, the static bias only, and a warning.

    Raises
    ------
    EngineInputError
        Lost samples in a rotation, a rotation about another axis or by another angle than its
        label's, or rotations that cannot determine M (``fit_rotations``).
    """
    t, acc, gyro = data.t, data.acc, data.gyro
    statics, rotations = data.statics, data.rotations
    latitude_deg = settings.latitude_deg
    omega_v = earth_rate_vertical(latitude_deg) if latitude_deg is not None else 0.0
    static_gyro = np.concatenate([gyro[sl] for _, sl in statics])
    gyro_mean = static_gyro.mean(axis=0)
    if not rotations:
        return GyroStage(None, gyro_mean, [], [
            "no rotation steps: the gyroscope gets its bias only (scale and misalignment need "
            "rot+x rot-x rot+y rot-y rot+z rot-z); its section is not written"])
    warnings = []
    rot_labels = [lab for lab, _ in rotations]
    integrals = np.array([integrate(t[sl], gyro[sl]) for _, sl in rotations])
    durations = np.array([t[sl.stop - 1] - t[sl.start] for _, sl in rotations])
    info = [r for r in map(rotation_of, rot_labels) if r is not None]  # every label is a rotation's
    axes = np.array([i[0] for i in info])
    angles = np.array([i[1] for i in info])
    check_rotation_gaps(t, rotations)
    check_rotation_axes(acc, rotations, axes, accel.matrix, accel.bias, t)
    static_var = static_gyro.var(axis=0, ddof=1)
    noise_var = np.array([static_var * np.sum(np.diff(t[sl]) ** 2) for _, sl in rotations])
    correction = np.linalg.inv(accel.matrix)
    force_rot = np.array([correction @ (acc[sl].mean(axis=0) - accel.bias) for _, sl in rotations])
    # g-sensitivity (calibration_turntable_gsens, eq. 1), where the poses determine it (the Earth term
    # there with M ~ I: its error is below 1e-6 rad/s). The bias stays the static mean: the poses'
    # specific force averages to zero in the built-in sequences, where it is the intercept of eq. (1)
    # too. Each turn, its axis vertical, feels g along it: G f T is taken out of its integral.
    gsens = g_sensitivity_from_poses(acc, gyro, statics, accel.matrix, accel.bias, np.eye(3), omega_v)
    warnings += gsens.warnings
    if gsens.matrix is not None:
        integrals = integrals - durations[:, None] * force_rot @ gsens.matrix.T
    earth = None
    if latitude_deg is not None:
        up_rot = force_rot / np.linalg.norm(force_rot, axis=1, keepdims=True)
        earth = omega_v * durations[:, None] * up_rot
    up_static = accel.up[np.repeat(np.arange(len(statics)), accel.counts)].mean(axis=0)
    rot, bias_solved = fit_rotations(integrals, angles, axes, durations, noise_var, rot_labels,
                                     gyro_mean, earth)
    if latitude_deg is not None:
        # eq. (2) needs M; one refinement with the fitted M is enough (the Earth term is tiny)
        gyro_mean = static_gyro.mean(axis=0) - rot.matrix @ (omega_v * up_static)
        if not bias_solved:
            rot, _ = fit_rotations(integrals, angles, axes, durations, noise_var, rot_labels,
                                   gyro_mean, earth)
    check_rotation_angles(rot.angle_error, angles, rotations, t)
    m_g = rot.matrix
    for i, axis in enumerate("xyz"):
        if m_g[i, i] < 0:
            warnings.append(f"gyroscope: the {axis} axis turns opposite to the labels (scale "
                            f"{m_g[i, i]:.4g}): mounted reversed (the correction undoes it), unless the "
                            f"steps rot+{axis} and rot-{axis} were swapped")
    if not bias_solved:
        warnings.append("gyroscope: the rotations turn one way only about each axis, so the bias does "
                        "not cancel; the static bias was subtracted instead (add the opposite turns)")
    g_extra = {}
    if gsens.matrix is not None:
        g_extra["g_sensitivity"] = gsens.matrix.tolist()
    b_sd = _gyro_bias_sd(gyro, statics, static_var, len(static_gyro))
    gyro_sd = _gyro_stddev(rot, gyro_mean, b_sd)
    if gsens.stddev is not None:
        gyro_sd["g_sensitivity"] = gsens.stddev
    if rot.condition > 50:
        warnings.append(f"gyroscope: the rotations determine the parameters poorly (condition number "
                        f"{rot.condition:.0f}); turn about each axis both ways")
    gyro_cal = SensorCalibration(
        m_g, gyro_mean, method="turntable: rotations by integrated angle, bias from static steps",
        residual_rms=float(np.sqrt(np.mean(rot.angle_error**2))), stddev=gyro_sd,
        extra={"rotations": len(rotations), "residual": "integrated angle error, rad",
               "earth_rate_compensated": latitude_deg is not None,
               "bias_from_rotations": rot.bias_rotation.tolist(), **g_extra})
    poses = [{"label": lab, "t0": float(t[sl.start]), "t1": float(t[sl.stop - 1]), "kind": "rotation",
              "angle_error_deg": float(np.degrees(rot.angle_error[k]))}
             for k, (lab, sl) in enumerate(rotations)]
    return GyroStage(gyro_cal, gyro_mean, poses, warnings)


def _gyro_bias_sd(gyro: np.ndarray, statics: Steps, static_var: np.ndarray, n_static: int) -> np.ndarray:
    """1-sigma of the static bias of eq. (2): white noise of the mean plus the drift budget (module
    docstring); the step means scatter about their mean as the bias drifts (the rate is zero in
    every static step)."""
    step_means = np.array([gyro[sl].mean(axis=0) for _, sl in statics])
    step_white = np.mean([gyro[sl].var(axis=0, ddof=1) / (sl.stop - sl.start) for _, sl in statics],
                         axis=0)
    drift = drift_budget(step_means - step_means.mean(axis=0), 1, step_white)
    return np.sqrt(static_var / n_static + drift)


def _gyro_stddev(rot: RotationFit, gyro_mean: np.ndarray, b_sd: np.ndarray) -> dict[str, Any]:
    """1-sigma of the gyroscope's matrix, scale and misalignment from the rotation fit's covariance;
    the bias's is ``b_sd``."""
    def gyro_parts(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return p[:9].reshape(3, 3), gyro_mean

    gyro_sd = stddev_from(gyro_parts, np.concatenate([rot.matrix.ravel(), rot.bias_rotation]), rot.cov)
    gyro_sd["bias"] = b_sd
    return gyro_sd


def calibrate_turntable(data: TurntableCapture,
                        settings: TurntableSettings = TurntableSettings()) -> CalibrationReport:
    """Accelerometer and gyroscope from a capture labelled per ``shared/specs/capture-csv.md``.

    Parameters
    ----------
    data : TurntableCapture
        The labelled capture, checked on construction.
    settings : TurntableSettings
        Local gravity and, optionally, the latitude for the Earth rate.

    Returns
    -------
    CalibrationReport
        accel (poses) and gyro (rotations), per-step residuals and warnings.

    Raises
    ------
    EngineInputError
        Data that cannot determine the parameters: too few or degenerate poses, motion during a
        static step, saturation, lost samples in a rotation, labels the readings contradict.
    """
    warnings = []
    if data.ignored:
        warnings.append(f"steps with labels that are neither poses nor rotations were ignored: "
                        f"{', '.join(sorted(set(data.ignored)))}")
    check_steady_steps(data.t, data.acc, data.gyro, data.statics, data.rotations)
    acc_stage = fit_accelerometer(data, settings.gravity)
    warnings += acc_stage.warnings
    accel, poses = accel_calibration(acc_stage, data, settings.gravity)
    gyro_stage = fit_gyroscope(data, acc_stage, settings)
    warnings += gyro_stage.warnings
    details = {"poses": acc_stage.labels, "rotations": [lab for lab, _ in data.rotations],
               "gyro_bias_static": gyro_stage.bias_static.tolist(), "latitude_deg": settings.latitude_deg}
    return CalibrationReport(accel, gyro_stage.calibration, "turntable", settings.gravity,
                             poses + gyro_stage.poses, warnings, details)
