"""Applying a parameter file to raw samples: what ``imu-station apply`` and firmware compute.

    acc  = M_a^-1 (raw_a - b_a - B_a(T, dT))
    gyro = M_g^-1 (raw_g - b_g - B_g(T, dT))

with B the thermal bias of ``station.engines.thermal_model`` (zero where the file has no
thermal section or the temperature is unknown).
"""

from __future__ import annotations

import numpy as np

from station.engines.sensor_model import SensorCalibration
from station.engines.thermal_model import ThermalBias, ThermalModel


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
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected samples from raw ones and whichever sections of a parameter file exist (module
    docstring: acc = M_a^-1 (raw_a - b_a - B_a(T, dT)), likewise the gyro).

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
    return acc_cal.correct(acc, acc_tb), gyr_cal.correct(gyro, gyr_tb)
