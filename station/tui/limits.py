"""Pass/fail of a calibration against limits: what the results screen shows beside each parameter.

The built-in limits suit consumer and industrial MEMS units: a parameter outside them means a
damaged unit or a bad run (wrong pose, motion during a hold) rather than a unit that needs
calibrating. A factory plan's limits (``tui --plan``) replace them: the unit is then judged as the
line judges it (:func:`plan_verdicts`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from station.engines.calibration.common import CalibrationReport
from station.engines.shared.sensor_model import SensorCalibration
from station.factory.measure import measure
from station.factory.plan import Plan

BUILT_IN = "built-in"
BUILT_IN_MEANING = "loose: they catch a damaged unit or a bad run"


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
    """One checked quantity: its worst value against the limit (``low`` too for a plan's range)."""

    sensor: str
    name: str
    value: float
    limit: float | None
    unit: str
    low: float | None = None

    @property
    def passed(self) -> bool:
        """True when the value is finite and within its limit(s)."""
        if not np.isfinite(self.value):
            return False
        above = self.limit is not None and self.value > self.limit
        return not above and (self.low is None or self.value >= self.low)

    def limit_text(self) -> str:
        """The limit as written: ``<= 1.5 m/s^2``, ``±0.5 m/s^2`` or ``0.99 .. 1.01``."""
        unit = f" {self.unit}" if self.unit else ""
        if self.low is not None and self.limit is not None:
            if self.low == -self.limit:
                return f"±{self.limit:.4g}{unit}"
            return f"{self.low:.4g} .. {self.limit:.4g}{unit}"
        if self.low is not None:
            return f">= {self.low:.4g}{unit}"
        return f"<= {self.limit:.4g}{unit}"


def limits_name(plan: Plan | None) -> str:
    """Which limits judge the results, for the header and the results screen.

    Parameters
    ----------
    plan : Plan or None
        The factory plan given with ``--plan``.

    Returns
    -------
    str
    """
    return BUILT_IN if plan is None else f"plan {plan.name}"


def plan_verdicts(plan: Plan, report: CalibrationReport, link: Mapping[str, Any]) -> list[Verdict]:
    """Each quantity the plan limits, judged as the factory run judges it (its worst component).

    Parameters
    ----------
    plan : Plan
        The factory plan.
    report : CalibrationReport
        The calibration.
    link : dict
        The link's statistics (``samples``, ``lost``, ``overflow_drops``).

    Returns
    -------
    list of Verdict
        One per limited quantity the calibration has (a gyroscope limit without rotations has none).
    """
    out = []
    for spec in plan.limits:
        found = measure(plan, [spec.quantity], report, dict(link))
        if not found:
            continue
        # measure() gives numbers (None where not finite); a record read back may hold text
        values = [float(m.value) if isinstance(m.value, (int, float)) else float("nan") for m in found]
        failed = [k for k, m in enumerate(found) if m.outcome != "PASS"]
        k = failed[0] if failed else max(range(len(found)), key=lambda i: abs(values[i]))
        worst, value = found[k], values[k]
        sensor, _, name = spec.quantity.partition(".")
        component = worst.name[len(spec.quantity) + 1:]  # x, y, z or xy ...; empty for a scalar
        out.append(Verdict(sensor, f"{name.replace('_', ' ')} {component}".strip(), value, spec.high,
                           spec.unit, spec.low))
    return out


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
