"""Pass/fail of a calibration against limits: what the results screen shows beside each parameter.

The defaults suit consumer and industrial MEMS units: a parameter outside them means a damaged
unit or a bad run (wrong pose, motion during a hold) rather than a unit that needs calibrating.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.sensor_model import SensorCalibration


@dataclass(frozen=True)
class SensorLimits:
    """Pass limits of one triad's calibration, in the sensor's unit (bias, residual) or as ratios."""

    bias_max: float  # |b| per axis, sensor unit
    scale_error_max: float  # |K - 1| per axis
    misalignment_max: float  # |S_ij|, rad
    residual_rms_max: float  # sensor unit


ACCEL_LIMITS = SensorLimits(bias_max=1.5, scale_error_max=0.1, misalignment_max=0.05, residual_rms_max=0.05)
# The gyro residual of the rotation method is the integrated angle error (rad): 0.05 rad is 3 deg.
GYRO_LIMITS = SensorLimits(bias_max=0.2, scale_error_max=0.1, misalignment_max=0.05, residual_rms_max=0.05)


@dataclass(frozen=True)
class Verdict:
    """One checked quantity: its worst value against the limit."""

    sensor: str
    name: str
    value: float
    limit: float
    unit: str

    @property
    def passed(self) -> bool:
        """True when the value is finite and within its limit."""
        return bool(np.isfinite(self.value)) and self.value <= self.limit


def evaluate(sensor: str, cal: SensorCalibration, limits: SensorLimits, unit: str,
             residual_unit: str | None = None) -> list[Verdict]:
    """The largest |bias|, |scale - 1|, |misalignment| and the residual RMS against ``limits``.

    ``residual_unit``: the unit of the method's residual when it is not the sensor's (the
    rotation fit's residual is an angle, rad).
    """
    worst = lambda values: float(np.max(np.abs(values)))  # noqa: E731
    verdicts = [
        Verdict(sensor, "max |bias|", worst(cal.bias), limits.bias_max, unit),
        Verdict(sensor, "max |scale - 1|", worst(cal.scale - 1.0), limits.scale_error_max, ""),
        Verdict(sensor, "max |misalignment|", worst(cal.misalignment), limits.misalignment_max, "rad"),
    ]
    if cal.residual_rms is not None:
        verdicts.append(Verdict(sensor, "residual rms", float(cal.residual_rms), limits.residual_rms_max,
                                residual_unit or unit))
    return verdicts
