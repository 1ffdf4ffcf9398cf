"""The autopilots' parameter files as the exports write them, read back by the tests."""

from __future__ import annotations

from pathlib import Path


def read_px4(path: Path) -> dict[str, tuple[float, int]]:
    """A QGroundControl .params file: vehicle, component, name, value, MAV_PARAM_TYPE per line."""
    out = {}
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            continue
        vehicle, component, name, value, kind = line.split("\t")
        assert (vehicle, component) == ("1", "1")
        out[name] = (float(value), int(kind))
    return out


def px4_values(path: Path) -> dict[str, float]:
    """The values of a QGroundControl .params file (:func:`read_px4` without the types)."""
    return {name: value for name, (value, _) in read_px4(path).items()}


def read_ardupilot(path: Path) -> dict[str, float]:
    """An ArduPilot .param file: NAME,VALUE per line."""
    out = {}
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            name, value = line.split(",")
            out[name] = float(value)
    return out
