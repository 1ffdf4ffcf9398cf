"""Applying a parameter file to raw samples: what ``imu-station apply`` and firmware compute.

    acc  = M_a(T)^-1 (raw_a - b_a - B_a(T, dT))                  (1)
    gyro = M_g(T)^-1 (raw_g - b_g - B_g(T, dT) - G acc)          (2)
    mag  = M_m^-1 (raw_m - b_m)                                   (3)

with B the thermal bias of ``station.engines.thermal.model`` (zero where the file has no
thermal section or the temperature is unknown), M(T) the section's matrix moved by the thermal
section's scale-factor and misalignment polynomials (``station.engines.thermal.intrinsics``; the
section's own matrix where it has none or the temperature is unknown), G the gyro's
g-sensitivity (rad/s per m/s^2: the bias change G f at specific force f, here the corrected
accelerometer sample of (1); zero where the file has none) and M_m, b_m the magnetometer's soft
and hard iron (microtesla).
"""

from __future__ import annotations

import numpy as np

from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.intrinsics import correct_at, matrices_at
from station.engines.thermal.model import ThermalBias, ThermalModel


def _thermal_bias(model: ThermalModel | None, triad: ThermalBias | None, temp: np.ndarray | None,
                  dtemp: np.ndarray | None, n: int) -> np.ndarray:
    if model is None or triad is None or temp is None:
        return np.zeros((n, 3))
    temp = np.asarray(temp, float)
    dtemp = np.zeros(n) if dtemp is None else np.asarray(dtemp, float)
    known_temp = np.nan_to_num(temp, nan=model.reference_temp)
    bias = triad.evaluate(known_temp, np.nan_to_num(dtemp), model.reference_temp)
    # Unknown temperature: no thermal term rather than a guess.
    bias[~np.isfinite(temp)] = 0.0
    return bias


def apply_calibration(
    acc: np.ndarray,
    gyro: np.ndarray,
    temp: np.ndarray | None = None,
    dtemp: np.ndarray | None = None,
    accel_cal: SensorCalibration | None = None,
    gyro_cal: SensorCalibration | None = None,
    thermal: ThermalModel | None = None,
    g_sensitivity: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected samples from raw ones and whichever sections of a parameter file exist (module
    docstring, equations (1) and (2)).

    Parameters
    ----------
    acc, gyro : ndarray, (N, 3)
        Raw samples.
    temp, dtemp : ndarray, (N,), optional
        Temperature (degC, NaN where unknown) and its filtered rate (degC/s) for the thermal bias B.
    accel_cal, gyro_cal : SensorCalibration, optional
        The static sections; identity where absent.
    thermal : ThermalModel, optional
        The thermal section; no thermal term where absent or the temperature is unknown.
    g_sensitivity : ndarray, (3, 3), optional
        G of equation (2), rad/s per m/s^2; none removed where absent.

    Returns
    -------
    tuple of ndarray
        Corrected (acc, gyro), each (N, 3).
    """
    acc = np.asarray(acc, float)
    gyro = np.asarray(gyro, float)
    n = len(acc)
    acc_cal = accel_cal or SensorCalibration.identity()
    gyr_cal = gyro_cal or SensorCalibration.identity()
    acc_tb = _thermal_bias(thermal, thermal.accel if thermal else None, temp, dtemp, n)
    gyr_tb = _thermal_bias(thermal, thermal.gyro if thermal else None, temp, dtemp, n)
    acc_true = _correct(acc, acc_cal, acc_tb, thermal, "accel", temp)
    if g_sensitivity is not None:
        # (2): the bias the specific force adds, in the gyro's raw axes like b_g and B_g.
        gyr_tb = gyr_tb + acc_true @ np.asarray(g_sensitivity, float).reshape(3, 3).T
    return acc_true, _correct(gyro, gyr_cal, gyr_tb, thermal, "gyro", temp)


def _correct(raw: np.ndarray, cal: SensorCalibration, extra_bias: np.ndarray, thermal: ThermalModel | None,
             triad: str, temp: np.ndarray | None) -> np.ndarray:
    """M^-1 (raw - b - extra), with M(T) of ``station.engines.thermal.intrinsics`` where the thermal
    section has the triad's scale or misalignment and the sample's temperature is known."""
    scale = thermal.scale.get(triad) if thermal is not None else None
    misalignment = thermal.misalignment.get(triad) if thermal is not None else None
    if thermal is None or temp is None or (scale is None and misalignment is None):
        return cal.correct(raw, extra_bias)
    temp = np.asarray(temp, float)
    known = np.isfinite(temp)
    if not known.any():
        return cal.correct(raw, extra_bias)
    extra = np.broadcast_to(extra_bias, raw.shape)
    out = np.empty(raw.shape)
    out[~known] = cal.correct(raw[~known], extra[~known])
    matrices = matrices_at(cal.matrix, temp[known], thermal.reference_temp, scale, misalignment)
    out[known] = correct_at(raw[known], cal.bias + extra[known], matrices)
    return out


def apply_mag(mag: np.ndarray, mag_cal: SensorCalibration | None) -> np.ndarray:
    """Corrected magnetic field, equation (3) of the module docstring: M_m^-1 (raw_m - b_m).

    Parameters
    ----------
    mag : ndarray, (N, 3)
        Raw field, microtesla (NaN rows stay NaN).
    mag_cal : SensorCalibration, optional
        The ``mag`` section's matrix and bias; the raw field is returned as it is where absent.

    Returns
    -------
    ndarray, (N, 3)
        The field in the frame the section names (``frame``: the accelerometer's or the
        magnetometer's own axes), microtesla.
    """
    mag = np.asarray(mag, float)
    return mag.copy() if mag_cal is None else mag_cal.correct(mag)
