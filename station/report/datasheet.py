"""The unit's datasheet: one table of the figures a gyro/accelerometer datasheet gives (IEEE Std 952 and
1293, ADIS16470, BMI088, Xsens MTi), in datasheet units, from a parameter file's sections.

Each row says what measured it. Conversions (SI inside, datasheet units out):

- in-run bias stability: the Allan B term (the floor is 0.664 B), rad/s -> deg/h, m/s^2 -> ug;
- angle / velocity random walk: N, rad/s/sqrt(Hz) = rad/sqrt(s) -> deg/sqrt(h) (x 180/pi x 60),
  m/s^2/sqrt(Hz) = m/s/sqrt(s) -> m/s/sqrt(h) (x 60);
- turn-on repeatability: deg/s and mg, with the chi-square interval of ``characterise``; a chamber
  campaign's at each soak, and its bias hysteresis between the up and down ramps (deg/h, mg);
- g-sensitivity: G (rad/s per m/s^2) -> deg/s/g, one row per direction of the specific force;
- scale-factor error (K - 1) in ppm from the calibration's scale, nonlinearity and asymmetry in ppm;
- misalignment: per axis the root-sum-square of its row of S (off-diagonal), mrad;
- temperature sensitivity of the bias: the least-squares slope of the thermal bias at dT = 0 over the
  thermal model's temperature range, deg/s/degC and mg/degC, with the jackknife 1-sigma the thermal fit
  stored (``temp_sensitivity_sd``);
- where a calibration across temperature wrote them: the scale factor's temperature coefficient, the
  least-squares slope of K(T) over the range divided by K, ppm/degC, and the misalignment's change over
  the range (max - min of each entry of S(T); per axis the root-sum-square of its row), urad.

A figure whose section is absent is left out; an axis not measured shows as null (``-``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from station.common import table
from station.engines.thermal.intrinsics import OFF_DIAGONAL
from station.engines.thermal.model import ThermalModel

G = 9.80665  # m/s^2 per g, the datasheets' standard gravity
DEG = 180.0 / np.pi
RAD_S_TO_DEG_H = DEG * 3600.0


@dataclass(frozen=True)
class Row:
    """One datasheet figure: per axis value and 1-sigma (or interval) in ``unit``, and its source.

    Attributes
    ----------
    figure, unit : str
    values : list of float or None
        x, y, z.
    uncertainty : list of float, list of [lo, hi], or None per axis
        1-sigma, or a confidence interval when ``interval`` is set.
    measured_by : str
    interval : str
        The level of an interval (e.g. ``68 % interval``); empty for a 1-sigma.
    """

    figure: str
    unit: str
    values: list[float | None]
    uncertainty: list[Any]
    measured_by: str
    interval: str = ""

    def as_dict(self) -> dict[str, Any]:
        """The row as plain data (``--json``)."""
        return {"figure": self.figure, "unit": self.unit, "values": self.values,
                "uncertainty": self.uncertainty, "uncertainty_kind": self.interval or "1-sigma",
                "measured_by": self.measured_by}


def _scaled(values: Any, factor: float) -> list[float | None]:
    if values is None:
        return [None, None, None]
    return [None if v is None else float(v) * factor for v in values]


def _source(doc: dict[str, Any], section: str, fallback: str) -> str:
    src = (doc.get("sources") or {}).get(section) or {}
    where = src.get("capture")
    return f"{fallback} ({where})" if where else fallback


def _noise_rows(doc: dict[str, Any]) -> list[Row]:
    noise = doc.get("noise") or {}
    record = (noise.get("record") or {}).get("source")
    by = "Allan deviation" + (f" of {record}" if record else "")
    rows = []
    for sensor, term, figure, unit, factor in (
            ("gyro", "B", "gyro in-run bias stability", "deg/h", RAD_S_TO_DEG_H),
            ("accel", "B", "accel in-run bias stability", "ug", 1e6 / G),
            ("gyro", "N", "angle random walk", "deg/sqrt(h)", DEG * 60.0),
            ("accel", "N", "velocity random walk", "m/s/sqrt(h)", 60.0)):
        part = noise.get(sensor) or {}
        if part.get(term) is None:
            continue
        sd = (part.get("stddev") or {}).get(term)
        rows.append(Row(figure, unit, _scaled(part[term], factor), _scaled(sd, factor),
                        f"{by} ({term} term)"))
    return rows


def _characterisation_rows(doc: dict[str, Any]) -> list[Row]:
    ch = doc.get("characterisation") or {}
    rows = []
    level = ch.get("repeatability_level")
    kind = f"{100 * level:.0f} % interval" if level else "interval"
    turn_ons = ch.get("turn_ons")
    for sensor, unit, factor in (("gyro", "deg/s", DEG), ("accel", "mg", 1e3 / G)):
        key = f"{sensor}_bias_repeatability"
        if ch.get(key) is None:
            continue
        interval = ch.get(f"{key}_interval") or [None, None, None]
        rows.append(Row(f"{sensor} turn-on bias repeatability", unit, _scaled(ch[key], factor),
                        [None if i is None else [float(v) * factor for v in i] for i in interval],
                        f"spread of {turn_ons} turn-on means, in-run noise removed (characterise)", kind))
    rows += _across_temperature_rows(ch)
    for key, figure in (("gyro_scale_nonlinearity_ppm", "gyro scale-factor nonlinearity"),
                        ("gyro_scale_asymmetry_ppm", "gyro scale-factor asymmetry")):
        if ch.get(key) is not None:
            sd = ch.get(key.replace("_ppm", "_sd_ppm"))
            rows.append(Row(figure, "ppm", _scaled(ch[key], 1.0), _scaled(sd, 1.0),
                            "constant-rate steps (characterise)"))
    return rows


def _across_temperature_rows(ch: dict[str, Any]) -> list[Row]:
    """A chamber campaign's turn-on repeatability at each soak and bias hysteresis between its up and down
    ramps (``characterisation.across_temperature``, ``station.factory.campaign_figures``)."""
    block = ch.get("across_temperature") or {}
    rows = []
    for soak in block.get("turn_on") or []:
        for sensor, unit, factor in (("gyro", "deg/s", DEG), ("accel", "mg", 1e3 / G)):
            values = soak.get(f"{sensor}_bias_repeatability")
            if values is not None:
                figure = f"{sensor} turn-on bias repeatability at {float(soak['soak_c']):g} degC"
                rows.append(Row(figure, unit, _scaled(values, factor), [None, None, None],
                                f"1-sigma over {ch.get('turn_ons')} power-ups at the soak (campaign)"))
    hysteresis = block.get("hysteresis")
    if hysteresis:
        span = (f"{hysteresis['bins']} bins of {hysteresis['bin_c']:g} degC over "
                f"{hysteresis['t_min']:.1f}..{hysteresis['t_max']:.1f} degC")
        for sensor, unit, factor in (("gyro", "deg/h", RAD_S_TO_DEG_H), ("accel", "mg", 1e3 / G)):
            rows.append(Row(f"{sensor} bias hysteresis (up - down)", unit,
                            _scaled(hysteresis[f"{sensor}_bias"], factor), [None, None, None],
                            f"mean over {span} of the up ramp's bias less the down ramp's (campaign)"))
            rows.append(Row(f"{sensor} bias hysteresis, largest", unit,
                            _scaled(hysteresis[f"{sensor}_bias_max"], factor), [None, None, None],
                            f"largest |up - down| of the {span} (campaign)"))
    return rows


def _calibration_rows(doc: dict[str, Any]) -> list[Row]:
    rows = []
    ch = doc.get("characterisation") or {}
    for sensor in ("gyro", "accel"):
        section = doc.get(sensor)
        if not section:
            continue
        method = section.get("method") or "calibration"
        sd = section.get("stddev") or {}
        by = _source(doc, sensor, f"calibrate ({method})")
        if section.get("scale") is not None:
            error: list[float | None] = [(float(k) - 1.0) * 1e6 for k in section["scale"]]
            rows.append(Row(f"{sensor} scale-factor error", "ppm", error, _scaled(sd.get("scale"), 1e6), by))
        if section.get("misalignment") is not None:
            s = np.asarray(section["misalignment"], float)
            s_sd = sd.get("misalignment")
            unc = (np.sqrt(np.sum(np.asarray(s_sd, float) ** 2, axis=1)) * 1e3).tolist() if s_sd else None
            rows.append(Row(f"{sensor} misalignment", "mrad", (np.sqrt(np.sum(s**2, axis=1)) * 1e3).tolist(),
                            unc or [None, None, None], by + "; per axis the root-sum-square of its row"))
        if sensor == "gyro" and section.get("g_sensitivity") is not None:
            gs = np.asarray(section["g_sensitivity"], float) * DEG * G
            gs_sd = sd.get("g_sensitivity")
            gs_sd = np.asarray(gs_sd, float) * DEG * G if gs_sd is not None else None
            for j, axis in enumerate("xyz"):
                rows.append(Row(f"gyro g-sensitivity, force along {axis}", "deg/s/g", gs[:, j].tolist(),
                                gs_sd[:, j].tolist() if gs_sd is not None else [None, None, None],
                                by + "; static poses"))
    if doc.get("gyro") is None and ch.get("gyro_scale_error_ppm") is not None:
        rows.append(Row("gyro scale-factor error", "ppm", _scaled(ch["gyro_scale_error_ppm"], 1.0),
                        _scaled(ch.get("gyro_scale_error_sd_ppm"), 1.0),
                        "constant-rate steps (characterise)"))
    return rows


def _thermal_rows(doc: dict[str, Any]) -> list[Row]:
    section = doc.get("thermal")
    if not section:
        return []
    model = ThermalModel.from_dict(section)
    rows = []
    for sensor, unit, factor in (("gyro", "deg/s/degC", DEG), ("accel", "mg/degC", 1e3 / G)):
        bias = getattr(model, sensor)
        if bias is None:
            continue
        slope = bias.temperature_sensitivity(model.reference_temp)
        # the 1-sigma is absent from files written before the thermal fit stored it
        rows.append(Row(f"{sensor} bias temperature sensitivity", unit, (slope * factor).tolist(),
                        _scaled(bias.extra.get("temp_sensitivity_sd"), factor),
                        f"slope of the thermal model over {bias.t_min:.1f}..{bias.t_max:.1f} degC (thermal)"))
    for sensor in ("gyro", "accel"):
        rows += _intrinsics_rows(doc, model, sensor)
    return rows


def _intrinsics_rows(doc: dict[str, Any], model: ThermalModel, sensor: str) -> list[Row]:
    """The scale factor's temperature coefficient (ppm of K per degC) and the misalignment's change over the
    calibrated range (per axis the root-sum-square of its row's changes, urad), where a calibration across
    temperature wrote ``thermal.scale``/``thermal.misalignment``."""
    rows = []
    scale = model.scale.get(sensor)
    if scale is not None:
        k = np.asarray((doc.get(sensor) or {}).get("scale") or np.ones(3), float)
        ppm = 1e6 / k
        sd = scale.extra.get("temperature_coefficient_sd")
        rows.append(Row(f"{sensor} scale-factor temperature coefficient", "ppm/degC",
                        (scale.temperature_coefficient(model.reference_temp) * ppm).tolist(),
                        (np.asarray(sd, float) * ppm).tolist() if sd is not None else [None, None, None],
                        f"slope over {scale.t_min:.1f}..{scale.t_max:.1f} degC "
                        "(calibration across temperature)"))
    misalignment = model.misalignment.get(sensor)
    if misalignment is not None:
        change = np.zeros((3, 3))
        for c, (i, j) in enumerate(OFF_DIAGONAL):
            change[i, j] = misalignment.change_over_range(model.reference_temp)[c]
        span = f"{misalignment.t_min:.1f}..{misalignment.t_max:.1f} degC"
        rows.append(Row(f"{sensor} misalignment change over temperature", "urad",
                        (np.sqrt(np.sum(change**2, axis=1)) * 1e6).tolist(), [None, None, None],
                        f"max - min over {span}, per axis the root-sum-square of its row "
                        "(calibration across temperature)"))
    return rows


def datasheet_rows(doc: dict[str, Any]) -> list[Row]:
    """Every figure the parameter file's sections give, in datasheet order.

    Parameters
    ----------
    doc : dict
        A parameter file as plain data (checked by ``station.export.params.checks``).

    Returns
    -------
    list of Row
    """
    return _noise_rows(doc) + _characterisation_rows(doc) + _calibration_rows(doc) + _thermal_rows(doc)


def cell(value: float | None, unc: Any) -> str:
    """One value as the table shows it: value +/- 1-sigma, value [interval], or ``-`` where not measured.

    Parameters
    ----------
    value : float or None
    unc : float, [lo, hi] or None

    Returns
    -------
    str
    """
    if value is None:
        return "-"
    text = f"{value:.4g}"
    if isinstance(unc, list | tuple):
        return f"{text} [{unc[0]:.3g}, {unc[1]:.3g}]"
    if unc is not None:
        return f"{text} +/- {unc:.2g}"
    return text


def format_table(rows: list[Row], sources: bool = True) -> str:
    """The rows as a plain-text table: figure, unit, x, y, z (value +/- 1-sigma, or [interval]), source.

    Parameters
    ----------
    rows : list of Row
    sources : bool
        With the "measured by" column (False: a table that fits 80 columns).

    Returns
    -------
    str
    """
    columns = 6 if sources else 5
    header = ("figure", "unit", "x", "y", "z", "measured by")[:columns]
    cells = [(r.figure, r.unit, *(cell(v, u) for v, u in zip(r.values, r.uncertainty, strict=True)),
              r.measured_by + (f" [{r.interval}]" if r.interval else ""))[:columns] for r in rows]
    return table.format_table("", header, cells, rule=False)
