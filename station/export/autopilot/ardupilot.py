"""ArduPilot parameters (``.param``: ``NAME,VALUE`` lines, ``#`` comments).

ArduPilot corrects (``AP_InertialSensor_Backend::_rotate_and_correct_accel`` / ``_gyro``):

    acc  = ((raw - P(T) + P(T_cal)) - INS_ACCOFFS) .* INS_ACCSCAL
    gyro =  (raw - P(T) + P(T_cal)) - INS_GYROFFS

with the temperature calibration of ``AP_InertialSensor_tempcal.cpp``: T and T_cal clamped to
[INS_TCALn_TMIN, INS_TCALn_TMAX], P a cubic without constant about TEMP_REFERENCE = 35 degC,

    P(T) = (c1 x + c2 x^2 + c3 x^3),  x = T - 35,  c_k = INS_TCALn_ACCk_* / 1e6 (GYRk for gyro),

and T_cal the INS_ACCn_CALTEMP / INS_GYRn_CALTEMP at which the offsets hold. Our re-fit of the
thermal bias is c0 + P(T), so the offsets are b + c0 + P(T_cal). ArduPilot holds no misalignment,
no gyro scale, no dT terms, no gyro g-sensitivity, no change of scale factor or misalignment with
temperature (INS_TCAL* is a bias: ``shared.thermal_intrinsics_loss`` reports what is dropped), and one
temperature range per IMU for both sensors.

The compass (``AP_Compass_Backend::correct_field``, milligauss):

    mag = W ((raw + COMPASS_OFS) * COMPASS_SCALE)   (the scale only where COMPASS_SCALE is set)

W symmetric, [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]] (the parameters'
own description). The offsets are ADDED: COMPASS_OFS = -b_m in milligauss (1 uT = 10 mGauss); W is
the symmetric factor P of our correction (``autopilot.polar``), and COMPASS_SCALE is written 0 (no
scaling) since W holds our scale. The rotation U is not held. Second and third compasses are
COMPASS_OFS2_/DIA2_/ODI2_/SCALE2 and ..3.
"""

from __future__ import annotations

import numpy as np

from station import __version__
from station.engines.thermal.model import ThermalModel
from station.export.autopilot import board
from station.export.autopilot import shared as ap
from station.export.params.file import ParamsFile
from station.export.params.sections import mag_calibration

AXES = ("X", "Y", "Z")
TEMP_REFERENCE = 35.0
SCALE_FACTOR = 1.0e6
MAX_INSTANCE = 2
ACCEL_SCALE_RANGE = (0.8, 1.2)  # INS_ACCSCAL_* @Range
ACCEL_OFFSET_LIMIT = 3.5  # INS_ACCOFFS_* @Range, m/s^2
MGAUSS_PER_UT = 10.0
COMPASS_OFFSETS_MAX = 1800.0  # COMPASS_OFFS_MAX default (AP_COMPASS_OFFSETS_MAX_DEFAULT), mGauss


def names(instance: int) -> dict[str, str]:
    """Parameter name prefixes of IMU ``instance`` (0-based: 0 is ArduPilot's first IMU)."""
    n = instance + 1
    first = n == 1
    return {
        "acc_off": "INS_ACCOFFS_" if first else f"INS_ACC{n}OFFS_",
        "acc_scal": "INS_ACCSCAL_" if first else f"INS_ACC{n}SCAL_",
        "gyr_off": "INS_GYROFFS_" if first else f"INS_GYR{n}OFFS_",
        "acc_id": "INS_ACC_ID" if first else f"INS_ACC{n}_ID",
        "gyr_id": "INS_GYR_ID" if first else f"INS_GYR{n}_ID",
        "tcal": f"INS_TCAL{n}_",
        "acc_caltemp": f"INS_ACC{n}_CALTEMP",
        "gyr_caltemp": f"INS_GYR{n}_CALTEMP",
    }


def compass_names(instance: int) -> dict[str, str]:
    """Compass parameter name prefixes of compass ``instance`` (0-based: 0 is COMPASS_OFS_*)."""
    n = "" if instance == 0 else str(instance + 1)
    return {"ofs": f"COMPASS_OFS{n}_", "dia": f"COMPASS_DIA{n}_", "odi": f"COMPASS_ODI{n}_",
            "scale": f"COMPASS_SCALE{n}"}


def ardupilot_correct_mag(values: dict[str, float], instance: int, raw_ut: np.ndarray) -> np.ndarray:
    """ArduPilot's compass correction (no motor compensation) with ``values``, microtesla in and out."""
    n = compass_names(instance)
    offset = np.array([values.get(f"{n['ofs']}{a}", 0.0) for a in AXES])
    scale = values.get(n["scale"], 0.0)
    w = ap.symmetric_from(values, [f"{n['dia']}{a}" for a in AXES], [f"{n['odi']}{a}" for a in AXES], 1.0)
    field = np.asarray(raw_ut, float) * MGAUSS_PER_UT + offset
    if scale != 0.0:
        field = field * scale
    return field @ w.T / MGAUSS_PER_UT


def _compass_params(params: ParamsFile, instance: int, notes: list[str]) -> list[ap.Param]:
    mag = mag_calibration(params)
    if mag is None:
        return []
    _, w = ap.polar(mag.correction)
    n = compass_names(instance)
    offsets = -mag.bias * MGAUSS_PER_UT
    out = ap.vector_params(n["ofs"], AXES, offsets)
    out += ap.symmetric_params([f"{n['dia']}{a}" for a in AXES], [f"{n['odi']}{a}" for a in AXES], w)
    out.append(ap.Param(n["scale"], 0.0, "float"))
    if np.any(np.abs(offsets) > COMPASS_OFFSETS_MAX):
        notes.append(f"warning: compass offsets {np.round(offsets, 1).tolist()} mGauss exceed "
                     f"COMPASS_OFFS_MAX's default {COMPASS_OFFSETS_MAX:g}: ArduPilot's arming check refuses "
                     "them unless it is raised")
    notes.append("compass values are in the unit's own axes; ArduPilot applies COMPASS_ORIENT (external) or "
                 "AHRS_ORIENTATION (internal) before them")
    return out


def _poly(values: dict[str, float], prefix: str, x: np.ndarray) -> np.ndarray:
    c = [np.array([values.get(f"{prefix}{k}_{a}", 0.0) for a in AXES]) for k in (1, 2, 3)]
    x = np.asarray(x, float)[:, None]
    return (c[0] + (c[1] + c[2] * x) * x) * x / SCALE_FACTOR


def _tcal(values: dict[str, float], tcal: str, sensor: str, caltemp_name: str,
          temp: np.ndarray) -> np.ndarray:
    if values.get(f"{tcal}ENABLE", 0) != 1:
        return np.zeros((len(temp), 3))
    lo, hi = values[f"{tcal}TMIN"], values[f"{tcal}TMAX"]
    t = np.clip(temp, lo, hi)
    t_cal = np.full(len(temp), np.clip(values[caltemp_name], lo, hi))
    prefix = f"{tcal}{sensor}"
    return _poly(values, prefix, t - TEMP_REFERENCE) - _poly(values, prefix, t_cal - TEMP_REFERENCE)


def ardupilot_offsets(values: dict[str, float], instance: int,
                      temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What ArduPilot subtracts from raw accel and gyro at ``temp``: P(T) - P(T_cal) + offsets."""
    n = names(instance)
    acc_off = np.array([values.get(f"{n['acc_off']}{a}", 0.0) for a in AXES])
    gyr_off = np.array([values.get(f"{n['gyr_off']}{a}", 0.0) for a in AXES])
    return (_tcal(values, n["tcal"], "ACC", n["acc_caltemp"], temp) + acc_off,
            _tcal(values, n["tcal"], "GYR", n["gyr_caltemp"], temp) + gyr_off)


def ardupilot_correct(values: dict[str, float], instance: int, raw_acc: np.ndarray, raw_gyro: np.ndarray,
                      temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ArduPilot's correction (sensor frame) with ``values``; absent parameters at ArduPilot's defaults."""
    acc_scal = np.array([values.get(f"{names(instance)['acc_scal']}{a}", 1.0) for a in AXES])
    acc_off, gyr_off = ardupilot_offsets(values, instance, temp)
    return (raw_acc - acc_off) * acc_scal, raw_gyro - gyr_off


def _temperature_range(thermal: ThermalModel) -> tuple[float, float]:
    """One range for both sensors: where both models are valid, or their union if disjoint."""
    triads = [t for t in (thermal.accel, thermal.gyro) if t is not None]
    lo, hi = max(t.t_min for t in triads), min(t.t_max for t in triads)
    if lo >= hi:
        lo, hi = min(t.t_min for t in triads), max(t.t_max for t in triads)
    return lo, hi


def build_ardupilot(params: ParamsFile, instance: int = 0, device_id: int | None = None,
                    gyro_device_id: int | None = None) -> ap.AutopilotExport:
    """ArduPilot parameters for IMU ``instance`` (0-based; 0 writes INS_ACCOFFS_*, INS_TCAL1_*, ...); for a
    board file (``imus``), every IMU as its own instance (``instance`` 0) or IMU ``instance`` alone
    (:mod:`station.export.autopilot.board`)."""
    if not 0 <= instance <= MAX_INSTANCE:
        raise ValueError(f"ArduPilot IMU instance {instance} is out of 0..{MAX_INSTANCE}")
    if board.is_board(params):
        return board.build_board(params, build_ardupilot, MAX_INSTANCE, instance, device_id, gyro_device_id)
    gyro_device_id = device_id if gyro_device_id is None else gyro_device_id
    n = names(instance)
    out: list[ap.Param] = []
    notes: list[str] = []
    compass = _compass_params(params, instance, notes)
    thermal = params.thermal
    if thermal is not None and thermal.accel is None and thermal.gyro is None:
        thermal = None  # a thermal section without a model: nothing to compensate
    fits: dict[str, ap.CubicFit | None] = {"accel": None, "gyro": None}
    offsets = {"accel": None if params.accel is None else params.accel.bias.copy(),
               "gyro": None if params.gyro is None else params.gyro.bias.copy()}
    tcal: list[ap.Param] = [ap.Param(f"{n['tcal']}ENABLE", 0 if thermal is None else 1, "int")]
    if thermal is not None:
        lo, hi = _temperature_range(thermal)
        t_cal = float(np.clip(thermal.reference_temp, lo, hi))
        tcal += [ap.Param(f"{n['tcal']}TMIN", lo, "float"), ap.Param(f"{n['tcal']}TMAX", hi, "float")]
        for name, sensor, caltemp in (("accel", "ACC", n["acc_caltemp"]), ("gyro", "GYR", n["gyr_caltemp"])):
            triad = getattr(thermal, name)
            coeffs = np.zeros((3, 4))
            if triad is not None:
                fit = ap.fit_cubic(triad, thermal.reference_temp, TEMP_REFERENCE, lo, hi)
                fits[name] = fit
                coeffs = fit.coeffs
                x = t_cal - TEMP_REFERENCE
                shift = coeffs[:, 0] + coeffs[:, 1] * x + coeffs[:, 2] * x**2 + coeffs[:, 3] * x**3
                offset = offsets[name]
                offsets[name] = (offset if offset is not None else np.zeros(3)) + shift
            for k in (1, 2, 3):
                tcal += ap.vector_params(f"{n['tcal']}{sensor}{k}_", AXES, coeffs[:, k] * SCALE_FACTOR)
            tcal.append(ap.Param(caltemp, t_cal, "float"))
    # An offset exists where the file has intrinsics or a thermal model for the sensor.
    acc_off, gyr_off = offsets["accel"], offsets["gyro"]
    if acc_off is not None:
        if device_id is not None:
            out.append(ap.Param(n["acc_id"], device_id, "int"))
        out += ap.vector_params(n["acc_off"], AXES, acc_off)
        scale = 1.0 / params.accel.scale if params.accel is not None else np.ones(3)
        out += ap.vector_params(n["acc_scal"], AXES, scale)
        lo_s, hi_s = ACCEL_SCALE_RANGE
        if np.any((scale < lo_s) | (scale > hi_s)):
            notes.append(f"warning: accel scale {np.round(scale, 4).tolist()} is outside ArduPilot's "
                         f"{lo_s}..{hi_s}; its accel calibration would reject it")
        if np.any(np.abs(acc_off) > ACCEL_OFFSET_LIMIT):
            notes.append(f"warning: accel offsets {np.round(acc_off, 4).tolist()} exceed "
                         f"ArduPilot's +-{ACCEL_OFFSET_LIMIT} m/s^2 range")
    if gyr_off is not None:
        if gyro_device_id is not None:
            out.append(ap.Param(n["gyr_id"], gyro_device_id, "int"))
        out += ap.vector_params(n["gyr_off"], AXES, gyr_off)
        notes.append("ArduPilot re-measures gyro offsets at every boot unless INS_GYR_CAL = 0; "
                     "set it to keep these")
    if out or thermal is not None:
        # The IMU's temperature calibration is written only with the IMU's sections: a file holding
        # a compass alone must not switch off a thermal calibration the vehicle already has.
        out += tcal
        notes.append("ArduPilot applies the sensor's orientation before these corrections; the values are in "
                     "the unit's own axes, as calibrated")
    out += compass
    return ap.finish_export("ardupilot", params, out, notes, fits, instance, ardupilot_correct,
                            ardupilot_offsets, ardupilot_correct_mag)


def render_ardupilot(result: ap.AutopilotExport, params: ParamsFile, station_id: str, exported: str) -> str:
    """The ``.param`` text (Mission Planner / MAVProxy ``NAME,VALUE``)."""
    device = params.device
    lines = [
        f"# ArduPilot sensor calibration written by imu-station {__version__} at "
        f"{ap.sanitize_comment(exported)} on station {ap.sanitize_comment(station_id)}",
        f"# Unit serial {ap.sanitize_comment(str(device.get('serial', '')))}, "
        f"model {ap.sanitize_comment(str(device.get('model', '')))}, "
        f"firmware {ap.sanitize_comment(str(device.get('firmware', '')))}",
    ]
    lines += [f"{p.name},{p.text()}" for p in result.params]
    return "\n".join(lines) + "\n"
