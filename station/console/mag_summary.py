"""What ``imu-station calibrate --method mag`` prints: the magnetometer fit as tables (rich) or JSON."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from station.engines.magnetometer.calibration import MagCalibration
from station.export.params.file import to_plain

if TYPE_CHECKING:
    from rich.console import Console


def mag_report_dict(cal: MagCalibration, source: str, field_source: str) -> dict[str, Any]:
    """The fit as the JSON ``--json`` prints: the section's values and what the operator should know.

    Parameters
    ----------
    cal : MagCalibration
        The fit.
    source : str
        The capture file.
    field_source : str
        Where the field magnitude came from (``given``, the model, ``data``).

    Returns
    -------
    dict
        Plain data.
    """
    return to_plain({
        "source": source, "method": cal.method, "frame": cal.frame, "field_norm": cal.field_norm,
        "field_source": field_source, "matrix": cal.matrix, "bias": cal.bias, "correction": cal.correction,
        "stddev": cal.stddev, "residual_rms": cal.residual_rms, "dip_rms": cal.dip_rms,
        "dip_deg": cal.dip_deg,
        "alignment_deg": cal.alignment_deg() if cal.frame == "accel" else None,
        "coverage": cal.coverage.share, "missing_directions": list(cal.coverage.missing),
        "samples": cal.samples, "still_poses": cal.still, "start": cal.start,
        "disturbances": [{"t0": d.t0, "t1": d.t1, "peak_ut": d.peak_ut} for d in cal.disturbances],
        "warnings": cal.warnings,
    })


def _pm(value: float, sd: float | None, digits: int = 4) -> str:
    if sd is None or not np.isfinite(sd) or sd == 0:
        return f"{value:.{digits}f}"
    return f"{value:.{digits}f} ± {sd:.2g}"


def print_mag_report(cal: MagCalibration, field_source: str, console: Console) -> None:
    """Coverage, every parameter with its 1-sigma, the residuals, the disturbances left out and the
    warnings.

    Parameters
    ----------
    cal : MagCalibration
        The fit.
    field_source : str
        Where the field magnitude came from.
    console : rich.console.Console
        Where to print.
    """
    from rich.table import Table

    from station.common.text import MAX_MESSAGE
    from station.console.markup import markup_safe

    console.print(f"[bold]{cal.method}[/] (frame: {cal.frame}), forward model raw = A true + b, microtesla")
    field_sd = cal.stddev.get("field_norm")
    field_text = _pm(cal.field_norm, field_sd if isinstance(field_sd, float) else None, 3)
    console.print(f"field magnitude F = {field_text} uT ({markup_safe(field_source)})")
    console.print(f"coverage: {cal.coverage.share:.0%} of the sphere of field directions"
                  + (f"; missing: {', '.join(cal.coverage.missing[:6])}" if cal.coverage.missing else ""))
    table = Table(title="magnetometer: hard iron b and matrix A (1-sigma)")
    table.add_column("parameter")
    for axis in "xyz":
        table.add_column(axis, justify="right")
    bias_sd = np.asarray(cal.stddev["bias"])
    matrix_sd = np.asarray(cal.stddev["matrix"])
    table.add_row("hard iron b (uT)", *[_pm(cal.bias[i], bias_sd[i], 3) for i in range(3)])
    for i, row in enumerate("xyz"):
        table.add_row(f"A, row {row}", *[_pm(cal.matrix[i, j], matrix_sd[i, j], 5) for j in range(3)])
    console.print(table)
    if cal.frame == "accel":
        align_sd = np.asarray(cal.stddev["alignment_deg"])
        dip_sd = cal.stddev["dip_deg"]
        console.print(f"rotation to the accelerometer: {cal.alignment_deg():.3f} deg (1-sigma per axis "
                      f"{', '.join(f'{v:.2g}' for v in align_sd)} deg); dip "
                      f"{_pm(float(cal.dip_deg or 0.0), float(np.asarray(dip_sd)), 3)} deg")
    dip_text = "" if cal.dip_rms is None else f"; dip {cal.dip_rms:.3g} uT RMS over {cal.still} still poses"
    console.print(f"residuals: |true| - F {cal.residual_rms:.3g} uT RMS over {cal.samples} samples{dip_text}")
    for w in cal.warnings:
        console.print(f"[yellow]warning:[/] {markup_safe(w, MAX_MESSAGE)}")
