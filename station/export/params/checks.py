"""The parameter-file schema (``shared/specs/params-file.md``) checked on read, section by section.

Types (a boolean is not a number), shapes, finiteness and plausible ranges, each named with its
unit, so that nothing the export writes for firmware can hold a value its loader or a C compiler
refuses. A failure names the file, the key (``accel.bias``) and, when the file is at hand, its line.

The ranges are generous: they admit a calibration in raw counts (a 24-bit sensor's bias, a matrix
of thousands of counts per SI unit) and refuse only what no sensor gives, such as -1e30.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from station.engines.thermal.model import TERMS
from station.errors import InputFileError

Keys = tuple[str | int, ...]
Locate = Callable[[Keys], int | None]

MATRIX_LIMIT = 1e7  # raw per true unit: counts per m/s^2 of a 24-bit accelerometer stay far below
BIAS_LIMIT = 1e8  # m/s^2, rad/s or counts
MAX_CONDITION = 1e6  # of M: the correction M^-1 must stay meaningful in float32
MAX_MISALIGNMENT = 10.0  # |S_ij| of M = K (I + S), rad; a real one is below 0.1
G_SENSITIVITY_LIMIT = 10.0  # rad/s per m/s^2
TEMP_RANGE = (-100.0, 200.0)  # degC
DTEMP_LIMIT = 100.0  # degC/s
TAU_LIMIT = 1e5  # s
DEVICE_IDS = ("accel_device_id", "gyro_device_id")  # an autopilot log's sensor ids, in ``device``
COEFF_LIMIT = 1e7  # sensor unit per degC^k (degC/s)^l
MAX_SEGMENTS = 64
NOISE_LIMIT = 1e6
FLOAT32_MAX = float(np.finfo(np.float32).max)
UNITS = {"accel": "m/s^2", "gyro": "rad/s", "temperature": "degC"}
SENSOR_UNIT = {"accel": "m/s^2", "gyro": "rad/s"}


def _name(keys: Keys) -> str:
    out = ""
    for key in keys:
        out += f"[{key}]" if isinstance(key, int) else (f".{key}" if out else str(key))
    return out


class _Checker:
    def __init__(self, path: str | Path, locate: Locate | None):
        self.path = path
        self.locate = locate

    def fail(self, keys: Keys, problem: str) -> InputFileError:
        line = self.locate(keys) if self.locate is not None else None
        return InputFileError(self.path, problem, line=line, column=_name(keys) or None)

    def mapping(self, value: Any, keys: Keys, what: str = "a mapping (key: value lines)") -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(keys, f"must be {what}, not {_shown(value)}")
        return value

    def text(self, value: Any, keys: Keys) -> str:
        if not isinstance(value, str):
            raise self.fail(keys, f"must be text, not {_shown(value)}")
        return value

    def number(self, value: Any, keys: Keys, lo: float, hi: float, unit: str) -> float:
        in_unit = f" ({unit})" if unit else ""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(keys, f"must be a number{in_unit}, not {_shown(value)}")
        if not (isinstance(value, int) or math.isfinite(value)):
            raise self.fail(keys, f"{_shown(value)} is not a finite number{in_unit}")
        # Compared before float(): an integer of 400 digits has no float.
        if not lo <= value <= hi:
            if hi >= FLOAT32_MAX:
                raise self.fail(keys, f"{_shown(value)} is beyond the float32 range the firmware holds")
            raise self.fail(keys, f"{_shown(value)} {unit} is outside the plausible range "
                            f"{lo:g}..{hi:g} {unit}")
        return float(value)

    def array(self, value: Any, keys: Keys, shape: tuple[int, ...], limit: float, unit: str,
              nullable: bool = False) -> None:
        """A nested list of ``shape`` of numbers within +-limit (or null where ``nullable``)."""
        if not shape:
            if not (nullable and value is None):
                self.number(value, keys, -limit, limit, unit)
            return
        if not isinstance(value, list) or len(value) != shape[0]:
            kind = "numbers" if len(shape) == 1 else f"lists ({'x'.join(map(str, shape))})"
            raise self.fail(keys, f"must be a list of {shape[0]} {kind}, not {_shown(value)}")
        for i, item in enumerate(value):
            self.array(item, (*keys, i), shape[1:], limit, unit, nullable)

    def numbers(self, value: Any, keys: Keys) -> None:
        """Any nesting of lists of finite numbers and nulls (a 1-sigma table, free-form)."""
        if value is None:
            return
        if isinstance(value, list):
            for i, item in enumerate(value):
                self.numbers(item, (*keys, i))
            return
        self.number(value, keys, -FLOAT32_MAX, FLOAT32_MAX, "")


def _shown(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def check_params(data: Any, path: str | Path = "<params>", locate: Locate | None = None) -> None:
    """Refuse a parameter-file document that breaks the schema; return quietly otherwise.

    Parameters
    ----------
    data : Any
        The document as read from YAML (plain dicts, lists, text and numbers).
    path : str or Path
        The file, for the message.
    locate : callable, optional
        Maps a key path such as ``("accel", "bias", 1)`` to its line in the file.

    Raises
    ------
    InputFileError
        With the file, the key, the line when ``locate`` knows it, and the unit of a number.
    """
    c = _Checker(path, locate)
    doc = c.mapping(data, (), "a YAML mapping; expected an imu-station parameter file")
    if doc.get("device") is not None:
        for key, value in c.mapping(doc["device"], ("device",)).items():
            if key in ("serial", "model", "firmware") and (isinstance(value, bool)
                                                           or not isinstance(value, str | int | float)):
                raise c.fail(("device", key), f"must be text, not {_shown(value)}")
            if key in DEVICE_IDS and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                raise c.fail(("device", key), f"must be a sensor's device id (a whole number from 0), not "
                             f"{_shown(value)}")
    if "created" in doc:
        c.text(doc["created"], ("created",))
    if doc.get("units") is not None:
        for key, value in c.mapping(doc["units"], ("units",)).items():
            if key in UNITS and value != UNITS[key]:
                raise c.fail(("units", key), f"is {_shown(value)}; this station reads {key} in {UNITS[key]}")
    for name in ("accel", "gyro"):
        if doc.get(name) is not None:
            _sensor(c, doc[name], name)
    if doc.get("thermal") is not None:
        _thermal(c, doc["thermal"])
    if doc.get("noise") is not None:
        _noise(c, doc["noise"])
    if doc.get("mag") is not None:
        _mag(c, doc["mag"])
    if doc.get("characterisation") is not None:
        _characterisation(c, doc["characterisation"])
    if doc.get("imus") is not None:
        _imus(c, doc["imus"], doc)
    if doc.get("sources") is not None:
        _sources(c, doc["sources"])


MAX_IMUS = 256  # instances are one byte in every log and protocol
ROTATION_TOLERANCE = 1e-5  # |R^T R - I| of a stored rotation, written from float64 and read back


def _imus(c: _Checker, value: Any, doc: dict[str, Any]) -> None:
    """``imus``: the board's IMUs, the first naming the top-level sections, the others their own sections
    and their rotation to the first (``station.export.params.imus``)."""
    if not isinstance(value, list) or not 1 <= len(value) <= MAX_IMUS:
        raise c.fail(("imus",), f"must be a list of 1 to {MAX_IMUS} IMU entries (instance, device ids, "
                     f"sections), not {_shown(value)}")
    seen: set[int] = set()
    for k, item in enumerate(value):
        keys: Keys = ("imus", k)
        entry = c.mapping(item, keys)
        instance = entry.get("instance")
        if isinstance(instance, bool) or not isinstance(instance, int) or not 0 <= instance < MAX_IMUS:
            raise c.fail((*keys, "instance"), f"must be the IMU's instance, a whole number "
                         f"0..{MAX_IMUS - 1}, not {_shown(instance)}")
        if instance in seen:
            raise c.fail((*keys, "instance"), f"instance {instance} is listed twice; each IMU once")
        seen.add(instance)
        for key in ("device_id", "gyro_device_id"):
            ident = entry.get(key)
            if ident is not None and (isinstance(ident, bool) or not isinstance(ident, int)
                                      or not 0 <= ident <= 2**32 - 1):
                raise c.fail((*keys, key), f"must be a device id, a whole number 0..{2**32 - 1}, not "
                             f"{_shown(ident)}")
        if k == 0:
            extra = [key for key in ("accel", "gyro", "thermal", "rotation_to_first") if key in entry]
            if extra:
                raise c.fail((*keys, extra[0]), "the first IMU's sections are the top-level ones; its entry "
                             "holds only its instance and device ids (remove this key, or move it up)")
            if doc.get("accel") is None:
                raise c.fail(("imus",), "lists the board's IMUs but the file has no top-level 'accel' "
                             "section, the first IMU's; write the file with 'imu-station calibrate'")
            continue
        if "rotation_to_first" not in entry:
            raise c.fail(keys, f"IMU {instance} lacks the required key 'rotation_to_first' (3x3, its vectors "
                         "into the first IMU's axes)")
        for name in ("accel", "gyro"):
            if entry.get(name) is not None:
                _sensor(c, entry[name], name, keys)
        if entry.get("thermal") is not None:
            _thermal(c, entry["thermal"], keys)
        c.array(entry["rotation_to_first"], (*keys, "rotation_to_first"), (3, 3), 1.0 + ROTATION_TOLERANCE,
                "")
        rotation = np.asarray(entry["rotation_to_first"], float)
        if (np.max(np.abs(rotation.T @ rotation - np.eye(3))) > ROTATION_TOLERANCE
                or np.linalg.det(rotation) < 0):
            raise c.fail((*keys, "rotation_to_first"), "is not a rotation (R^T R = I, det +1): a mirror or a "
                         "scaled matrix; write it with 'imu-station calibrate'")
        if entry.get("rotation_sigma") is not None:
            c.array(entry["rotation_sigma"], (*keys, "rotation_sigma"), (3,), math.pi, "rad", nullable=True)
            _not_negative(c, entry["rotation_sigma"], (*keys, "rotation_sigma"))


def _sources(c: _Checker, value: Any) -> None:
    """``sources``: per section, the capture and unit it came from, every value text."""
    for name, source in c.mapping(value, ("sources",)).items():
        for key, item in c.mapping(source, ("sources", name)).items():
            if isinstance(item, bool) or not isinstance(item, str | int | float):
                raise c.fail(("sources", name, key), f"must be text, not {_shown(item)}")


def _sensor(c: _Checker, value: Any, name: str, within: Keys = ()) -> None:
    unit = SENSOR_UNIT[name]
    at: Keys = (*within, name)
    section = c.mapping(value, at)
    for key in ("matrix", "bias"):
        if key not in section:
            raise c.fail(at, f"section '{name}' lacks the required key '{key}'")
    c.array(section["matrix"], (*at, "matrix"), (3, 3), MATRIX_LIMIT, "raw per true unit")
    c.array(section["bias"], (*at, "bias"), (3,), BIAS_LIMIT, unit)
    _invertible(c, section["matrix"], (*at, "matrix"))
    for key, shape in (("correction", (3, 3)), ("scale", (3,)), ("misalignment", (3, 3))):
        if key in section:
            c.array(section[key], (*at, key), shape, FLOAT32_MAX, "")
    if section.get("method") is not None:
        c.text(section["method"], (*at, "method"))
    if section.get("residual_rms") is not None:
        c.number(section["residual_rms"], (*at, "residual_rms"), 0.0, FLOAT32_MAX, unit)
    if section.get("stddev") is not None:
        for key, sd in c.mapping(section["stddev"], (*at, "stddev")).items():
            c.numbers(sd, (*at, "stddev", key))
    if "g_sensitivity" in section:
        c.array(section["g_sensitivity"], (*at, "g_sensitivity"), (3, 3), G_SENSITIVITY_LIMIT,
                "rad/s per m/s^2")


def _invertible(c: _Checker, matrix: Any, keys: Keys, diagonal: bool = True) -> None:
    m = np.asarray(matrix, dtype=float)
    if abs(np.linalg.det(m)) < 1e-12 or np.linalg.cond(m) > MAX_CONDITION:
        raise c.fail(keys, f"is singular or nearly so (condition number {np.linalg.cond(m):.3g}, the most "
                     f"read is {MAX_CONDITION:g}): it cannot be inverted into a correction")
    if not diagonal:
        return
    # M = K (I + S): the scale K is the diagonal, and S = K^-1 M - I must be a misalignment.
    scale = np.abs(np.diag(m))
    if np.any(scale * MAX_MISALIGNMENT < np.max(np.abs(m), axis=1)):
        raise c.fail(keys, f"has a diagonal (the scale factors) of {np.diag(m).tolist()} that is not the "
                     f"largest part of its row: a misalignment beyond {MAX_MISALIGNMENT:g} rad is no "
                     "sensor's")


def _thermal(c: _Checker, value: Any, within: Keys = ()) -> None:
    at: Keys = (*within, "thermal")
    section = c.mapping(value, at)
    for key in ("reference_temp", "dtemp_filter"):
        if key not in section:
            raise c.fail(at, f"section 'thermal' lacks the required key '{key}'")
    c.number(section["reference_temp"], (*at, "reference_temp"), *TEMP_RANGE, "degC")
    filt = c.mapping(section["dtemp_filter"], (*at, "dtemp_filter"))
    if filt.get("kind") != "ema":
        raise c.fail((*at, "dtemp_filter", "kind"),
                     f"dT filter kind {_shown(filt.get('kind'))} is unknown; this station knows 'ema'")
    c.number(filt.get("tau_s"), (*at, "dtemp_filter", "tau_s"), 0.0, TAU_LIMIT, "s")
    for name in ("accel", "gyro"):
        if section.get(name) is not None:
            _thermal_triad(c, section[name], (*at, name), SENSOR_UNIT[name])
    for key, rows in (("scale", 3), ("misalignment", 6)):
        if section.get(key) is None:
            continue
        for name, entry in c.mapping(section[key], (*at, key)).items():
            if name not in ("accel", "gyro"):
                raise c.fail((*at, key, name),
                             f"is not a triad; 'thermal.{key}' holds 'accel' and 'gyro'")
            if entry is not None:
                _temp_polynomial(c, entry, (*at, key, name), rows)


def _temp_polynomial(c: _Checker, value: Any, keys: Keys, rows: int) -> None:
    """An entry of ``thermal.scale``/``thermal.misalignment`` (``station.engines.thermal.intrinsics``)."""
    entry = c.mapping(value, keys)
    for key in ("clamp", "powers", "coeffs"):
        if key not in entry:
            raise c.fail(keys, f"lacks the required key '{key}'")
    clamp = entry["clamp"]
    if not isinstance(clamp, list) or len(clamp) != 2:
        raise c.fail((*keys, "clamp"), f"must be [min, max] in degC, not {_shown(clamp)}")
    low, high = (c.number(v, (*keys, "clamp", i), *TEMP_RANGE, "degC") for i, v in enumerate(clamp))
    if not np.float32(low) < np.float32(high):
        raise c.fail((*keys, "clamp"), f"[{low:g}, {high:g}] degC is not a range (min not below max)")
    powers = entry["powers"]
    if (not isinstance(powers, list) or not 1 <= len(powers) <= 3 or len(set(map(str, powers))) != len(powers)
            or any(isinstance(p, bool) or p not in (1, 2, 3) for p in powers)):
        raise c.fail((*keys, "powers"),
                     f"must list distinct powers of t among 1, 2 and 3, not {_shown(powers)}")
    what = "per degC^k (k the power)"
    c.array(entry["coeffs"], (*keys, "coeffs"), (rows, len(powers)), COEFF_LIMIT, what)
    if entry.get("stddev") is not None:
        c.array(entry["stddev"], (*keys, "stddev"), (rows, len(powers)), COEFF_LIMIT, what)
        for r, row in enumerate(entry["stddev"]):
            for j, sd in enumerate(row):
                if sd < 0:
                    raise c.fail((*keys, "stddev", r, j), f"{sd:g} is negative; a 1-sigma is at least 0")


def _thermal_triad(c: _Checker, value: Any, keys: Keys, unit: str) -> None:
    triad = c.mapping(value, keys)
    if "terms" in triad and triad["terms"] != list(TERMS):
        raise c.fail((*keys, "terms"), f"thermal terms {_shown(triad['terms'])} are not the known "
                     f"{list(TERMS)}")
    clamp = c.mapping(triad.get("clamp", {}), (*keys, "clamp"))
    for key, lo, hi, what in (("temp", *TEMP_RANGE, "degC"), ("dtemp", -DTEMP_LIMIT, DTEMP_LIMIT, "degC/s")):
        if key in clamp:
            pair = clamp[key]
            if not isinstance(pair, list) or len(pair) != 2:
                raise c.fail((*keys, "clamp", key), f"must be [min, max] in {what}, not {_shown(pair)}")
            low, high = (c.number(v, (*keys, "clamp", key, i), lo, hi, what) for i, v in enumerate(pair))
            if low > high:
                raise c.fail((*keys, "clamp", key), f"[{low:g}, {high:g}] {what} is not a range "
                             "(min above max)")
    segments = triad.get("segments")
    if not isinstance(segments, list) or not 1 <= len(segments) <= MAX_SEGMENTS:
        raise c.fail((*keys, "segments"), f"must be a list of 1 to {MAX_SEGMENTS} segments, not "
                     f"{_shown(segments)}")
    previous_max = None
    for i, seg_value in enumerate(segments):
        at = (*keys, "segments", i)
        seg = c.mapping(seg_value, at)
        for key in ("t_min", "t_max", "coeffs"):
            if key not in seg:
                raise c.fail(at, f"segment {i} lacks the required key '{key}'")
        t_min = c.number(seg["t_min"], (*at, "t_min"), *TEMP_RANGE, "degC")
        t_max = c.number(seg["t_max"], (*at, "t_max"), *TEMP_RANGE, "degC")
        # Compared as the float32 the firmware holds, the rule of station.export.firmware.blob.
        if not np.float32(t_min) < np.float32(t_max):
            raise c.fail((*at, "t_max"), f"t_min {t_min:g} degC must be below t_max {t_max:g} degC")
        if previous_max is not None and np.float32(t_min) < np.float32(previous_max):
            raise c.fail((*at, "t_min"), f"segment {i} starts at {t_min:g} degC, before the previous one "
                         f"ends ({previous_max:g} degC); segments must be in increasing order")
        c.array(seg["coeffs"], (*at, "coeffs"), (3, len(TERMS)), COEFF_LIMIT,
                f"{unit} per degC^k (degC/s)^l")
        previous_max = t_max
    if triad.get("temp_sensitivity_sd") is not None:
        c.array(triad["temp_sensitivity_sd"], (*keys, "temp_sensitivity_sd"), (3,), COEFF_LIMIT,
                f"{unit} per degC", nullable=True)
        _not_negative(c, triad["temp_sensitivity_sd"], (*keys, "temp_sensitivity_sd"))


def _noise(c: _Checker, value: Any) -> None:
    section = c.mapping(value, ("noise",))
    for sensor in ("accel", "gyro"):
        if section.get(sensor) is None:
            continue
        keys: Keys = ("noise", sensor)
        terms = c.mapping(section[sensor], keys)
        for term in ("N", "K", "B", "Q", "R"):
            if terms.get(term) is not None:
                c.array(terms[term], (*keys, term), (3,), NOISE_LIMIT, "(the term's SI unit)", nullable=True)
                _not_negative(c, terms[term], (*keys, term))
        if terms.get("stddev") is not None:
            for term, sd in c.mapping(terms["stddev"], (*keys, "stddev")).items():
                c.numbers(sd, (*keys, "stddev", term))
        gauss_markov = terms.get("GM")
        if gauss_markov is not None:
            if not isinstance(gauss_markov, list) or len(gauss_markov) != 3:
                raise c.fail((*keys, "GM"), f"must be 3 lists (per axis) of [sigma, tau_c] pairs, not "
                             f"{_shown(gauss_markov)}")
            for axis, processes in enumerate(gauss_markov):
                if processes is None:
                    continue
                if not isinstance(processes, list):
                    raise c.fail((*keys, "GM", axis), f"must be a list of [sigma, tau_c] pairs, not "
                                 f"{_shown(processes)}")
                for k, pair in enumerate(processes):
                    c.array(pair, (*keys, "GM", axis, k), (2,), NOISE_LIMIT, "(sigma; tau_c in s)")
                    _not_negative(c, pair, (*keys, "GM", axis, k))
        if terms.get("valid_tau") is not None:
            c.array(terms["valid_tau"], (*keys, "valid_tau"), (3, 2), 1e9, "s", nullable=True)


def _not_negative(c: _Checker, values: list[Any], keys: Keys) -> None:
    for i, v in enumerate(values):
        if v is not None and v < 0:
            raise c.fail((*keys, i), f"{v:g} is negative; a noise term is a size, at least 0")


def _mag(c: _Checker, value: Any) -> None:
    section = c.mapping(value, ("mag",))
    for key in ("matrix", "bias"):
        if key not in section:
            raise c.fail(("mag",), f"section 'mag' lacks the required key '{key}'")
    c.array(section["matrix"], ("mag", "matrix"), (3, 3), MATRIX_LIMIT, "raw per true unit")
    c.array(section["bias"], ("mag", "bias"), (3,), BIAS_LIMIT, "microtesla")
    # frame accel: a magnetometer mounted with its axes permuted has a matrix whose diagonal is not its
    # largest part, and is no less a calibration
    _invertible(c, section["matrix"], ("mag", "matrix"), diagonal=section.get("frame") != "accel")
    if "correction" in section:
        c.array(section["correction"], ("mag", "correction"), (3, 3), FLOAT32_MAX, "")
    if section.get("frame") is not None and section["frame"] not in ("accel", "sensor"):
        raise c.fail(("mag", "frame"), f"is {_shown(section['frame'])}; it is 'accel' or 'sensor'")
    if section.get("field_norm") is not None:
        c.number(section["field_norm"], ("mag", "field_norm"), 0.0, BIAS_LIMIT, "microtesla")
    if section.get("coverage") is not None:
        c.number(section["coverage"], ("mag", "coverage"), 0.0, 1.0, "(share of the sphere)")
    if section.get("residual_rms") is not None:
        c.number(section["residual_rms"], ("mag", "residual_rms"), 0.0, FLOAT32_MAX, "microtesla")
    if section.get("method") is not None:
        c.text(section["method"], ("mag", "method"))
    if section.get("stddev") is not None:
        for key, sd in c.mapping(section["stddev"], ("mag", "stddev")).items():
            c.numbers(sd, ("mag", "stddev", key))
    for key, limit in (("dip_deg", 90.0), ("alignment_deg", 180.0)):
        if section.get(key) is not None:
            c.number(section[key], ("mag", key), -limit, limit, "deg")


def _characterisation(c: _Checker, value: Any) -> None:
    section = c.mapping(value, ("characterisation",))
    if section.get("turn_ons") is not None:
        turn_ons = section["turn_ons"]
        if isinstance(turn_ons, bool) or not isinstance(turn_ons, int) or not 1 <= turn_ons <= 1_000_000:
            raise c.fail(("characterisation", "turn_ons"), f"must be a whole number of restarts, not "
                         f"{_shown(turn_ons)}")
    for key, unit in (("accel_bias_repeatability", "m/s^2"), ("gyro_bias_repeatability", "rad/s"),
                      ("gyro_scale_nonlinearity_ppm", "ppm"), ("gyro_scale_asymmetry_ppm", "ppm")):
        if section.get(key) is not None:
            c.array(section[key], ("characterisation", key), (3,), BIAS_LIMIT, unit, nullable=True)
