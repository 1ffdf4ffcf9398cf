"""The ``thermal`` section as a certificate lists it: the model's settings and every coefficient.

The bias model is ``B(T, dT) = sum_k c_k term_k`` with ``t = T - T_ref`` and the terms t^3, t^2, t,
dT^2, dT, t dT and 1 (``station.engines.thermal.model.TERMS``); each coefficient is shown in the
triad's readable unit (mg, deg/h) per the unit of its term (degC, degC/s), so that a reader can
evaluate the model by hand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from station.common.units import PEOPLE
from station.engines.thermal.model import TERMS, ThermalModel
from station.report.html import number
from station.report.parameters import AXES, BIAS_UNIT, SENSOR_NAMES, Row

TERM_SHOWN = {"t3": "t\u00b3", "t2": "t\u00b2", "t": "t", "dt2": "dT\u00b2", "dt": "dT", "tdt": "t\u00b7dT",
              "1": "1"}
"""How each term is printed (t = T - T_ref in degC, dT in degC/s)."""
TERM_UNIT = {"t3": "/\u00b0C\u00b3", "t2": "/\u00b0C\u00b2", "t": "/\u00b0C",
             "dt2": "\u00b7s\u00b2/\u00b0C\u00b2", "dt": "\u00b7s/\u00b0C",
             "tdt": "\u00b7s/\u00b0C\u00b2", "1": ""}
"""What each coefficient's unit adds to the triad's bias unit (mg/°C for the t term)."""


@dataclass(frozen=True)
class CoefficientTable:
    """One triad's coefficients: ``rows`` of (segment range, axis, seven values) in ``unit``-based units."""

    name: str
    title: str
    units: list[str]
    terms: list[str]
    rows: list[tuple[str, str, list[float]]]


def thermal_rows(model: ThermalModel | None) -> list[Row]:
    """The model's reference temperature, dT filter, and per triad its calibrated range, dT clamp and
    held-out RMS before and after compensation.

    Parameters
    ----------
    model : ThermalModel or None

    Returns
    -------
    list of Row
    """
    if model is None:
        return []
    rows = [Row("reference temperature T_ref", "", model.reference_temp, None, "degC"),
            Row("dT filter", "", f"{model.dtemp_filter.kind}, tau {model.dtemp_filter.tau_s:g} s", None, "",
                "dT filter = how the firmware estimates dT from T")]
    for name in ("accel", "gyro"):
        bias = getattr(model, name)
        if bias is None:
            continue
        who, unit = SENSOR_NAMES[name], BIAS_UNIT[name]
        rows.append(Row(f"{who} calibrated range", "", f"{bias.t_min:.1f} to {bias.t_max:.1f}", None, "degC",
                        f"{len(bias.segments)} segment(s); T clamped beyond"))
        rows.append(Row(f"{who} dT clamp", "", f"{number(bias.dt_min)} to {number(bias.dt_max)}", None,
                        "degC/s"))
        for key, what in (("cv_rms_before", "held-out RMS, uncompensated"),
                          ("cv_rms_after", "held-out RMS, compensated")):
            values = bias.extra.get(key)
            if isinstance(values, list):
                rows += [Row(f"{who} {what}", AXES[i], _si(values, i, PEOPLE[unit]), None, unit,
                             "held-out RMS = of 1 s means, 5-fold cross-validation") for i in range(3)]
    return rows


def coefficient_tables(model: ThermalModel | None) -> list[CoefficientTable]:
    """Every segment's seven coefficients per axis, per triad, in readable units.

    Parameters
    ----------
    model : ThermalModel or None

    Returns
    -------
    list of CoefficientTable
    """
    if model is None:
        return []
    tables = []
    for name in ("accel", "gyro"):
        bias = getattr(model, name)
        if bias is None:
            continue
        unit = BIAS_UNIT[name]
        rows = [(f"{seg.t_min:.1f} to {seg.t_max:.1f}", AXES[i],
                 [float(c) * PEOPLE[unit] for c in seg.coeffs[i]]) for seg in bias.segments for i in range(3)]
        tables.append(CoefficientTable(name, f"{SENSOR_NAMES[name]} thermal bias coefficients",
                                       [unit + TERM_UNIT[t] for t in TERMS], [TERM_SHOWN[t] for t in TERMS],
                                       rows))
    return tables


def _si(values: Any, i: int, factor: float) -> float | None:
    value = values[i] if i < len(values) else None
    return float(value) * factor if isinstance(value, int | float) else None
