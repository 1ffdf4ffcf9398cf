"""The parameter file's numbers as a certificate lists them: each with its 1-sigma, in the units people read.

Inside the station everything is SI (m/s^2, rad/s, rad); a certificate reads mg, deg/h, ppm and
deg, and the noise terms in the datasheet units ``imu-station allan`` names beside them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.units import STANDARD_GRAVITY
from station.common.units import DEG, PEOPLE
from station.engines.allan.terms import NAMES as NOISE_NAMES
from station.engines.allan.terms import UNITS as NOISE_UNITS
from station.errors import EngineInputError
from station.export.estimators.kalibr import KEYS as KALIBR_KEYS
from station.export.estimators.kalibr import UNIT as KALIBR_UNIT
from station.export.estimators.kalibr import filter_values
from station.export.params.file import gauss_markov_of

AXES = "xyz"
BIAS_UNIT = {"accel": "mg", "gyro": "deg/h", "mag": "uT"}
_RESIDUAL_UNIT = {"m/s^2": "mg", "rad/s": "deg/h", "rad": "deg", "uT": "uT"}
SENSOR_NAMES = {"accel": "accelerometer", "gyro": "gyroscope", "mag": "magnetometer"}


@dataclass(frozen=True)
class Row:
    """One line of a parameter table: ``value`` and ``sigma`` (1-sigma) in ``unit``; None where not known;
    a value that is not one number (a range, a setting) is its text."""

    quantity: str
    axis: str
    value: float | str | None
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
        gyro's g-sensitivity in deg/s/g (where the poses determined it), the residual RMS in the unit
        of what was fitted.
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
    if section.get("g_sensitivity") is not None:
        gs_unit = DEG * STANDARD_GRAVITY  # rad/s per m/s^2 -> deg/s per g
        rows += [Row("g-sensitivity", AXES[i] + AXES[j],
                     _scaled(_at(section.get("g_sensitivity"), (i, j)), gs_unit),
                     _scaled(_at(sd.get("g_sensitivity"), (i, j)), gs_unit), "deg/s/g",
                     "row: the gyro axis; column: the axis of the specific force")
                 for i in range(3) for j in range(3)]
    r_unit, factor = _residual_unit(section, name)
    rows.append(Row("residual RMS", "", _scaled(_at(section, "residual_rms"), factor), None, r_unit,
                    "fit quality, not an uncertainty"))
    return rows


def mag_rows(section: dict[str, Any]) -> list[Row]:
    """Every number of the ``mag`` section: hard iron, the soft-iron matrix, the field magnitude and
    dip, the angle between the magnetometer's and the accelerometer's axes, the fit's residual and the
    sphere coverage (microtesla, deg, %)."""
    sd = section.get("stddev") or {}
    rows = [Row("hard iron (bias)", AXES[i], _at(section.get("bias"), i), _at(sd.get("bias"), i), "uT")
            for i in range(3)]
    rows += [Row("soft iron (matrix)", AXES[i] + AXES[j], _at(section.get("matrix"), (i, j)),
                 _at(sd.get("matrix"), (i, j)), "", "raw = matrix @ true + bias")
             for i in range(3) for j in range(3)]
    source = str(section.get("field_source") or "")
    rows.append(Row("field magnitude", "", _at(section, "field_norm"), _at(sd, "field_norm"), "uT",
                    f"from {source}" if source else ""))
    if _at(section, "dip_deg") is not None:
        rows.append(Row("dip (inclination)", "", _at(section, "dip_deg"), _at(sd, "dip_deg"), "deg",
                        "positive: the field points down"))
    if _at(section, "alignment_deg") is not None:
        rows.append(Row("alignment to the accelerometer", "", _at(section, "alignment_deg"), None, "deg",
                        "angle of the rotation between the two triads' axes"))
        rows += [Row("alignment, 1-sigma per rotation axis", AXES[i], _at(sd.get("alignment_deg"), i), None,
                     "deg") for i in range(3) if _at(sd.get("alignment_deg"), i) is not None]
    rows.append(Row("residual RMS", "", _at(section, "residual_rms"), None, "uT",
                    "of |corrected| - field magnitude"))
    rows.append(Row("sphere coverage", "", _scaled(_at(section, "coverage"), PEOPLE["%"]), None, "%",
                    "share of field directions the capture visited"))
    return rows


def noise_rows(section: dict[str, Any]) -> list[Row]:
    """Every noise term present, per axis, in datasheet units (deg/sqrt(h), deg/h, ug, ...), then each
    axis's Gauss-Markov processes (steady-state sigma in the bias instability's unit, correlation time
    in s) and the cluster times the model holds over."""
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
                         _scaled(_at(sd.get(term), i), factor), unit, f"{term} = {NOISE_NAMES[term]}")
                     for i in range(3)]
        rows += _gauss_markov_rows(sensor, terms)
        valid = terms.get("valid_tau")
        for end, what in ((0, "from"), (1, "to")):
            rows += [Row(f"{SENSOR_NAMES[sensor]} model valid {what}", AXES[i], _at(valid, (i, end)), None,
                         "s", "valid from / to = the cluster times the model was fitted to and checked on")
                     for i in range(3) if _at(valid, (i, end)) is not None]
    return rows


def _gauss_markov_rows(sensor: str, terms: dict[str, Any]) -> list[Row]:
    """Each axis's first-order Gauss-Markov processes: steady-state sigma (the B term's unit) and
    correlation time tau_c (s), the k-th process of every axis on one line."""
    processes = [list(p or []) for p in (gauss_markov_of(terms) or [])[:3]]
    spread = terms.get("GM_stddev") or []
    _, unit, factor = NOISE_UNITS[sensor]["B"]
    who = SENSOR_NAMES[sensor]
    rows = []
    for k in range(max((len(p) for p in processes), default=0)):
        rows += [Row(f"{who} Gauss-Markov {k + 1} sigma", AXES[i], _scaled(_at(processes, (i, k, 0)), factor),
                     _scaled(_at(spread, (i, k, 0)), factor), unit,
                     "Gauss-Markov sigma = the process's steady-state 1-sigma")
                 for i in range(len(processes))]
        rows += [Row(f"{who} Gauss-Markov {k + 1} tau_c", AXES[i], _at(processes, (i, k, 1)),
                     _at(spread, (i, k, 1)), "s", "tau_c = correlation time") for i in range(len(processes))]
    return rows


def kalibr_rows(section: dict[str, Any]) -> list[Row]:
    """The four numbers a filter takes (Kalibr's imu.yaml, VINS-Fusion, ORB-SLAM3), in their SI units;
    empty when the record shows no K (the noise section then cannot give them, as ``allan --kalibr``
    says)."""
    try:
        values = filter_values(section)
    except EngineInputError:
        return []
    return [Row(KALIBR_KEYS[key], "", values[key], None, KALIBR_UNIT[key],
                "filter values = the largest axis's" + (
                    ", equivalent to the whole noise model" if (section.get(key[0]) or {}).get(
                        "filter_equivalent") else "")) for key in KALIBR_KEYS]


def rotation_rows(entry: dict[str, Any], first: int) -> list[Row]:
    """An ``imus`` entry's rotation relative to the first IMU, in degrees with its 1-sigma.

    The rotation R with v_this = R v_first (``rotation_to_first`` is R^T) as a rotation vector about the
    first IMU's x, y, z axes, the small angles the 1-sigma is of, and its whole angle.

    Parameters
    ----------
    entry : dict
        The entry as the parameter file holds it (``rotation_to_first``, ``rotation_sigma`` in rad).
    first : int
        The first IMU's instance, for the labels.

    Returns
    -------
    list of Row
    """
    to_first = np.asarray(entry["rotation_to_first"], float)
    r = to_first.T
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0)))
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    vector = axis / np.linalg.norm(axis) * angle if np.linalg.norm(axis) > 1e-15 else np.zeros(3)
    sigma = entry.get("rotation_sigma")
    quantity = f"rotation about IMU {first}'s axes"
    rows = [Row(quantity, AXES[i], math.degrees(vector[i]),
                _scaled(_at(sigma, i), math.degrees(1.0)), "deg",
                f"rotation vector of R, v_this = R v_{first}, each IMU in its own axes") for i in range(3)]
    rows.append(Row("rotation angle", "", math.degrees(angle), None, "deg"))
    ids = [f"{key.replace('_', ' ')} {entry[key]}" for key in ("device_id", "gyro_device_id")
           if entry.get(key) is not None]
    if ids:
        rows.append(Row("device", "", ", ".join(ids), None, ""))
    return rows
