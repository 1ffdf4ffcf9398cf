"""The ``imus`` section: several IMUs of one board in one parameter file (``shared/specs/params-file.md``).

The top-level ``accel`` and ``gyro`` stay the first IMU's, so every reader of a one-IMU file reads a
board's file as the first IMU's. ``imus`` lists every IMU, the first too: its entry names it (instance,
device ids) and points at the top-level sections; each other entry holds its own ``accel`` and ``gyro``
(the same keys), optionally its ``thermal``, and its rotation relative to the first with the 1-sigma::

    v_first = rotation_to_first @ v_this        (each IMU's vectors in its own axes)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import ThermalModel
from station.export.params.file import ParamsFile, sensor_from_dict, sensor_to_dict, to_plain

IMUS = "imus"


@dataclass
class BoardEntry:
    """One IMU of the board as the parameter file holds it (the first: the top-level sections)."""

    instance: int
    device_id: int | None
    gyro_device_id: int | None
    accel: SensorCalibration | None
    gyro: SensorCalibration | None
    thermal: ThermalModel | None
    rotation_to_first: np.ndarray  # (3, 3); identity for the first
    rotation_sigma: np.ndarray | None  # (3,) rad about the first's x, y, z; None for the first
    first: bool

    @property
    def rotation_angle_deg(self) -> float:
        """The angle of the rotation to the first, degrees."""
        cos = (np.trace(self.rotation_to_first) - 1.0) / 2.0
        return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _int_or_none(value: Any) -> int | None:
    return None if value is None else int(value)


def device_ids(device: dict[str, Any]) -> dict[str, int]:
    """``device_id`` and ``gyro_device_id`` from a capture's device info (a log's accel/gyro device ids)."""
    out = {}
    accel, gyro = device.get("accel_device_id"), device.get("gyro_device_id")
    if accel is not None:
        out["device_id"] = int(accel)
    if gyro is not None and gyro != accel:
        out["gyro_device_id"] = int(gyro)
    return out


def first_entry(instance: int, device: dict[str, Any]) -> dict[str, Any]:
    """The first IMU's entry: its instance and device ids (its sections are the top-level ones)."""
    return {"instance": int(instance), **device_ids(device)}


def other_entry(instance: int, device: dict[str, Any], accel: SensorCalibration | None,
                gyro: SensorCalibration | None, to_first: np.ndarray, sigma: np.ndarray,
                details: dict[str, Any] | None = None) -> dict[str, Any]:
    """An entry of an IMU after the first: its sections and its rotation to the first with the 1-sigma.

    Parameters
    ----------
    instance : int
    device : dict
        The capture's device info (device ids).
    accel, gyro : SensorCalibration or None
    to_first : ndarray, (3, 3)
        v_first = to_first @ v_this.
    sigma : ndarray, (3,)
        1-sigma of the small angles about the first's x, y, z axes, rad.
    details : dict, optional
        More keys (the residuals, what the rotation rests on).

    Returns
    -------
    dict
    """
    out: dict[str, Any] = {"instance": int(instance), **device_ids(device)}
    if accel is not None:
        out["accel"] = sensor_to_dict(accel)
    if gyro is not None:
        out["gyro"] = sensor_to_dict(gyro)
    out["rotation_to_first"] = to_plain(np.asarray(to_first, float))
    out["rotation_sigma"] = to_plain(np.asarray(sigma, float))
    cos = (np.trace(to_first) - 1.0) / 2.0
    out["rotation_angle_deg"] = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    out.update(to_plain(details or {}))
    return out


def board_entries(params: ParamsFile) -> list[BoardEntry]:
    """The board's IMUs, the first with the top-level sections; empty for a one-IMU file.

    Parameters
    ----------
    params : ParamsFile
        Checked on reading (``checks._imus``).

    Returns
    -------
    list of BoardEntry
    """
    entries = params.other.get(IMUS)
    if not entries:
        return []
    out = []
    for k, entry in enumerate(entries):
        first = k == 0

        def own(name: str, entry: dict[str, Any] = entry) -> SensorCalibration | None:
            return sensor_from_dict(entry[name]) if entry.get(name) else None

        out.append(BoardEntry(
            instance=int(entry["instance"]),
            device_id=_int_or_none(entry.get("device_id")),
            gyro_device_id=_int_or_none(entry.get("gyro_device_id")),
            accel=params.accel if first else own("accel"),
            gyro=params.gyro if first else own("gyro"),
            thermal=params.thermal if first else (ThermalModel.from_dict(entry["thermal"])
                                                  if entry.get("thermal") else None),
            rotation_to_first=np.eye(3) if first else np.asarray(entry["rotation_to_first"], float),
            rotation_sigma=None if first or entry.get("rotation_sigma") is None
            else np.asarray(entry["rotation_sigma"], float),
            first=first))
    return out


def instance_params(params: ParamsFile, entry: BoardEntry) -> ParamsFile:
    """One IMU of a board file as a one-IMU parameter file (its sections at the top level), for the
    exports that write one sensor at a time."""
    if entry.first:
        return ParamsFile(device=dict(params.device), created=params.created, accel=params.accel,
                          gyro=params.gyro, thermal=params.thermal, noise=params.noise,
                          other={k: v for k, v in params.other.items() if k != IMUS})
    return ParamsFile(device=dict(params.device), created=params.created, accel=entry.accel, gyro=entry.gyro,
                      thermal=entry.thermal)
