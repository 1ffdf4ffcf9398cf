"""The parameter file, schema ``imu-station/params/1`` (``shared/specs/params-file.md``).

Every engine command writes its own section into the file named by ``-o`` and keeps the
sections already there; writes are atomic. Readers refuse a schema they do not know.

A file holds one unit: :func:`merge_sections` (and :func:`open_for_unit`, for a command that checks
before a long computation) refuse to merge a second unit's results into it, or results that name no
unit into a file that names one, and record in ``sources`` which capture (path and SHA-256) and
unit each section came from.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from station.common.files import atomic_write_text, sha256_file
from station.common.yaml_file import read_yaml
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import ThermalModel
from station.errors import InputFileError, StationError
from station.export.params.checks import DEVICE_IDS, UNITS, Locate, check_params

SCHEMA = "imu-station/params/1"
SENSOR_KEYS = ("matrix", "bias", "scale", "misalignment", "correction", "method", "residual_rms", "stddev")
SECTIONS = ("accel", "gyro", "thermal", "noise")
"""The sections :class:`ParamsFile` holds typed; any other section name is kept in ``other``."""
REPLACE_OPTION = "--replace"
"""The option of the commands that write a parameter file (calibrate, allan, thermal, characterise) that
starts it afresh."""
SERIAL_OPTION = "--serial"
"""Their option that names the unit of a capture that names none (:func:`name_unit`)."""
# libyaml's emitter with PyYAML's safe representer: 4x faster than yaml.safe_dump, the same values read
# back, the same text but where a long escaped string wraps (PyYAML built without libyaml: the Python one)
_SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def utc_now() -> str:
    """The current UTC time as ``YYYY-MM-DDTHH:MM:SSZ``."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def to_plain(value: Any) -> Any:
    """numpy arrays and scalars to lists and floats, recursively, so YAML and JSON stay plain."""
    if isinstance(value, dict):
        return {str(k): to_plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def sensor_to_dict(cal: SensorCalibration) -> dict[str, Any]:
    """The ``accel``/``gyro`` section of one triad (``shared/specs/params-file.md``)."""
    out = {
        "matrix": cal.matrix,
        "bias": cal.bias,
        "scale": cal.scale,
        "misalignment": cal.misalignment,
        "correction": cal.correction,
        "method": cal.method,
        "residual_rms": cal.residual_rms,
        "stddev": cal.stddev,
    }
    out.update(cal.extra)
    return to_plain(out)


def sensor_from_dict(d: dict[str, Any]) -> SensorCalibration:
    """A sensor section already checked by ``check_params``."""
    extra = {k: v for k, v in d.items() if k not in SENSOR_KEYS}
    return SensorCalibration(
        np.asarray(d["matrix"], dtype=float), np.asarray(d["bias"], dtype=float),
        method=str(d.get("method") or ""), residual_rms=d.get("residual_rms"), stddev=d.get("stddev") or {},
        extra=extra,
    )


def gauss_markov_of(sensor_noise: dict[str, Any]) -> list[list[list[float]]] | None:
    """Per axis the [sigma, tau_c] pairs of a ``noise.gyro`` / ``noise.accel`` mapping, or None.

    Reads the spec's ``GM`` key, and files written before it: ``gauss_markov: {sigma: [..],
    correlation_time_s: [..]}`` (one process per axis, null where none).
    """
    if sensor_noise.get("GM") is not None:
        return [list(p or []) for p in sensor_noise["GM"]]
    old = sensor_noise.get("gauss_markov")
    if not old:
        return None
    return [[] if s is None or t is None else [[s, t]]
            for s, t in zip(old.get("sigma") or [], old.get("correlation_time_s") or [], strict=False)]


@dataclass
class ParamsFile:
    """A unit's parameter file: known sections typed, every other section kept as it was read."""

    device: dict[str, Any] = field(default_factory=dict)
    created: str = field(default_factory=utc_now)
    accel: SensorCalibration | None = None
    gyro: SensorCalibration | None = None
    thermal: ThermalModel | None = None
    noise: dict[str, Any] | None = None
    sources: dict[str, dict[str, Any]] = field(default_factory=dict)
    other: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The whole parameter file as plain data, sections in the spec's order."""
        out: dict[str, Any] = {
            "schema": SCHEMA,
            "device": self.device,
            "created": self.created,
            "units": dict(UNITS),
        }
        if self.accel is not None:
            out["accel"] = sensor_to_dict(self.accel)
        if self.gyro is not None:
            out["gyro"] = sensor_to_dict(self.gyro)
        if self.thermal is not None:
            out["thermal"] = self.thermal.to_dict()
        if self.noise is not None:
            out["noise"] = self.noise
        out.update(self.other)
        if self.sources:
            out["sources"] = self.sources
        return to_plain(out)

    def dump(self) -> str:
        """The parameter file as YAML text."""
        return yaml.dump(self.to_dict(), Dumper=_SAFE_DUMPER, sort_keys=False, default_flow_style=None,
                         width=120)

    def save(self, path: str | Path) -> None:
        """Write the parameter file to ``path`` atomically."""
        atomic_write_text(path, self.dump())

    @classmethod
    def from_dict(cls, d: Any, path: str | Path = "<params>", locate: Locate | None = None) -> ParamsFile:
        """A parameter file from its YAML document, checked against the schema (``check_params``).

        ``locate`` maps a key path to its line in the file, for the messages.
        """
        schema = d.get("schema") if isinstance(d, dict) else None
        if isinstance(d, dict) and schema != SCHEMA:
            line = locate(("schema",)) if locate is not None else None
            raise InputFileError(
                path, f"schema is {schema!r}, this station reads {SCHEMA!r}; "
                "write the file with this station or upgrade it", line=line, column="schema")
        check_params(d, path, locate)
        known = {"schema", "device", "created", "units", "sources", *SECTIONS}
        return cls(
            device=dict(d.get("device") or {}),
            created=str(d.get("created", utc_now())),
            accel=sensor_from_dict(d["accel"]) if d.get("accel") else None,
            gyro=sensor_from_dict(d["gyro"]) if d.get("gyro") else None,
            thermal=ThermalModel.from_dict(d["thermal"]) if d.get("thermal") else None,
            noise=d.get("noise"),
            sources={str(k): dict(v) for k, v in (d.get("sources") or {}).items()},
            other={k: v for k, v in d.items() if k not in known},
        )

    @classmethod
    def load(cls, path: str | Path) -> ParamsFile:
        """Read and check a parameter file (bounded in size and alias expansion:
        ``station.common.yaml_file``)."""
        document = read_yaml(path, "does not exist; give the parameter file written by "
                             "'imu-station calibrate', 'allan' or 'thermal'")
        return cls.from_dict(document.construct(), path, document.line_of)

    @classmethod
    def load_or_new(cls, path: str | Path) -> ParamsFile:
        """The file at ``path`` if it exists (so its sections are kept), else an empty one."""
        return cls.load(path) if Path(path).exists() else cls()

    def update_device(self, info: dict[str, Any] | None) -> None:
        """Record what is known of the unit (serial, model, firmware, and an autopilot log's IMU device ids,
        which the PX4 and ArduPilot exports bind their parameters to) without losing known keys."""
        for key in ("serial", "model", "firmware"):
            if info and info.get(key) is not None:
                self.device[key] = str(info[key])
        for key in DEVICE_IDS:
            if info and info.get(key) is not None:
                self.device[key] = int(info[key])

    def set_section(self, name: str, value: Any, source: dict[str, Any] | None = None) -> None:
        """Write section ``name`` and record where it came from (``source``; None forgets the old one).

        Parameters
        ----------
        name : str
            ``accel``, ``gyro``, ``thermal``, ``noise`` or another section kept as read.
        value : Any
            The section (a ``SensorCalibration``, a ``ThermalModel``, a mapping).
        source : dict, optional
            What :func:`section_source` returns for the capture the section was computed from.
        """
        if name in SECTIONS:
            setattr(self, name, value)
        else:
            self.other[name] = value
        if source:
            self.sources[name] = dict(source)
        else:
            self.sources.pop(name, None)


class UnitMismatchError(StationError):
    """A parameter file holds another unit's results than the ones about to be merged into it (exit 4)."""


def _unit_name(device: dict[str, Any]) -> str:
    model = device.get("model")
    return f"{device['serial']}" + (f" (model {model})" if model is not None else "")


def unit_conflict(held: dict[str, Any], device: dict[str, Any] | None) -> str | None:
    """How two descriptions of a unit show two different units, or None when they may be the same.

    Serials decide; models too where both are known. A side that does not know its serial
    cannot show a difference (a CSV capture without a header, a unit that does not report one).

    Parameters
    ----------
    held : dict
        The ``device`` of the parameter file.
    device : dict or None
        What is known of the unit whose results are to be merged.

    Returns
    -------
    str or None
        E.g. ``serial SN-A (model X) vs SN-B (model X)``.
    """
    device = device or {}
    serial_a, serial_b = held.get("serial"), device.get("serial")
    if serial_a is None or serial_b is None:
        return None
    model_a, model_b = held.get("model"), device.get("model")
    if str(serial_a) != str(serial_b) or (model_a is not None and model_b is not None
                                          and str(model_a) != str(model_b)):
        return f"{_unit_name(held)} vs {_unit_name(device)}"
    return None


def name_unit(device: dict[str, Any] | None, serial: str | None) -> dict[str, Any]:
    """The unit's info with the serial the operator gave (``--serial``) for a capture that names none.

    Parameters
    ----------
    device : dict or None
        What the capture says of its unit (its metadata, the HDF5 file's ``device``).
    serial : str or None
        The operator's ``--serial``; None keeps ``device`` as it is.

    Returns
    -------
    dict
        A copy of ``device``, with ``serial`` when given.

    Raises
    ------
    UnitMismatchError
        The capture names another serial than ``serial`` (exit 4): the operator's word does not
        overrule the unit's own.
    """
    named = dict(device or {})
    if serial is None:
        return named
    if named.get("serial") is not None and str(named["serial"]) != serial:
        raise UnitMismatchError(f"{SERIAL_OPTION} {serial}, but the capture names unit {_unit_name(named)}: "
                                f"give the capture of unit {serial}, or leave {SERIAL_OPTION} out")
    named["serial"] = serial
    return named


def open_for_unit(path: str | Path, device: dict[str, Any] | None, *, replace: bool = False,
                  option: str = REPLACE_OPTION, unit_pending: bool = False) -> ParamsFile:
    """The parameter file to merge one unit's results into, refusing a file of another unit.

    A file that names a unit takes the results of that unit only: results of a unit whose serial is
    unknown (a capture CSV without metadata, a unit that does not report its serial) are refused
    too, until the operator names it (``--serial``, see :func:`name_unit`) or starts afresh.

    Parameters
    ----------
    path : str or Path
        The parameter file; a missing one gives an empty :class:`ParamsFile`.
    device : dict or None
        What is known of the unit (serial, model, firmware).
    replace : bool
        Start afresh: the existing file is neither read nor kept (the operator asked).
    option : str
        How the operator says ``replace``, for the message (``--replace``, a TUI key).
    unit_pending : bool
        The unit is not known yet (it is about to be recorded, and will say who it is): only a
        serial ``device`` gives is checked, and a file that cannot be read is refused.

    Returns
    -------
    ParamsFile
        The file's sections, or none; nothing is written yet.

    Raises
    ------
    UnitMismatchError
        The file holds another unit's results, or names a unit and ``device`` none (exit 4),
        naming the file and the units.
    InputFileError
        The existing file cannot be read or breaks the schema.
    """
    if replace or not Path(path).exists():
        return ParamsFile()
    params = ParamsFile.load(path)
    held = dict(params.device)
    if "serial" not in held:
        # an older file has no device serial but its sections may say whose they are
        serials = {str(s["serial"]) for s in params.sources.values() if s.get("serial") is not None}
        if len(serials) == 1:
            held["serial"] = serials.pop()
    conflict = unit_conflict(held, device)
    if conflict is not None:
        raise UnitMismatchError(
            f"{path} holds the results of unit {_unit_name(held)}, these are of unit "
            f"{_unit_name(device or {})}: one parameter file holds one unit; write to another file, "
            f"or give {option} to start {path} afresh (its sections are dropped)")
    if not unit_pending and held.get("serial") is not None and (device or {}).get("serial") is None:
        # the commands say --serial; a TUI names its own key and has its unit's serial to give
        name = f"{SERIAL_OPTION} {held['serial']} if it is that unit, or " if option == REPLACE_OPTION else ""
        raise UnitMismatchError(
            f"{path} holds the results of unit {_unit_name(held)}, and these name no unit (a capture CSV "
            f"without '# serial:' metadata, a unit that does not report its serial): give {name}{option} "
            f"to start {path} afresh (its sections are dropped), or write to another file")
    return params


def section_source(capture: str | Path | None, device: dict[str, Any] | None) -> dict[str, Any]:
    """Where a section came from: the capture file (path and SHA-256) and the unit, for ``sources``.

    Parameters
    ----------
    capture : str, Path or None
        The capture file the section was computed from; None (or not a regular file: a serial
        port, standard input) records no path or checksum.
    device : dict or None
        What is known of the unit.

    Returns
    -------
    dict
        ``capture``, ``sha256``, ``serial``, ``model`` where known, and ``written`` (UTC).
    """
    out: dict[str, Any] = {}
    if capture is not None and Path(capture).is_file():
        out["capture"] = str(capture)
        out["sha256"] = sha256_file(capture)
    for key in ("serial", "model"):
        if device and device.get(key) is not None:
            out[key] = str(device[key])
    out["written"] = utc_now()
    return out


def merge_sections(path: str | Path, device: dict[str, Any] | None, sections: dict[str, Any], *,
                   capture: str | Path | None = None, replace: bool = False,
                   option: str = REPLACE_OPTION) -> ParamsFile:
    """Merge one unit's ``sections`` into the parameter file at ``path``, refusing another unit's file.

    The one way the commands and the TUI write results: the file's other sections are kept
    (unless ``replace``), the device is recorded, each section written records its source.

    Parameters
    ----------
    path : str or Path
        The parameter file (created when missing).
    device : dict or None
        What is known of the unit (serial, model, firmware).
    sections : dict
        Section name to value; a value of None leaves that section as it is.
    capture : str, Path or None
        The capture file the sections were computed from (see :func:`section_source`).
    replace : bool
        Start the file afresh, dropping its sections (see :func:`open_for_unit`).
    option : str
        How the operator says ``replace``, for the refusal's message.

    Returns
    -------
    ParamsFile
        The file as written.

    Raises
    ------
    UnitMismatchError
        The file holds another unit's results; it is left untouched (exit 4).
    StationError
        The existing file cannot be read, or the new one cannot be written.
    """
    params = open_for_unit(path, device, replace=replace, option=option)
    params.update_device(device)
    source = section_source(capture, device)
    for name, value in sections.items():
        if value is not None:
            params.set_section(name, value, source)
    params.save(path)
    return params
