"""The parameter file, schema ``imu-station/params/1`` (``shared/specs/params-file.md``).

Every engine command writes its own section into the file named by ``-o`` and keeps the
sections already there; writes are atomic. Readers refuse a schema they do not know.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from station.engines.sensor_model import SensorCalibration
from station.engines.thermal_model import ThermalModel
from station.errors import InputFileError
from station.export.params_check import UNITS, Locate, check_params
from station.files import atomic_write_text
from station.yaml_file import read_yaml

SCHEMA = "imu-station/params/1"
SENSOR_KEYS = ("matrix", "bias", "scale", "misalignment", "correction", "method", "residual_rms", "stddev")


def utc_now() -> str:
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


@dataclass
class ParamsFile:
    """A unit's parameter file: known sections typed, every other section kept as it was read."""

    device: dict[str, Any] = field(default_factory=dict)
    created: str = field(default_factory=utc_now)
    accel: SensorCalibration | None = None
    gyro: SensorCalibration | None = None
    thermal: ThermalModel | None = None
    noise: dict[str, Any] | None = None
    other: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
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
        return to_plain(out)

    def dump(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None, width=120)

    def save(self, path: str | Path) -> None:
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
        known = {"schema", "device", "created", "units", "accel", "gyro", "thermal", "noise"}
        return cls(
            device=dict(d.get("device") or {}),
            created=str(d.get("created", utc_now())),
            accel=sensor_from_dict(d["accel"]) if d.get("accel") else None,
            gyro=sensor_from_dict(d["gyro"]) if d.get("gyro") else None,
            thermal=ThermalModel.from_dict(d["thermal"]) if d.get("thermal") else None,
            noise=d.get("noise"),
            other={k: v for k, v in d.items() if k not in known},
        )

    @classmethod
    def load(cls, path: str | Path) -> ParamsFile:
        """Read and check a parameter file (bounded in size and alias expansion: ``station.yaml_file``)."""
        document = read_yaml(path, "does not exist; give the parameter file written by "
                             "'imu-station calibrate', 'allan' or 'thermal'")
        return cls.from_dict(document.construct(), path, document.line_of)

    @classmethod
    def load_or_new(cls, path: str | Path) -> ParamsFile:
        """The file at ``path`` if it exists (so its sections are kept), else an empty one."""
        return cls.load(path) if Path(path).exists() else cls()

    def update_device(self, info: dict[str, Any] | None) -> None:
        """Record what is known of the unit (serial, model, firmware) without losing known keys."""
        for key in ("serial", "model", "firmware"):
            if info and info.get(key) is not None:
                self.device[key] = str(info[key])
