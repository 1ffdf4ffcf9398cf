"""The parameter file's numbers as a certificate lists them: each with its 1-sigma, in the units people read.

Inside the station everything is SI (m/s^2, rad/s, rad); a certificate reads mg, deg/h, ppm and
deg, and the noise terms in the datasheet units ``imu-station allan`` names beside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from station.common.units import DEG, PEOPLE
from station.engines.allan.terms import NAMES as NOISE_NAMES
from station.engines.allan.terms import UNITS as NOISE_UNITS
from station.export.params.file import ParamsFile

AXES = "xyz"
BIAS_UNIT = {"accel": "mg", "gyro": "deg/h", "mag": "uT"}
_RESIDUAL_UNIT = {"m/s^2": "mg", "rad/s": "deg/h", "rad": "deg", "uT": "uT"}
SENSOR_NAMES = {"accel": "accelerometer", "gyro": "gyroscope", "mag": "magnetometer"}


@dataclass(frozen=True)
class Row:
    """One line of a parameter table: ``value`` and ``sigma`` (1-sigma) in ``unit``; None where not known."""

    quantity: str
    axis: str
    value: float | None
    sigma: float | None
    unit: str
    note: str = ""


def _at(values: Any, index: Any) -> float | None:
    """``values[index]`` as a float, or None where the section does not have it (missing, null)."""
    try:
        for i in index if isinstance(index, tuple) else (index,):
            values = values[i]
    except (TypeError, IndexError, KeyError):
        return None
    return float(values) if isinstance(values, int | float) and math.isfinite(values) else None


def _scaled(value: float | None, factor: float, offset: float = 0.0) -> float | None:
    return None if value is None else (value - offset) * factor


def _residual_unit(section: dict[str, Any], sensor: str) -> tuple[str, float]:
    """The unit the section's ``residual_rms`` is in: its ``residual`` note names it (a turntable's gyro
    residual is an angle), else the section's own unit."""
    note = str(section.get("residual") or "")
    own = {"accel": "m/s^2", "gyro": "rad/s"}.get(sensor, "uT")
    si = note.rsplit(",", 1)[-1].strip() if "," in note else own
    unit = _RESIDUAL_UNIT.get(si, si)
    return unit, PEOPLE.get(unit, 1.0)


def sensor_rows(name: str, section: dict[str, Any]) -> list[Row]:
    """Bias, scale error, misalignment and fit residual of one triad's section.

    Parameters
    ----------
    name : str
        ``accel`` or ``gyro``.
    section : dict
        The section as the parameter file holds it (SI units, ``stddev`` beside the estimates).

    Returns
    -------
    list of Row
        Bias in mg or deg/h, scale error K - 1 in ppm, the six misalignment angles in deg, the
        residual RMS in the unit of what was fitted.
    """
    sd = section.get("stddev") or {}
    unit = BIAS_UNIT[name]
    rows = [Row("bias", AXES[i], _scaled(_at(section.get("bias"), i), PEOPLE[unit]),
                _scaled(_at(sd.get("bias"), i), PEOPLE[unit]), unit) for i in range(3)]
    rows += [Row("scale error", AXES[i], _scaled(_at(section.get("scale"), i), PEOPLE["ppm"], 1.0),
                 _scaled(_at(sd.get("scale"), i), PEOPLE["ppm"]), "ppm") for i in range(3)]
    rows += [Row("misalignment", AXES[i] + AXES[j], _scaled(_at(section.get("misalignment"), (i, j)), DEG),
                 _scaled(_at(sd.get("misalignment"), (i, j)), DEG), "deg")
             for i in range(3) for j in range(3) if i != j]
    r_unit, factor = _residual_unit(section, name)
    rows.append(Row("residual RMS", "", _scaled(_at(section, "residual_rms"), factor), None, r_unit,
                    "fit quality, not an uncertainty"))
    return rows


def mag_rows(section: dict[str, Any]) -> list[Row]:
    """Hard iron, field magnitude, fit residual and sphere coverage of the ``mag`` section (microtesla)."""
    sd = section.get("stddev") or {}
    rows = [Row("hard iron (bias)", AXES[i], _at(section.get("bias"), i), _at(sd.get("bias"), i), "uT")
            for i in range(3)]
    rows.append(Row("field magnitude", "", _at(section, "field_norm"), _at(sd, "field_norm"), "uT"))
    rows.append(Row("residual RMS", "", _at(section, "residual_rms"), None, "uT",
                    "of |corrected| - field magnitude"))
    rows.append(Row("sphere coverage", "", _scaled(_at(section, "coverage"), PEOPLE["%"]), None, "%",
                    "share of field directions the capture visited"))
    return rows


def noise_rows(section: dict[str, Any]) -> list[Row]:
    """Every noise term present, per axis, in datasheet units (deg/sqrt(h), deg/h, ug, ...)."""
    rows = []
    for sensor in ("gyro", "accel"):
        terms = section.get(sensor)
        if not isinstance(terms, dict):
            continue
        sd = terms.get("stddev") or {}
        for term, (_, unit, factor) in NOISE_UNITS[sensor].items():
            if terms.get(term) is None:
                continue
            rows += [Row(f"{SENSOR_NAMES[sensor]} {term}", AXES[i], _scaled(_at(terms.get(term), i), factor),
                         _scaled(_at(sd.get(term), i), factor), unit, NOISE_NAMES[term]) for i in range(3)]
    return rows


def thermal_rows(params: ParamsFile) -> list[Row]:
    """The thermal model's reference, calibrated range and segments per triad."""
    model = params.thermal
    if model is None:
        return []
    rows = [Row("reference temperature", "", model.reference_temp, None, "degC")]
    for name in ("accel", "gyro"):
        bias = getattr(model, name)
        if bias is None:
            continue
        rows.append(Row(f"{SENSOR_NAMES[name]} range", "", bias.t_min, None, "degC",
                        f"to {bias.t_max:.1f} degC, {len(bias.segments)} segment(s); clamped beyond"))
    return rows
