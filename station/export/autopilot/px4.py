"""PX4 parameters (QGroundControl ``.params``: ``vehicle-id<TAB>component-id<TAB>NAME<TAB>VALUE<TAB>TYPE``).

PX4 corrects (``sensor_calibration::Accelerometer::Correct`` and ``Gyroscope::Correct``):

    acc  = R ((raw - TC_A(T) - CAL_ACCn_OFF) .* CAL_ACCn_SCALE)
    gyro = R  (raw - TC_G(T) - CAL_GYROn_OFF)

with R the board rotation (not ours to set) and the thermal offset of
``TemperatureCompensation::calc_thermal_offsets_3D``:

    TC(T) = X0 + X1 dt + X2 dt^2 + X3 dt^3,   dt = clamp(T, TMIN, TMAX) - TREF.

So offsets are our bias b, scales 1/K (the six-pose optimum), TREF our reference temperature and
X0..X3 a cubic re-fitted on it. PX4 holds no misalignment, no gyro scale, no dT terms, no gyro
g-sensitivity, and no change of scale factor or misalignment with temperature (TC_* is a bias:
``shared.thermal_intrinsics_loss`` reports what is dropped).

The magnetometer (``sensor_calibration::Magnetometer::Correct``, gauss):

    mag = R (W ((raw + power compensation) - CAL_MAGn_{X,Y,Z}OFF))

W symmetric: CAL_MAGn_{X,Y,Z}SCALE on its diagonal, CAL_MAGn_XODIAG = W_01, YODIAG = W_02,
ZODIAG = W_12. So OFF is our hard iron b_m in gauss (1 G = 100 uT; subtracted, as ours) and W the
symmetric factor P of our correction (``autopilot.polar``); its rotation U is not held.
"""

from __future__ import annotations

import numpy as np

from station import __version__
from station.export.autopilot import board
from station.export.autopilot import shared as ap
from station.export.params.file import ParamsFile
from station.export.params.sections import mag_calibration

AXES = ("X", "Y", "Z")
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9
MAX_INSTANCE = 3
UT_PER_GAUSS = 100.0
MAG_SCALE_RANGE = (0.1, 3.0)  # CAL_MAGn_{X,Y,Z}SCALE @min/@max
MAG_ODIAG = ("XODIAG", "YODIAG", "ZODIAG")


def _tc_offset(values: dict[str, float], prefix: str, enable: str, temp: np.ndarray) -> np.ndarray:
    if values.get(enable, 0) != 1 or f"{prefix}TREF" not in values:
        return np.zeros((len(temp), 3))
    t = np.clip(temp, values[f"{prefix}TMIN"], values[f"{prefix}TMAX"]) - values[f"{prefix}TREF"]
    coeff = np.array([[values[f"{prefix}X{k}_{axis}"] for k in range(4)] for axis in range(3)])
    return np.stack([t**0, t, t**2, t**3], axis=-1) @ coeff.T


def px4_offsets(values: dict[str, float], instance: int, temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What PX4 subtracts from raw accel and gyro at temperatures ``temp``: TC(T) + CAL offset."""
    acc_off = np.array([values.get(f"CAL_ACC{instance}_{a}OFF", 0.0) for a in AXES])
    gyr_off = np.array([values.get(f"CAL_GYRO{instance}_{a}OFF", 0.0) for a in AXES])
    return (_tc_offset(values, f"TC_A{instance}_", "TC_A_ENABLE", temp) + acc_off,
            _tc_offset(values, f"TC_G{instance}_", "TC_G_ENABLE", temp) + gyr_off)


def px4_correct(values: dict[str, float], instance: int, raw_acc: np.ndarray, raw_gyro: np.ndarray,
                temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PX4's correction (sensor frame, R = I) with ``values``; absent parameters at PX4's defaults."""
    acc_scale = np.array([values.get(f"CAL_ACC{instance}_{a}SCALE", 1.0) for a in AXES])
    acc_off, gyr_off = px4_offsets(values, instance, temp)
    return (raw_acc - acc_off) * acc_scale, raw_gyro - gyr_off


def px4_correct_mag(values: dict[str, float], instance: int, raw_ut: np.ndarray) -> np.ndarray:
    """PX4's magnetometer correction (R = I, no power compensation) with ``values``, microtesla in and out."""
    prefix = f"CAL_MAG{instance}_"
    offset = np.array([values.get(f"{prefix}{a}OFF", 0.0) for a in AXES])
    w = ap.symmetric_from(values, [f"{prefix}{a}SCALE" for a in AXES], [prefix + o for o in MAG_ODIAG], 1.0)
    return ((np.asarray(raw_ut, float) / UT_PER_GAUSS - offset) @ w.T) * UT_PER_GAUSS


def _mag_params(params: ParamsFile, instance: int, notes: list[str]) -> list[ap.Param]:
    mag = mag_calibration(params)
    if mag is None:
        return []
    _, w = ap.polar(mag.correction)
    prefix = f"CAL_MAG{instance}_"
    out = ap.vector_params(prefix, tuple(f"{a}OFF" for a in AXES), mag.bias / UT_PER_GAUSS)
    out += ap.symmetric_params([f"{prefix}{a}SCALE" for a in AXES], [prefix + o for o in MAG_ODIAG], w)
    lo, hi = MAG_SCALE_RANGE
    if np.any((np.diag(w) < lo) | (np.diag(w) > hi)):
        notes.append(f"warning: magnetometer scale {np.round(np.diag(w), 4).tolist()} is outside PX4's "
                     f"{lo}..{hi}")
    notes.append(f"CAL_MAG{instance}_ID is not written: PX4 applies the CAL_MAG{instance}_* values to the "
                 f"magnetometer that CAL_MAG{instance}_ID already names (see 'listener sensor_mag')")
    return out


def build_px4(params: ParamsFile, instance: int = 0, device_id: int | None = None,
              gyro_device_id: int | None = None) -> ap.AutopilotExport:
    """PX4 parameters for sensor ``instance`` (CAL_ACCn / CAL_GYROn / TC_An / TC_Gn); for a board file
    (``imus``), every IMU as its own instance (``instance`` 0) or IMU ``instance`` alone
    (:mod:`station.export.autopilot.board`)."""
    if not 0 <= instance <= MAX_INSTANCE:
        raise ValueError(f"PX4 sensor instance {instance} is out of 0..{MAX_INSTANCE}")
    if board.is_board(params):
        return board.build_board(params, build_px4, MAX_INSTANCE, instance, device_id, gyro_device_id)
    gyro_device_id = device_id if gyro_device_id is None else gyro_device_id
    out: list[ap.Param] = []
    notes: list[str] = []
    if params.accel is not None:
        if device_id is not None:
            out.append(ap.Param(f"CAL_ACC{instance}_ID", device_id, "int"))
        out += ap.vector_params(f"CAL_ACC{instance}_", tuple(f"{a}OFF" for a in AXES), params.accel.bias)
        scale = 1.0 / params.accel.scale
        out += ap.vector_params(f"CAL_ACC{instance}_", tuple(f"{a}SCALE" for a in AXES), scale)
    if params.gyro is not None:
        if gyro_device_id is not None:
            out.append(ap.Param(f"CAL_GYRO{instance}_ID", gyro_device_id, "int"))
        out += ap.vector_params(f"CAL_GYRO{instance}_", tuple(f"{a}OFF" for a in AXES), params.gyro.bias)
    fits: dict[str, ap.CubicFit | None] = {"accel": None, "gyro": None}
    thermal = params.thermal
    for name, letter, dev in (("accel", "A", device_id), ("gyro", "G", gyro_device_id)):
        triad = getattr(thermal, name) if thermal is not None else None
        if thermal is None or triad is None:
            continue
        fit = ap.fit_cubic(triad, thermal.reference_temp, thermal.reference_temp, triad.t_min, triad.t_max)
        fits[name] = fit
        prefix = f"TC_{letter}{instance}_"
        out.append(ap.Param(f"TC_{letter}_ENABLE", 1, "int"))
        if dev is not None:
            out.append(ap.Param(f"{prefix}ID", dev, "int"))
        out += [ap.Param(f"{prefix}TREF", fit.centre, "float"), ap.Param(f"{prefix}TMIN", fit.t_min, "float"),
                ap.Param(f"{prefix}TMAX", fit.t_max, "float")]
        for k in range(4):
            out += ap.vector_params(f"{prefix}X{k}_", ("0", "1", "2"), fit.coeffs[:, k])
    inertial = bool(out)
    out += _mag_params(params, instance, notes)
    if device_id is None and inertial:
        notes.append("no --device-id: CAL_*_ID and TC_*_ID are not written, so PX4 applies these values to "
                     f"whichever sensor its instance {instance} already names; give the sensor's device id "
                     "(from 'listener sensor_accel' / 'sensor_gyro') to bind them")
    notes.append("PX4 rotates the corrected vector by the sensor's rotation afterwards; these values are in "
                 "the unit's own axes, as calibrated")
    return ap.finish_export("px4", params, out, notes, fits, instance, px4_correct, px4_offsets,
                            px4_correct_mag)


def render_px4(result: ap.AutopilotExport, params: ParamsFile, station_id: str, exported: str) -> str:
    """The QGroundControl parameter file text (tab-separated, ``#`` comments)."""
    device = params.device
    lines = [
        "# Onboard parameters for Vehicle 1",
        "#",
        "# Stack: PX4 Pro",
        f"# Written by imu-station {__version__} at {ap.sanitize_comment(exported)} on station "
        f"{ap.sanitize_comment(station_id)}",
        f"# Unit serial {ap.sanitize_comment(str(device.get('serial', '')))}, "
        f"model {ap.sanitize_comment(str(device.get('model', '')))}, "
        f"firmware {ap.sanitize_comment(str(device.get('firmware', '')))}",
        "#",
        "# Vehicle-Id Component-Id Name Value Type",
    ]
    for p in result.params:
        kind = MAV_PARAM_TYPE_INT32 if p.kind == "int" else MAV_PARAM_TYPE_REAL32
        lines.append(f"1\t1\t{p.name}\t{p.text()}\t{kind}")
    return "\n".join(lines) + "\n"
