"""The parameter file's ``mag`` section (``shared/specs/params-file.md``) from a magnetometer fit.

Forward model raw = matrix @ true + bias (microtesla); ``correction`` = inverse(matrix); ``frame``
``accel`` when the rotation to the accelerometer was solved, ``sensor`` otherwise; ``field_norm`` the
|true| the fit is scaled to; ``residual_rms`` of |true| - field_norm; ``coverage`` the share of the
sphere of field directions visited; ``stddev`` the 1-sigma. Beyond the spec's keys: ``method``,
``field_source`` (where field_norm came from), ``dip_deg`` and ``alignment_deg`` (the angle of the
rotation between the accelerometer's and the magnetometer's axes) where solved.

:class:`~station.export.params.file.ParamsFile` keeps the section as read (in ``other``), and
``station.export.params.sections.mag_calibration`` reads it back as a ``SensorCalibration``; the schema
check is ``params_check._mag``.
"""

from __future__ import annotations

from typing import Any

from station.engines.magnetometer.calibration import MagCalibration
from station.export.params.file import to_plain


def mag_section(cal: MagCalibration, field_source: str) -> dict[str, Any]:
    """The ``mag`` section of a fit, plain data ready for YAML.

    Parameters
    ----------
    cal : MagCalibration
        The fit.
    field_source : str
        Where ``field_norm`` came from: ``given``, the geomagnetic model's description, or ``data``.

    Returns
    -------
    dict
        The section, keys in the spec's order, then the extra ones.
    """
    out: dict[str, Any] = {
        "matrix": cal.matrix,
        "bias": cal.bias,
        "correction": cal.correction,
        "frame": cal.frame,
        "field_norm": cal.field_norm,
        "residual_rms": cal.residual_rms,
        "coverage": round(cal.coverage.share, 4),
        "stddev": dict(cal.stddev),
        "method": cal.method,
        "field_source": field_source,
    }
    if cal.dip_deg is not None:
        out["dip_deg"] = cal.dip_deg
        out["alignment_deg"] = cal.alignment_deg()
    return to_plain(out)
