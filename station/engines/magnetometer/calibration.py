"""Magnetometer calibration: hard iron, soft iron and the rotation against the accelerometer, fitted
jointly with the dip-angle constraint (the equations are in :mod:`station.engines.magnetometer.fit`).

The steps:

1. rows with a magnetometer sample; refuse constant or clipped readings (:mod:`inputs`);
2. a start: the least-squares sphere (eq. (7) of ``fit``), refused where the field's direction did
   not move beyond the readings' noise or the sphere does not locate its centre (:mod:`determined`:
   a sphere through a still unit's noise sees every direction); where its directions cover at least
   ``ELLIPSOID_COVERAGE`` of the sphere, the algebraic ellipsoid (eq. (6)) instead, since on a
   partial cover the quadric is poorly determined and may not even be an ellipsoid; refuse
   directions in a plane or covering less than ``MIN_COVERAGE``;
3. the still poses (stretches of still samples) give the down direction d = -a / |a| of their mean
   accelerometer reading, and their mean magnetometer reading, one dip residual each (``_Gravity``);
   the rotation that best satisfies the dip constraint is solved linearly (``initial_rotation``);
   with ``estimate_accel`` (no accelerometer calibration at hand) the down directions are those of
   the raw accelerometer under intrinsics first fitted to its still poses alone and then estimated
   with the rest (:mod:`accel`: all nine, or all but the z bias near level);
4. a first fit with the soft-L1 loss (iteratively reweighted, ``JointProblem.reweighted``), whose
   magnitude residuals show the disturbed stretches (eq. (1) of ``inputs``) and whose dip
   residuals show poses that were not still (an acceleration the detector missed): both are left
   out, and so is a pose in a disturbed stretch;
5. the final Levenberg-Marquardt fit, each residual set weighted by its own scatter, and its
   covariance s^2 (J^T J)^-1 (``calibration_common.covariance``) propagated to every reported value;
   an accelerometer z bias held at zero near level adds its share as a consider parameter; a result
   with a value that is not a finite real number, or a 1-sigma above a tenth of its quantity's size,
   is refused (``determined`` eq. (4)).

Without the operator's field magnitude F the data's own is used: the fit runs at the start's F and
is then rescaled so that det C = 1 (the geometric mean of the ellipsoid's semi-axes becomes F):
(3) is unchanged by a common scale of C and F, and (2) scales with it. The result's matrix A = C^-1
splits (left polar decomposition) into A = P R: P symmetric (the soft iron's shape and scale) and R
the rotation from the accelerometer's axes to the magnetometer's (``alignment``).

Why this module is long: the fit's stages (start, accelerometer, joint solve,
result) share the capture, the settings and the accumulating notes of one call; apart, each stage
would take and return the same half-dozen objects, and the numbered list above reads as one function.
The numerics they call are already in ``fit``, ``inputs``, ``accel`` and ``coverage``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from station.engines.calibration.common import covariance, propagate
from station.engines.calibration.free_accel import acc_initial_guess
from station.engines.magnetometer.accel import ALL, NO_Z_BIAS, PoseAccel
from station.engines.magnetometer.coverage import MagCoverage, field_coverage
from station.engines.magnetometer.determined import check_centre, check_result
from station.engines.magnetometer.fit import (
    JointProblem,
    Start,
    ellipsoid_fit,
    initial_rotation,
    polar,
)
from station.engines.magnetometer.inputs import (
    Disturbance,
    check_directions,
    check_moving,
    check_not_saturated,
    disturbed,
    gravity_spread,
    still_noise,
    still_samples,
    still_stretches,
    usable_rows,
)
from station.engines.shared.levenberg_marquardt import least_squares_lm
from station.errors import EngineInputError

# Magnetometer samples the fit needs at the least.
MIN_SAMPLES = 50
# Below this share of the sphere the readings cannot determine an ellipsoid at all.
MIN_COVERAGE = 0.15
# From this share on, the algebraic ellipsoid is a good start; below it, the sphere.
ELLIPSOID_COVERAGE = 0.6
# Below this share the result carries a warning naming the missing directions.
WARN_COVERAGE = 0.5
# Still poses the dip constraint needs, and the least spread of their down directions (deg): with
# one attitude only, the rotation about the field is free.
MIN_POSES, MIN_DOWN_SPREAD_DEG = 4, 10.0
# Still poses an accelerometer estimated with the fit needs: its nine intrinsics, and a few residuals
# beyond them for their covariance (fewer: the least squares has more unknowns than residuals).
MIN_ACCEL_POSES = 12
# A dip residual beyond this many robust sigmas is a pose that was not still after all.
DIP_OUTLIER_SIGMAS = 6.0
# Differences between the estimated dip and the geomagnetic model's worth a warning (deg).
DIP_WARN_DEG = 3.0
# Scatter of |a| between still poses above which the accelerometer looks uncalibrated (a calibrated
# one scatters by a few 1e-4, an uncalibrated MEMS part by 3e-3 to 1e-2).
GRAVITY_SPREAD = 2e-3
# Share of the samples in disturbed stretches above which the capture is refused: the level the
# rest holds is then no longer clearly the Earth's field.
MAX_DISTURBED = 0.25
# The magnitude residual may exceed the noise at the still poses by this factor (the noise of moving
# samples, quantization and rounding add a little) before the fit is said not to describe the data.
MAX_NOISE_RATIO = 3.0
# ... and by this factor before the result is refused: no calibration describes such data.
REFUSE_NOISE_RATIO = 10.0
# Samples in the magnitude fit at the most (a longer capture is taken at a stride).
MAX_FIT_SAMPLES = 50_000
# Outlier-resistant first pass: rounds of reweighting, residuals beyond this share of F weighed down.
ROBUST_SHARE, ROBUST_ROUNDS = 0.02, 3
# Largest 1-sigma (deg, % of scale, % of g) of the accelerometer's nine intrinsics from its still
# poses alone for all nine to be estimated: the dip constraint determines them much better than the
# poses alone do (desk sessions to 45, 40, 35 deg: about 1.3, 2, 3-5, and all nine then fit well;
# to 30 deg: 40, and all nine wander off).
ACC_CONDITION = 10.0
# The 1-sigma, as a share of g, of an accelerometer's z bias where the poses leave it undetermined
# and it is held at zero: a consumer MEMS part's zero-g offset (datasheets: 10-40 mg at most).
ACC_Z_BIAS_SIGMA = 0.01


@dataclass(frozen=True)
class MagCapture:
    """A session for the magnetometer fit: one row per sample.

    Attributes
    ----------
    t : ndarray, (N,)
        Sample times, s.
    mag : ndarray, (N, 3)
        Raw field, microtesla (NaN rows: no magnetometer sample there).
    acc : ndarray, (N, 3), optional
        Accelerometer (any unit, corrected if a calibration is at hand): the down direction. None
        gives the plain fit in the magnetometer's own axes.
    gyro : ndarray, (N, 3), optional
        Gyroscope, rad/s: also required slow for a still sample.
    """

    t: np.ndarray
    mag: np.ndarray
    acc: np.ndarray | None = None
    gyro: np.ndarray | None = None


@dataclass(frozen=True)
class MagSettings:
    """How to fit.

    Attributes
    ----------
    field_ut : float, optional
        |true| to scale to (microtesla); None: the data's own.
    model_dip_deg : float, optional
        The dip a geomagnetic model gives for the place, compared with the estimate.
    window_s : float
        Moving-variance window of the still detector, s.
    joint : bool
        Fit the rotation with the dip constraint (needs ``acc``); False: the plain fit.
    estimate_accel : bool
        ``acc`` is raw (no calibration at hand): its intrinsics are estimated from the still poses
        with the rest (``station.engines.magnetometer.accel``), the rotation is to their frame.
    """

    field_ut: float | None = None
    model_dip_deg: float | None = None
    window_s: float = 0.5
    joint: bool = True
    estimate_accel: bool = False


@dataclass
class MagCalibration:
    """The fitted magnetometer: forward model raw = matrix @ true + bias, microtesla.

    Attributes
    ----------
    matrix, bias : ndarray
        A (3, 3) and b (3,) of the forward model.
    frame : str
        ``accel`` (true in the accelerometer's axes) or ``sensor`` (plain fit, C symmetric).
    field_norm : float
        F, microtesla.
    field_given : bool
        F was given (the operator or a geomagnetic model), not the data's own.
    residual_rms : float
        RMS of |true| - F over the samples used, microtesla.
    dip_rms : float or None
        RMS of the dip residual (eq. (3) of ``fit``) over the still poses, microtesla.
    coverage : MagCoverage
        Field directions visited (corrected field).
    dip_deg : float or None
        Estimated dip (positive: the field points down).
    stddev : dict
        1-sigma: ``bias`` (3,), ``matrix`` and ``correction`` (3, 3), ``alignment_deg`` (3,: the
        rotation vector of R, deg), ``dip_deg``, ``field_norm`` (when the data's own).
    start : str
        ``ellipsoid`` or ``sphere``.
    samples, still : int
        Samples in the magnitude fit, and still poses in the dip fit.
    disturbances : list of Disturbance
        Stretches left out.
    warnings : list of str
        What the operator should know, with what to do.
    accel_estimated : bool
        The accelerometer was raw: its intrinsics were estimated from the still poses with the rest.
    """

    matrix: np.ndarray
    bias: np.ndarray
    frame: str
    field_norm: float
    field_given: bool
    residual_rms: float
    dip_rms: float | None
    coverage: MagCoverage
    dip_deg: float | None
    stddev: dict[str, np.ndarray | float]
    start: str
    samples: int
    still: int
    disturbances: list[Disturbance] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    accel_estimated: bool = False

    @property
    def correction(self) -> np.ndarray:
        """C = A^-1: true = C (raw - b)."""
        return np.linalg.inv(self.matrix)

    @property
    def method(self) -> str:
        """Which fit produced it, for the parameter file."""
        if self.frame != "accel":
            return "mag: ellipsoid (no gravity reference)"
        return "mag: joint ellipsoid and alignment, dip constraint" + (
            ", accelerometer estimated from the still poses" if self.accel_estimated else "")

    def shape_and_alignment(self) -> tuple[np.ndarray, np.ndarray]:
        """A = P R (left polar decomposition): the soft iron's symmetric P and the rotation R."""
        return polar(self.matrix)

    def alignment_deg(self) -> float:
        """Angle of R, the rotation between the accelerometer's and the magnetometer's axes, deg."""
        _, rot = self.shape_and_alignment()
        return float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))))


def rotation_vector(rot: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle, rad) of a rotation matrix near the identity or not.

    Parameters
    ----------
    rot : ndarray, (3, 3)

    Returns
    -------
    ndarray, (3,)
    """
    angle = np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    if angle < 1e-12:
        return 0.5 * axis
    return axis * (angle / (2.0 * np.sin(angle)))


def _start(m: np.ndarray) -> Start:
    """Step 2: the sphere, or the ellipsoid where the sphere's directions cover enough; refused where
    the field did not move beyond the noise or the sphere does not locate its centre (``determined``
    eqs. (2)-(3)): a sphere through a still unit's noise sees directions everywhere."""
    sphere = check_centre(m).start
    check_directions(m - sphere.bias)
    cover = field_coverage(m - sphere.bias)
    if cover.share < MIN_COVERAGE:
        raise EngineInputError(
            f"the capture's field directions cover {cover.share:.0%} of the sphere, too few to fit the "
            f"magnetometer (at least {MIN_COVERAGE:.0%}); capture again turning the unit through more "
            f"orientations: {'; '.join(cover.advice(2))}")
    if cover.share >= ELLIPSOID_COVERAGE:
        ellipsoid = ellipsoid_fit(m)
        if ellipsoid is not None:
            return ellipsoid
    return sphere


def _spread_deg(down: np.ndarray) -> float:
    """Largest angle of the down directions from their mean direction, deg."""
    mean = down.mean(axis=0)
    mean /= max(np.linalg.norm(mean), 1e-300)
    return float(np.degrees(np.arccos(np.clip(down @ mean, -1.0, 1.0))).max())


def _robust_sigma(r: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(r - np.median(r))))


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r**2))) if len(r) else 0.0


def calibrate_mag(data: MagCapture, settings: MagSettings = MagSettings()) -> MagCalibration:
    """Fit hard iron, soft iron and (with a gravity reference) the alignment to the accelerometer.

    Parameters
    ----------
    data : MagCapture
        The session.
    settings : MagSettings
        Field magnitude, the model's dip, the still detector's window.

    Returns
    -------
    MagCalibration
        The forward model, its 1-sigma, residuals, coverage, disturbances left out and warnings.

    Raises
    ------
    EngineInputError
        No magnetometer samples, constant or clipped readings, too few directions, or a capture
        disturbed throughout; each message says what to do.
    """
    t = np.asarray(data.t, float)
    rows = usable_rows(data.mag)
    m = np.asarray(data.mag, float)[rows]
    t_m = t[rows]
    if len(m) < MIN_SAMPLES:
        raise EngineInputError(f"the capture holds {len(m)} magnetometer samples; the fit needs at least "
                               f"{MIN_SAMPLES} (a minute of turning the unit at 10 Hz or more)")
    check_moving(m)
    check_not_saturated(m)
    start = _start(m)
    warnings: list[str] = []
    gravity = _gravity_reference(data, rows, settings, warnings)
    # |det|: a negative determinant (a left-handed start) would make the cube root complex
    field_fit = settings.field_ut if settings.field_ut is not None else float(
        abs(np.linalg.det(start.correction)) ** (-1.0 / 3.0))
    # consecutive samples of a fast magnetometer repeat one another: a stride keeps the magnitude
    # fit's size bounded (the still poses' means use every sample)
    step = -(-len(m) // MAX_FIT_SAMPLES)
    m_fit, t_fit = m[::step], t_m[::step]
    problem = JointProblem(m_fit, gravity.m_pose, gravity.down, field_fit)
    acc0 = np.zeros(0)
    if problem.joint and settings.estimate_accel:
        problem, acc0 = _accel_stage(problem, gravity.a_pose, warnings)
    correction0 = field_fit * start.correction
    sin0 = 0.0
    if problem.joint:
        rot, sin0 = initial_rotation(problem.m_still, problem.down, start)
        correction0 = rot @ correction0
    p = problem.pack(start.bias, correction0, sin0, acc0)
    robust = ROBUST_SHARE * field_fit
    for _ in range(ROBUST_ROUNDS):
        p = problem.reweighted(p, robust, robust).solve(p)

    # Step 4: disturbances and still samples that moved, by the first fit's residuals.
    r_norm, r_dip, _ = problem.residual_parts(p)
    left_out, disturbances = disturbed(t_fit, r_norm, field_fit)
    keep_norm = ~left_out
    spoiled = np.zeros(len(t_m), bool)
    for d in disturbances:
        spoiled |= (t_m >= d.t0) & (t_m <= d.t1)
    keep_dip = np.array([not spoiled[a:b].any() for a, b in gravity.stretches], bool)
    if problem.joint:
        keep_dip &= np.abs(r_dip - np.median(r_dip)) <= DIP_OUTLIER_SIGMAS * max(_robust_sigma(r_dip), 1e-12)
    if left_out.mean() > MAX_DISTURBED:
        raise EngineInputError(
            f"the field's magnitude jumps in {len(disturbances)} stretches covering {left_out.mean():.0%} of "
            "the capture: the unit was near magnets, motors or steel most of the time; capture again away "
            "from them (a wooden table, a metre from computers and desk frames)")
    if disturbances:
        warnings.append(f"left out {len(disturbances)} disturbed stretch(es) where the field's magnitude "
                        f"jumped: {', '.join(d.describe() for d in disturbances[:5])}"
                        f"{' ...' if len(disturbances) > 5 else ''}; keep magnets, motors and steel away")

    # Step 5: the final fit, each residual set weighted by its scatter, twice: the second time with
    # the scatter at the optimum, so that s^2 of the covariance is about 1 for both sets.
    final = replace(problem, m=m_fit[keep_norm]).poses(keep_dip)
    r_norm, r_dip, r_acc = final.residual_parts(p)
    for _ in range(2):
        final = replace(final, w_norm=max(_rms(r_norm), 1e-9 * field_fit),
                        w_dip=max(_rms(r_dip), 1e-9 * field_fit) if final.joint else 1.0,
                        w_acc=max(_rms(r_acc), 1e-9 * (final.acc.gravity if final.acc else 1.0)))
        p = final.solve(p)
        r_norm, r_dip, r_acc = final.residual_parts(p)
    jac = final.jacobian(p)
    cov, _ = covariance(jac, final.residual(p))
    if final.acc is not None and final.acc.free == NO_Z_BIAS:
        cov = cov + _held_z_bias(final, p, jac)
    ratio = _rms(r_norm) / gravity.noise if gravity.noise else 0.0
    misfit = (f"the magnitude residual ({_rms(r_norm):.2g} uT RMS) is {ratio:.0f} times the magnetometer's "
              f"noise at the still poses ({gravity.noise or 0.0:.2g} uT): the field changed during the "
              "session in a way no calibration describes (magnets, motors or steel near the unit, or moving "
              "with it)")
    if ratio > REFUSE_NOISE_RATIO:
        raise EngineInputError(f"{misfit}; capture again away from them (a wooden table, a metre from "
                               "computers and desk frames)")
    if ratio > MAX_NOISE_RATIO:
        warnings.append(f"{misfit}; check the surroundings and capture again")
    return _result(final, p, cov, settings, start, disturbances, warnings)


@dataclass(frozen=True)
class _Gravity:
    """Step 3: the still stretches ([start, stop) of the magnetometer's rows) of eq. (3), each one's
    mean reading and down direction, and the magnetometer's noise there.

    One dip residual per still pose, not per sample: the down direction's errors (the
    accelerometer's own bias, scale and misalignment, a tilt while held) are the pose's, the same
    for all its samples, so the poses are the independent observations; per sample, thousands of
    residuals sharing one error would outweigh the magnitude residuals and bend the ellipsoid.
    """

    stretches: list[tuple[int, int]]
    m_pose: np.ndarray
    a_pose: np.ndarray
    down: np.ndarray
    noise: float | None


def _gravity_reference(data: MagCapture, rows: np.ndarray, settings: MagSettings,
                       warnings: list[str]) -> _Gravity:
    """Step 3: the down directions at the still samples, or none (the plain fit), saying why."""
    none = _Gravity([], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), None)
    if not settings.joint:
        return none
    if data.acc is None:
        warnings.append("no accelerometer: fitted in the magnetometer's own axes (frame: sensor)")
        return none
    t = np.asarray(data.t, float)[rows]
    acc = np.asarray(data.acc, float)[rows]
    gyro = np.asarray(data.gyro, float)[rows] if data.gyro is not None else None
    rate = 1.0 / float(np.median(np.diff(t)))
    still = still_samples(acc, gyro, rate, settings.window_s) & np.isfinite(acc).all(axis=1)
    noise = still_noise(np.asarray(data.mag, float)[rows], still)
    stretches = still_stretches(still)
    mag = np.asarray(data.mag, float)[rows]
    m_pose = np.array([mag[a:b].mean(axis=0) for a, b in stretches]).reshape(-1, 3)
    a_pose = np.array([acc[a:b].mean(axis=0) for a, b in stretches]).reshape(-1, 3)
    down = -a_pose / np.linalg.norm(a_pose, axis=1)[:, None]
    if len(stretches) < MIN_POSES:
        warnings.append(f"only {len(stretches)} still poses: the rotation to the accelerometer needs at "
                        f"least {MIN_POSES} (hold the unit still for a second at each); fitted in the "
                        "magnetometer's own axes instead")
        return replace(none, noise=noise)
    if _spread_deg(down) < MIN_DOWN_SPREAD_DEG:
        warnings.append(f"the still poses are all within {MIN_DOWN_SPREAD_DEG:g} deg of one tilt: the "
                        "rotation to the accelerometer needs still poses at several tilts (hold the unit "
                        "still for a second at each); fitted in the magnetometer's own axes instead")
        return replace(none, noise=noise)
    if settings.estimate_accel and len(stretches) < MIN_ACCEL_POSES:
        warnings.append(f"only {len(stretches)} still poses and no accelerometer calibration: its nine "
                        f"intrinsics need at least {MIN_ACCEL_POSES} (hold the unit still for a second at "
                        "each, or calibrate the accelerometer first with imu-station calibrate --method "
                        "free -o PARAMS and run this again with the same PARAMS); fitted in the "
                        "magnetometer's own axes instead")
        return replace(none, noise=noise)
    spread = gravity_spread(acc, still)
    if not settings.estimate_accel and spread is not None and spread > GRAVITY_SPREAD:
        warnings.append(f"|a| differs by {spread:.2%} (1 sigma) between the still poses: the accelerometer "
                        "looks uncalibrated, and its errors tilt the down direction the alignment is solved "
                        "against; calibrate it first (imu-station calibrate --method free -o PARAMS) and "
                        "run this again with the same PARAMS")
    return _Gravity(stretches, m_pose, a_pose, down, noise)


def _held_z_bias(problem: JointProblem, p: np.ndarray, jac: np.ndarray) -> np.ndarray:
    """What the held z bias of the accelerometer adds to the covariance (a consider parameter):
    its 1-sigma ``ACC_Z_BIAS_SIGMA`` of g through the sensitivity of the least-squares solution,
    dp/db_z = -(J^T J)^-1 J^T dr/db_z. Near level the hard iron's z is determined to the second
    order of the tilt only, as b_z is, and moves by about 0.04 uT per mg of b_z."""
    assert problem.acc is not None
    whole = replace(problem, acc=problem.acc.with_free(ALL))
    b, c, s = problem.unpack(p)
    column = whole.jacobian(whole.pack(b, c, s, problem.acc.full(problem.acc_params(p))))[:, -1]
    sensitivity = -np.linalg.lstsq(jac, column, rcond=None)[0]
    sigma = ACC_Z_BIAS_SIGMA * problem.acc.gravity
    return sigma**2 * np.outer(sensitivity, sensitivity)


def _accel_alone(acc: PoseAccel) -> tuple[np.ndarray, float]:
    """The accelerometer's intrinsics ``acc.free`` from its still poses alone (``accel`` eq. (2),
    Levenberg-Marquardt from ``calibration_free_accel.acc_initial_guess``), and the largest of their
    1-sigma (misalignment in deg, scale in % of itself, bias in % of g): how well the poses
    determine them."""
    q0 = acc.reduced(acc_initial_guess(acc.x, acc.gravity))
    q = least_squares_lm(acc.residual, q0, acc.jacobian, ftol=1e-14, xtol=1e-14, gtol=1e-14, max_nfev=500).x
    cov, _ = covariance(acc.jacobian(q), acc.residual(q))
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    full = acc.full(q)
    unit = np.array([np.degrees(1.0)] * 3 + list(100.0 / np.abs(full[3:6])) + [100.0 / acc.gravity] * 3)
    return q, float(np.max(sd * unit[list(acc.free)]))


def _accel_stage(problem: JointProblem, x: np.ndarray,
                 warnings: list[str]) -> tuple[JointProblem, np.ndarray]:
    """Step 3 without an accelerometer calibration: its intrinsics (``accel``) from the still
    poses alone start the joint fit (and give the start's down directions); all nine where the poses
    determine them (``ACC_CONDITION``), else all but the z bias."""
    gravity = float(np.median(np.linalg.norm(x, axis=1)))
    acc = PoseAccel(x, gravity, ALL)
    q, worst = _accel_alone(acc)
    terms = "bias, scale and misalignment"
    if worst > ACC_CONDITION:
        acc = acc.with_free(NO_Z_BIAS)
        q, _ = _accel_alone(acc)
        terms = "x and y bias, scale and misalignment (the z bias is taken into the z scale)"
        warnings.append(
            "the still poses stay near level: the accelerometer's z bias is not determined (held at zero; "
            f"the hard iron's z 1-sigma includes {ACC_Z_BIAS_SIGMA * 1e3:.0f} mg of it) and the tilt of its "
            "z axis only loosely (see the alignment's 1-sigma); tilt the unit further (45 deg), or "
            "calibrate the accelerometer first (imu-station calibrate --method free -o PARAMS) and run this "
            "again with the same PARAMS")
    warnings.append(f"no accelerometer calibration: its {terms} were estimated from the {len(x)} still poses "
                    "with the magnetometer; the rotation is to its axes as calibrate --method free (lower "
                    "convention) defines them")
    return replace(problem, down=acc.down(q), acc=acc, w_acc=max(_rms(acc.residual(q)), 1e-9 * gravity)), q


def _normalised(problem: JointProblem, p: np.ndarray, given: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """(C, b, F) of the parameters, rescaled to det C = 1 where F is the data's own."""
    b, c, _ = problem.unpack(p)
    if given:
        return c, b, problem.field
    # |det|: a magnetometer mounted left-handed against the accelerometer has det C < 0, and a
    # negative number's real power -1/3 is complex in Python
    k = abs(float(np.linalg.det(c))) ** (-1.0 / 3.0)
    return k * c, b, k * problem.field


def _result(problem: JointProblem, p: np.ndarray, cov: np.ndarray, settings: MagSettings, start: Start,
            disturbances: list[Disturbance], warnings: list[str]) -> MagCalibration:
    """The reported values and their 1-sigma by first-order propagation of the fit's covariance."""
    given = settings.field_ut is not None
    c, b, field_norm = _normalised(problem, p, given)
    matrix = np.linalg.inv(c)
    _, rot = polar(matrix)

    def reported(q: np.ndarray) -> np.ndarray:
        cq, bq, fq = _normalised(problem, q, given)
        aq = np.linalg.inv(cq)
        _, rq = polar(aq)
        dip = np.degrees(np.arcsin(np.clip(problem.unpack(q)[2], -1.0, 1.0)))
        # the rotation relative to the fitted one: small, so its vector is smooth in q
        turn = np.degrees(rotation_vector(rq @ rot.T))
        return np.concatenate([bq, aq.ravel(), cq.ravel(), turn, [dip, fq]])

    sd = np.sqrt(np.clip(np.diag(propagate(reported, p, cov)), 0.0, None))
    stddev: dict[str, np.ndarray | float] = {"bias": sd[0:3], "matrix": sd[3:12].reshape(3, 3),
                                             "correction": sd[12:21].reshape(3, 3)}
    if problem.joint:
        stddev["alignment_deg"] = sd[21:24]
        stddev["dip_deg"] = float(sd[24])
    if not given:
        stddev["field_norm"] = float(sd[25])
    h = (problem.m - b) @ c.T
    cover = field_coverage(h)
    sin_dip = problem.unpack(p)[2]
    dip_rms = (_rms(np.einsum("ij,ij->i", problem.downs(p), (problem.m_still - b) @ c.T)
                    - field_norm * sin_dip) if problem.joint else None)
    dip = float(np.degrees(np.arcsin(np.clip(sin_dip, -1.0, 1.0)))) if problem.joint else None
    if cover.share < WARN_COVERAGE:
        leans = ("the fit leans on the dip constraint" if problem.joint
                 else "the soft iron is poorly determined without a gravity reference")
        warnings.append(f"the field directions cover {cover.share:.0%} of the sphere: {leans}; to cover "
                        f"more, {'; '.join(cover.advice(2))}")
    model = settings.model_dip_deg
    if dip is not None and model is not None and abs(dip - model) > DIP_WARN_DEG:
        warnings.append(f"the estimated dip {dip:.1f} deg differs from the geomagnetic model's "
                        f"{model:.1f} deg: a disturbance the whole session long (a steel desk, a building's "
                        "frame), or a wrong place or date given")
    check_result(matrix, c, b, field_norm, stddev,
                 {"dip_deg": dip, "alignment_deg": float(np.degrees(np.linalg.norm(rotation_vector(rot))))})
    return MagCalibration(
        matrix=matrix, bias=b, frame="accel" if problem.joint else "sensor", field_norm=field_norm,
        field_given=given, residual_rms=_rms(np.linalg.norm(h, axis=1) - field_norm), dip_rms=dip_rms,
        coverage=cover, dip_deg=dip, stddev=stddev, start=start.kind, samples=len(problem.m),
        still=len(problem.m_still), disturbances=disturbances, warnings=warnings,
        accel_estimated=problem.acc is not None)
