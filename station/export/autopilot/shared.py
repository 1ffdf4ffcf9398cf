"""What PX4 and ArduPilot exports share: parameter lists, the cubic re-fit of the thermal model,
and the size of what an autopilot cannot hold, measured at the six calibration poses.

An autopilot corrects each axis on its own, (raw - offset(T)) * scale, with offset(T) one cubic
in T. Our model (``station.engines.shared.correction``) is a full matrix, a piecewise seven-term thermal
bias with dT terms, and a gyro g-sensitivity. What is lost is never hidden: ``assess`` runs the
autopilot's own formula (read from the very parameters written) against ``apply_calibration`` and
reports the error.

The magnetometer: both autopilots correct with a symmetric soft-iron matrix W after the offsets,
W (raw - offset). Our correction C = M_m^-1 also turns the field into the accelerometer's axes
(``frame: accel``), so it is split by the polar decomposition C = U P (U a rotation, P symmetric
positive definite): P is written, U is what the target cannot hold. P (raw - b) has exactly the
length of C (raw - b), so the field's magnitude survives and only its direction turns, by U's
angle; ``assess_mag`` measures that error with the target's own formula.

Scale factor and misalignment as functions of temperature (``thermal.scale``,
``thermal.misalignment``; M(T) = diag(K + k(t)) (I + S + s(t)), ``station.engines.thermal.intrinsics``):
neither autopilot's temperature calibration (PX4 TC_*, ArduPilot INS_TCAL*) holds anything but a bias,
so their change is lost whole. ``thermal_intrinsics_loss`` states it at the ends of each
polynomial's clamp, where it is largest for a monotonic drift: the scale-factor change k_i(t) / K_i in
ppm of K at T_ref, and the misalignment change s_ij(t) in microradians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocols.units import STANDARD_GRAVITY
from station.engines.shared.correction import apply_calibration
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.intrinsics import OFF_DIAGONAL_NAMES, TempPolynomial, matrices_at
from station.engines.thermal.model import ThermalBias
from station.export.params.file import ParamsFile
from station.export.params.sections import field_norm, g_sensitivity, mag_calibration

GYRO_POSE_RATE = 1.0  # rad/s: the gyro "poses" are +-1 rad/s about each axis
FIT_POINTS = 401
GRID_POINTS = 401
DTEMP_POINTS = 21
NEGLIGIBLE = 1e-12  # m/s^2 or rad/s over the whole fitted range: far below float32 of any offset
NOMINAL_TEMP = 25.0  # degC, where intrinsics are compared when the file has no thermal section

TargetCorrection = Callable[[dict[str, float], np.ndarray, np.ndarray, np.ndarray],
                            tuple[np.ndarray, np.ndarray]]
# A target's own formulas, reading the parameters of sensor instance ``int``.
InstanceCorrection = Callable[[dict[str, float], int, np.ndarray, np.ndarray, np.ndarray],
                              tuple[np.ndarray, np.ndarray]]
InstanceOffsets = Callable[[dict[str, float], int, np.ndarray], tuple[np.ndarray, np.ndarray]]
# A target's magnetometer formula: parameters, instance, raw field (uT) -> corrected field (uT).
MagCorrection = Callable[[dict[str, float], int, np.ndarray], np.ndarray]
MAG_UNIT = "uT"
PPM = 1e6
URAD_PER_RAD = 1e6
AXIS_NAMES = ("x", "y", "z")


@dataclass
class Param:
    """One autopilot parameter; ``value`` is what the autopilot stores (float32 or int32)."""

    name: str
    value: float | int
    kind: str  # "float" or "int"

    def text(self) -> str:
        """The value as the autopilot's parameter file writes it: an integer, or the shortest float32 text."""
        if self.kind == "int":
            return str(int(self.value))
        return np.format_float_positional(np.float32(self.value), unique=True, trim="-")


@dataclass
class Limitation:
    """Something the target cannot hold, with the error it leaves (``size`` in ``unit``)."""

    triad: str
    what: str
    size: float
    unit: str
    detail: str

    def to_dict(self) -> dict[str, Any]:
        """Plain data for ``--json``."""
        return {"triad": self.triad, "what": self.what, "size": self.size, "unit": self.unit,
                "detail": self.detail}


@dataclass
class AutopilotExport:
    """The parameters for one autopilot, what it cannot hold, the pose errors left, and notes."""

    target: str
    params: list[Param]
    limitations: list[Limitation] = field(default_factory=list)
    pose_errors: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    thermal_intrinsics_lost: dict[str, dict[str, Any]] = field(default_factory=dict)
    """``thermal_intrinsics_loss`` of the parameter file: what the target drops of the scale-factor
    and misalignment polynomials, per triad."""
    # What the target subtracts from raw accel and gyro at given temperatures (for the plot).
    offsets: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] | None = None

    def values(self) -> dict[str, float]:
        """Each parameter's value as the autopilot will read it back."""
        return {p.name: float(p.text()) for p in self.params}

    def to_dict(self) -> dict[str, Any]:
        """Plain data for ``--json``: target, parameters, limitations, pose errors, notes and, where the
        file has thermal scale or misalignment polynomials, ``thermal_intrinsics_lost``."""
        out = {
            "target": self.target,
            "parameters": {p.name: int(p.value) if p.kind == "int" else float(p.text()) for p in self.params},
            "limitations": [lim.to_dict() for lim in self.limitations],
            "pose_errors": self.pose_errors,
            "notes": self.notes,
        }
        if self.thermal_intrinsics_lost:
            out["thermal_intrinsics_lost"] = self.thermal_intrinsics_lost
        return out


def six_poses(magnitude: float) -> np.ndarray:
    """+x, -x, +y, -y, +z, -z, each of length ``magnitude`` (6, 3)."""
    return np.repeat(np.eye(3), 2, axis=0) * np.tile([magnitude, -magnitude], 3)[:, None]


POSE_NAMES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass
class CubicFit:
    """offset(T) = c[:, 0] + c[:, 1] x + c[:, 2] x^2 + c[:, 3] x^3 per axis, x = T - centre."""

    centre: float
    t_min: float
    t_max: float
    coeffs: np.ndarray  # (3, 4)


def fit_cubic(triad: ThermalBias, reference_temp: float, centre: float, t_min: float,
              t_max: float) -> CubicFit:
    """Least-squares cubic in (T - centre) to our thermal bias at dT = 0 over [t_min, t_max].

    Exact (to rounding) when the model is one segment holding only t^3, t^2, t and 1 terms:
    a cubic re-centred on another temperature is again a cubic.
    """
    temp = np.linspace(t_min, t_max, FIT_POINTS)
    bias = triad.evaluate(temp, np.zeros_like(temp), reference_temp)
    # Scaled abscissa keeps the normal equations well conditioned over wide ranges.
    half = max(abs(t_max - centre), abs(t_min - centre), 1.0)
    x = (temp - centre) / half
    design = np.stack([x**0, x, x**2, x**3], axis=-1)
    scaled, *_ = np.linalg.lstsq(design, bias, rcond=None)
    # A term whose whole contribution over the range is rounding noise is a zero, not 2e-21.
    scaled[np.abs(scaled) < NEGLIGIBLE] = 0.0
    coeffs = (scaled / half ** np.arange(4)[:, None]).T
    return CubicFit(centre, t_min, t_max, coeffs)


def thermal_range(params: ParamsFile) -> tuple[float, float] | None:
    """[min t_min, max t_max] over the triads' thermal bias models and their scale and misalignment
    polynomials' clamps, or None without any."""
    if params.thermal is None:
        return None
    spans = [(t.t_min, t.t_max) for t in (params.thermal.accel, params.thermal.gyro) if t is not None]
    spans += [(poly.t_min, poly.t_max) for polys in (params.thermal.scale, params.thermal.misalignment)
              for poly in polys.values()]
    if not spans:
        return None
    return min(lo for lo, _ in spans), max(hi for _, hi in spans)


def reference_temp(params: ParamsFile) -> float:
    """T_ref of the thermal section, or the nominal temperature without one."""
    return params.thermal.reference_temp if params.thermal is not None else NOMINAL_TEMP


def _raw(cal: SensorCalibration | None, triad: ThermalBias | None, t_ref: float, true: np.ndarray,
         temp: np.ndarray, intrinsics: tuple[TempPolynomial | None, TempPolynomial | None] = (None, None)
         ) -> np.ndarray:
    """raw = M(T) true + b + B(T, 0), the forward model behind the correction (M(T) = M without the
    triad's scale and misalignment polynomials)."""
    cal = cal or SensorCalibration.identity()
    raw = cal.forward(true)
    if intrinsics != (None, None):
        matrices = matrices_at(cal.matrix, temp, t_ref, *intrinsics)
        raw = (matrices @ np.asarray(true, float)[:, :, None])[:, :, 0] + cal.bias
    if triad is not None:
        raw = raw + triad.evaluate(temp, np.zeros_like(temp), t_ref)
    return raw


def _dtemp_effect(triad: ThermalBias, t_ref: float) -> float:
    lo, hi = triad.t_min, triad.t_max
    grid_t, grid_dt = np.meshgrid(np.linspace(lo, hi, 101),
                                  np.linspace(triad.dt_min, triad.dt_max, DTEMP_POINTS))
    temp, dtemp = grid_t.ravel(), grid_dt.ravel()
    diff = triad.evaluate(temp, dtemp, t_ref) - triad.evaluate(temp, np.zeros_like(temp), t_ref)
    return float(np.max(np.linalg.norm(diff, axis=1)))


def assess(params: ParamsFile, values: dict[str, float],
           correct: TargetCorrection) -> dict[str, dict[str, Any]]:
    """Errors the target's formula leaves against ``apply_calibration``, per triad.

    ``at_reference``: |target - ours| at the six poses (gravity for accel, 1 rad/s for gyro) at
    the reference temperature, dT = 0. ``over_temperature``: the largest such error over the
    calibrated temperature range widened by 5 degC each side, dT = 0. ``thermal_only``: the
    same at zero input, i.e. the thermal offset alone. ``dtemp_terms``: how far the dT terms the
    target drops move the bias over the dT clamp range.
    """
    t_ref = reference_temp(params)
    span = thermal_range(params)
    thermal = params.thermal
    temps: np.ndarray = np.array([t_ref])
    if span is not None and thermal is not None:
        # Segment edges and just below them: a piecewise model jumps there, the cubic does not.
        edges = np.array([x for triad in (thermal.accel, thermal.gyro) if triad is not None
                          for seg in triad.segments for x in (seg.t_min, seg.t_max)])
        temps = np.unique(np.concatenate([np.linspace(span[0] - 5, span[1] + 5, GRID_POINTS), temps,
                                          edges, edges - 1e-6]))
    out: dict[str, dict[str, Any]] = {}
    grid_t = np.repeat(temps, 7)
    poses = {"accel": np.vstack([six_poses(STANDARD_GRAVITY), np.zeros(3)]),
             "gyro": np.vstack([six_poses(GYRO_POSE_RATE), np.zeros(3)])}
    true_acc = np.tile(poses["accel"], (len(temps), 1))
    true_gyr = np.tile(poses["gyro"], (len(temps), 1))
    acc_triad = thermal.accel if thermal is not None else None
    gyr_triad = thermal.gyro if thermal is not None else None
    g_matrix = g_sensitivity(params)
    raw_acc = _raw(params.accel, acc_triad, t_ref, true_acc, grid_t, _intrinsics(params, "accel"))
    raw_gyr = _raw(params.gyro, gyr_triad, t_ref, true_gyr, grid_t, _intrinsics(params, "gyro"))
    if g_matrix is not None:
        # Each gyro pose is taken at the accel pose of its row: the bias G f rides on it.
        raw_gyr = raw_gyr + true_acc @ g_matrix.T
    ours = apply_calibration(raw_acc, raw_gyr, grid_t, np.zeros_like(grid_t), params.accel, params.gyro,
                             thermal, g_matrix)
    theirs = correct(values, raw_acc, raw_gyr, grid_t)
    # Exactly T_ref (it is in the grid): a grid point within isclose's tolerance of it is not it.
    at_ref = grid_t == t_ref
    is_pose = np.tile(np.arange(7) < 6, len(temps))
    for k, (name, triad) in enumerate((("accel", acc_triad), ("gyro", gyr_triad))):
        if getattr(params, name) is None and triad is None:
            continue  # nothing of this sensor in the file, nothing written for it
        err = np.linalg.norm(theirs[k] - ours[k], axis=1)
        entry: dict[str, Any] = {
            "unit": "m/s^2" if name == "accel" else "rad/s",
            "poses": list(POSE_NAMES),
            "at_reference": [float(e) for e in err[at_ref & is_pose]],
            "reference_temp": t_ref,
            "over_temperature": float(np.max(err[is_pose])),
            "thermal_only": float(np.max(err[~is_pose])),
            "dtemp_terms": _dtemp_effect(triad, t_ref) if triad is not None else 0.0,
            "temperature_range": [float(temps[0]), float(temps[-1])],
        }
        out[name] = entry
    return out


def _intrinsics(params: ParamsFile, name: str) -> tuple[TempPolynomial | None, TempPolynomial | None]:
    thermal = params.thermal
    if thermal is None:
        return None, None
    return thermal.scale.get(name), thermal.misalignment.get(name)


def thermal_intrinsics_loss(params: ParamsFile) -> dict[str, dict[str, Any]]:
    """What a target holding bias alone over temperature drops of the thermal scale factor and
    misalignment, at the ends of each polynomial's clamp (module docstring).

    The scale-factor change relative to K at T_ref, k_i(t) / K_i, in ppm, and the misalignment change
    s_ij(t) in microradians, equation (1) of ``station.engines.thermal.intrinsics`` at
    t = t_min - T_ref and t = t_max - T_ref (K the diagonal of the section's matrix; 1 without one).

    Parameters
    ----------
    params : ParamsFile

    Returns
    -------
    dict
        Per triad with a polynomial, ``reference_temp`` and, per polynomial present, ``scale``:
        ``{"unit": "ppm", "components": [x, y, z], "temps": [t_min, t_max], "change": [[at t_min,
        at t_max] per axis], "largest": max |change|}``, ``misalignment`` the same in ``urad`` over
        the components xy, xz, yx, yz, zx, zy. Empty without polynomials.
    """
    out: dict[str, dict[str, Any]] = {}
    if params.thermal is None:
        return out
    t_ref = params.thermal.reference_temp
    for name in ("accel", "gyro"):
        scale, misalignment = _intrinsics(params, name)
        if scale is None and misalignment is None:
            continue
        entry: dict[str, Any] = {"reference_temp": t_ref}
        k0 = np.diag((getattr(params, name) or SensorCalibration.identity()).matrix)
        for key, poly, unit, components, factor in (
                ("scale", scale, "ppm", AXIS_NAMES, PPM / k0[:, None]),
                ("misalignment", misalignment, "urad", OFF_DIAGONAL_NAMES, URAD_PER_RAD)):
            if poly is None:
                continue
            ends = np.array([poly.t_min, poly.t_max])
            change = poly.evaluate(ends, t_ref).T * factor  # (components, 2)
            entry[key] = {"unit": unit, "components": list(components), "temps": ends.tolist(),
                          "change": change.tolist(), "largest": float(np.max(np.abs(change)))}
        out[name] = entry
    return out


def _intrinsics_limitations(target: str, lost: dict[str, dict[str, Any]]) -> list[Limitation]:
    """The loss of ``thermal_intrinsics_loss`` as limitations, one per triad and polynomial."""
    holds = "TC_* thermal parameters hold" if target == "px4" else "INS_TCAL* parameters hold"
    out = []
    for name, entry in lost.items():
        for key, what in (("scale", "scale factor over temperature"),
                          ("misalignment", "misalignment over temperature")):
            if key not in entry:
                continue
            e = entry[key]
            lo, hi = e["temps"]
            per = ", ".join(f"{c} {a:+.4g}/{b:+.4g}" for c, (a, b) in zip(e["components"], e["change"],
                                                                          strict=True))
            relative = " relative to K at" if key == "scale" else " from"
            out.append(Limitation(name, what, e["largest"], e["unit"],
                                  f"{holds} bias only; change{relative} {entry['reference_temp']:g} degC, at "
                                  f"T = {lo:g}/{hi:g} degC ({e['unit']}): {per}"))
    return out


def misalignment_size(cal: SensorCalibration | None) -> float:
    """The largest |S_ij| of a triad's misalignment (0 without a calibration)."""
    return 0.0 if cal is None else float(np.max(np.abs(cal.misalignment)))


def limitations(params: ParamsFile, errors: dict[str, dict[str, Any]],
                cubic_fits: dict[str, CubicFit | None]) -> list[Limitation]:
    """What an autopilot with per-axis offsets, per-axis accel scale (none for the gyro), one
    thermal cubic per sensor and no g-sensitivity cannot hold, each with the error it leaves."""
    out = []
    for name in ("accel", "gyro"):
        if name not in errors:
            continue
        cal = getattr(params, name)
        e = errors[name]
        unit = e["unit"]
        pose_text = "gravity" if name == "accel" else f"{GYRO_POSE_RATE:g} rad/s"
        at_ref = max(e["at_reference"])
        if cal is not None and name == "accel":
            out.append(Limitation(name, "misalignment", at_ref, unit,
                                  f"largest |S_ij| {misalignment_size(cal):.3g} rad; error at the six poses "
                                  f"({pose_text}) at {e['reference_temp']:g} degC"))
        elif cal is not None:
            scale_dev = float(np.max(np.abs(cal.scale - 1.0)))
            out.append(Limitation(name, "scale and misalignment", at_ref, unit,
                                  f"no gyro scale on this target: largest |K_i - 1| {scale_dev:.3g}, "
                                  f"largest |S_ij| {misalignment_size(cal):.3g} rad; error at the six poses "
                                  f"({pose_text}) at {e['reference_temp']:g} degC"))
        fit = cubic_fits.get(name)
        triad = getattr(params.thermal, name) if params.thermal is not None else None
        if triad is not None and fit is not None:
            lo, hi = e["temperature_range"]
            out.append(Limitation(name, "thermal model as one cubic", e["thermal_only"], unit,
                                  f"{len(triad.segments)} segment(s) re-fitted as one cubic about "
                                  f"{fit.centre:g} degC on [{fit.t_min:g}, {fit.t_max:g}] degC; largest "
                                  f"offset error over [{lo:g}, {hi:g}] degC at dT = 0"))
            out.append(Limitation(name, "dT terms", e["dtemp_terms"], unit,
                                  f"dT^2, dT and t*dT terms dropped; largest bias they carry for dT in "
                                  f"[{triad.dt_min:g}, {triad.dt_max:g}] degC/s"))
    g_matrix = g_sensitivity(params)
    if g_matrix is not None and params.gyro is not None:
        # The corrected gyro's error at 1 g in each of the six poses: M_g^-1 G f.
        left = np.linalg.norm(six_poses(STANDARD_GRAVITY) @ g_matrix.T @ params.gyro.correction.T, axis=1)
        largest = float(np.max(np.abs(g_matrix)))
        out.append(Limitation("gyro", "g-sensitivity", float(np.max(left)), "rad/s",
                              f"no g-sensitivity on this target: largest |G_ij| {largest:.3g} rad/s per "
                              "m/s^2; gyro bias left at 1 g, worst of the six poses"))
    return out


def polar(correction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The polar decomposition C = U P (module docstring), from the SVD C = W S V^T.

    Parameters
    ----------
    correction : ndarray, (3, 3)
        C, the mag section's correction.

    Returns
    -------
    tuple of ndarray
        U = W V^T, the rotation; P = V S V^T, symmetric positive definite (both (3, 3)).
    """
    w, s, vt = np.linalg.svd(np.asarray(correction, float))
    return w @ vt, vt.T @ np.diag(s) @ vt


def rotation_angle(rotation: np.ndarray) -> float:
    """The angle (rad) of a rotation matrix: arccos((trace - 1) / 2)."""
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def assess_mag(params: ParamsFile, values: dict[str, float], correct: Callable[[dict[str, float], np.ndarray],
               np.ndarray]) -> tuple[dict[str, Any], list[Limitation]] | None:
    """The target's magnetometer error against ours, and what it cannot hold (None without a mag section).

    The six poses are the field of the section's ``field_norm`` along +-x, +-y, +-z of the output
    frame; raw = M_m true + b_m; ours = true, theirs = ``correct(values, raw)``. The rotation U the
    target drops turns a field of length |B| by at most 2 sin(angle / 2) |B|, reported as the
    limitation's size.
    """
    mag = mag_calibration(params)
    if mag is None:
        return None
    norm = field_norm(mag)
    true = six_poses(norm)
    err = np.linalg.norm(correct(values, mag.forward(true)) - true, axis=1)
    rotation, _ = polar(mag.correction)
    angle = rotation_angle(rotation)
    frame = mag.extra.get("frame", "sensor")
    errors = {"unit": MAG_UNIT, "poses": list(POSE_NAMES), "at_reference": [float(e) for e in err],
              "field_norm": norm}
    limitation = Limitation(
        "mag", "rotation (polar part of C)", 2.0 * np.sin(angle / 2.0) * norm, MAG_UNIT,
        f"the target's soft-iron matrix is symmetric: {np.degrees(angle):.3g} deg of rotation dropped "
        + ("(the magnetometer's axes to the accelerometer's, frame accel)" if frame == "accel" else
           "(frame sensor: only rounding)")
        + f"; field direction off by up to that angle, worst error at |B| = {norm:g} uT; magnitude kept")
    return errors, [limitation]


def finish_export(target: str, params: ParamsFile, out: list[Param], notes: list[str],
                  fits: dict[str, CubicFit | None], instance: int, correct: InstanceCorrection,
                  offsets: InstanceOffsets, correct_mag: MagCorrection) -> AutopilotExport:
    """The export of ``out`` with its pose errors, offsets and limitations, from the target's own
    ``correct``, ``offsets`` and ``correct_mag`` formulas for sensor ``instance``."""
    result = AutopilotExport(target, out, notes=notes)
    values = result.values()
    result.pose_errors = assess(params, values, lambda v, a, g, t: correct(v, instance, a, g, t))
    result.offsets = lambda temp: offsets(values, instance, temp)
    result.limitations = limitations(params, result.pose_errors, cubic_fits=fits)
    result.thermal_intrinsics_lost = thermal_intrinsics_loss(params)
    result.limitations += _intrinsics_limitations(target, result.thermal_intrinsics_lost)
    mag = assess_mag(params, values, lambda v, raw: correct_mag(v, instance, raw))
    if mag is not None:
        result.pose_errors["mag"], mag_limits = mag
        result.limitations += mag_limits
    return result


def symmetric_params(diagonal: list[str], off_diagonal: list[str], matrix: np.ndarray) -> list[Param]:
    """A symmetric matrix as the autopilots name it: ``diagonal`` names for W_00, W_11, W_22,
    ``off_diagonal`` for W_01, W_02, W_12 (both autopilots' order)."""
    m = np.asarray(matrix, float)
    values = [*np.diag(m), m[0, 1], m[0, 2], m[1, 2]]
    names = [*diagonal, *off_diagonal]
    return [Param(name, float(v), "float") for name, v in zip(names, values, strict=True)]


def symmetric_from(values: dict[str, float], diagonal: list[str], off_diagonal: list[str],
                   default_diagonal: float) -> np.ndarray:
    """The symmetric matrix a target builds from its parameters (absent ones at their defaults)."""
    d = [values.get(name, default_diagonal) for name in diagonal]
    o = [values.get(name, 0.0) for name in off_diagonal]
    return np.array([[d[0], o[0], o[1]], [o[0], d[1], o[2]], [o[1], o[2], d[2]]])


def vector_params(prefix: str, suffixes: tuple[str, ...], values: np.ndarray) -> list[Param]:
    """One float parameter per axis: ``prefix`` + each of ``suffixes``."""
    values = np.asarray(values, float)
    return [Param(f"{prefix}{s}", float(v), "float") for s, v in zip(suffixes, values, strict=True)]


def sanitize_comment(text: str) -> str:
    """A unit string safe on one ``#`` comment line of a parameter file: printable ASCII only,
    everything else (newlines above all, which could start a parameter line) escaped."""
    return text.encode("unicode_escape").decode("ascii")
