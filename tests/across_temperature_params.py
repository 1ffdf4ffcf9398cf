"""A parameter file as a chamber campaign leaves it (calibration across temperature, turn-ons per soak,
hysteresis) with known values, for the tests of the figures that show it (datasheet, certificate, TUI)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from export_params import make_params

from station.engines.thermal.intrinsics import TempPolynomial

T_MIN, T_MAX, T_REF = -20.0, 60.0, 25.0
SCALE = np.array([[2.0e-4, 1.0e-6], [-1.5e-4, 0.0], [1.0e-4, -2.0e-6]])  # per axis: t, t^2 (1/degC, 1/degC^2)
MISALIGNMENT = np.array([[3e-6], [-2e-6], [1e-6], [0.0], [4e-6], [-1e-6]])  # rad/degC, entries xy .. zy

# What a chamber campaign writes (station.factory.campaign): turn-on repeatability per soak, in SI.
TURN_ON = [{"soak_c": -20.0, "accel_bias_repeatability": [2e-3, 3e-3, 4e-3],
            "gyro_bias_repeatability": [1e-4, 2e-4, 3e-4]},
           {"soak_c": 60.0, "accel_bias_repeatability": [5e-3, 6e-3, 7e-3],
            "gyro_bias_repeatability": [4e-4, 5e-4, 6e-4]}]
HYSTERESIS = {"accel_bias": [1e-3, -2e-3, 0.0], "gyro_bias": [1e-5, 0.0, -2e-5],
              "accel_bias_max": [3e-3, 4e-3, 1e-3], "gyro_bias_max": [3e-5, 1e-5, 4e-5],
              "bins": 70, "bin_c": 1.0, "t_min": -15.0, "t_max": 55.0}


def campaign_file(path: Path) -> Path:
    """The parameter file with the values above, saved at ``path``."""
    params = make_params(seed=5, device={"serial": "SIM-CAMPAIGN", "model": "imu-sim", "firmware": "1"})
    assert params.thermal is not None
    params.thermal.scale["gyro"] = TempPolynomial(T_MIN, T_MAX, (1, 2), SCALE)
    params.thermal.misalignment["gyro"] = TempPolynomial(T_MIN, T_MAX, (1,), MISALIGNMENT)
    params.other["characterisation"] = {"turn_ons": 3, "across_temperature": {
        "soaks_c": [-20.0, 60.0], "turn_on": TURN_ON, "hysteresis": HYSTERESIS}}
    params.save(path)
    return path
