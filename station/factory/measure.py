"""Measurements of a run against the plan's limits: calibration parameters and link quality."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from station.engines.calibration.common import CalibrationReport
from station.factory.plan import QUANTITIES, SI_UNIT, UNITS, Plan
from station.factory.records import Measurement

AXES = "xyz"
OFF_DIAGONAL = [(i, j) for i, j in itertools.product(range(3), range(3)) if i != j]


def components(quantity: str, report: CalibrationReport | None, link: dict[str, Any]) -> dict[str, float]:
    """The SI values of one quantity by measurement name (``accel.bias.x`` ... ``accel.misalignment.xy``)."""
    if quantity == "link.lost_fraction":
        lost = float(link.get("lost", 0)) + float(link.get("overflow_drops", 0))
        expected = float(link.get("samples", 0)) + lost
        return {quantity: lost / expected if expected else float("nan")}
    sensor, name = quantity.split(".")
    cal = getattr(report, sensor) if report is not None else None
    if cal is None:
        return {}
    if name == "bias":
        return {f"{quantity}.{AXES[i]}": float(cal.bias[i]) for i in range(3)}
    if name == "scale_error":
        return {f"{quantity}.{AXES[i]}": float(cal.scale[i] - 1.0) for i in range(3)}
    if name == "misalignment":
        return {f"{quantity}.{AXES[i]}{AXES[j]}": float(cal.misalignment[i, j]) for i, j in OFF_DIAGONAL}
    if name == "residual_rms":
        return {quantity: float(cal.residual_rms)} if cal.residual_rms is not None else {}
    raise ValueError(f"unknown quantity {quantity!r}")


def measure(plan: Plan, quantities: list[str], report: CalibrationReport | None,
            link: dict[str, Any]) -> list[Measurement]:
    """Every component of ``quantities``: in the limit's unit and judged when the plan limits it,
    else in SI and UNSET."""
    out = []
    for quantity in quantities:
        spec = plan.limit(quantity)
        doc = QUANTITIES[quantity][1]
        for name, si_value in components(quantity, report, link).items():
            if spec is None:
                out.append(Measurement(name, _finite(si_value), SI_UNIT[QUANTITIES[quantity][0]], doc=doc))
                continue
            value = si_value / UNITS[spec.unit][1]
            out.append(Measurement(name, _finite(value), spec.unit, spec.low, spec.high,
                                   "PASS" if spec.check(value) else "FAIL", doc))
    return out


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None
