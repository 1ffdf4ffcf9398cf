"""Which sections a parameter file holds, and the two that ride inside others' keys: the ``mag``
section (kept by :class:`ParamsFile` as read, in ``other``) and the gyro's ``g_sensitivity``.

Every export writes what it can of any subset of sections and says what it left out
(``shared/specs/params-file.md``); these helpers are how each format asks.
"""

from __future__ import annotations

import numpy as np

from station.engines.shared.sensor_model import SensorCalibration
from station.export.params.file import ParamsFile, sensor_from_dict

MAG = "mag"
G_SENSITIVITY = "g_sensitivity"
DEFAULT_FIELD_UT = 50.0
"""The field magnitude (microtesla) an export assumes where the ``mag`` section does not say
(a mid-latitude Earth field)."""


def mag_calibration(params: ParamsFile) -> SensorCalibration | None:
    """The ``mag`` section as a :class:`SensorCalibration` (matrix, bias; frame, field_norm,
    coverage in ``extra``), or None without one."""
    section = params.other.get(MAG)
    return sensor_from_dict(section) if section else None


def g_sensitivity(params: ParamsFile) -> np.ndarray | None:
    """The gyro's g-sensitivity G (3, 3), rad/s per m/s^2, or None where the file has none."""
    if params.gyro is None or params.gyro.extra.get(G_SENSITIVITY) is None:
        return None
    return np.asarray(params.gyro.extra[G_SENSITIVITY], float).reshape(3, 3)


def field_norm(mag: SensorCalibration) -> float:
    """The field magnitude the ``mag`` section is scaled to (microtesla), or the default."""
    value = mag.extra.get("field_norm")
    return float(value) if value else DEFAULT_FIELD_UT


def present(params: ParamsFile) -> list[str]:
    """The sections the file holds, in the spec's order, then any other section by name."""
    typed = [name for name in ("accel", "gyro", "thermal", "noise") if getattr(params, name) is not None]
    if params.thermal is not None and params.thermal.accel is None and params.thermal.gyro is None:
        typed.remove("thermal")  # a thermal section without a model holds nothing to carry
    return typed + [name for name, value in params.other.items() if value is not None]


def left_out(params: ParamsFile, carried: tuple[str, ...], fmt: str) -> str | None:
    """The note saying which of the file's sections format ``fmt`` does not carry, or None.

    Parameters
    ----------
    params : ParamsFile
        The parameter file exported.
    carried : tuple of str
        The sections the format writes.
    fmt : str
        The format's name, for the note.

    Returns
    -------
    str or None
        E.g. ``px4 does not carry the file's noise, characterisation sections: not written``.
    """
    missing = [name for name in present(params) if name not in carried]
    if not missing:
        return None
    plural = "s" if len(missing) > 1 else ""
    return f"{fmt} does not carry the file's {', '.join(missing)} section{plural}: not written"
