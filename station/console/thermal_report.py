"""The thermal fit's report for a terminal: the ``thermal`` command and the TUI's sweep screen print it."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from protocols.units import STANDARD_GRAVITY
from station.common.text import printable

if TYPE_CHECKING:
    from station.engines.thermal.fit import ThermalFit

SCALES = {"accel": ("mg", 1e3 / STANDARD_GRAVITY), "gyro": ("deg/h", 3600.0 * 180.0 / math.pi)}
"""Unit and factor from SI of each triad's figures in the report."""


def format_report(fit: ThermalFit, calibrated: dict[str, bool]) -> str:
    """The terminal summary: one line per axis, held-out figures in mg and deg/h.

    Parameters
    ----------
    fit : ThermalFit
        The result of the thermal fit.
    calibrated : dict of str to bool
        Per triad (``accel``, ``gyro``): whether the bias was measured against a calibration
        (relative) or not (absolute).

    Returns
    -------
    str
        The report, lines joined by newlines, without a final newline.
    """
    m = fit.model
    lines = [
        f"temperature {fit.block_temp.min():.1f} .. {fit.block_temp.max():.1f} degC, dT "
        f"{fit.block_dtemp.min() * 60:.2f} .. {fit.block_dtemp.max() * 60:.2f} degC/min, "
        f"{len(fit.block_temp)} blocks of {fit.block_s:g} s, "
        f"poses {', '.join(printable(p) for p in fit.poses)}",
        f"T_ref {m.reference_temp:g} degC, dT filter ema tau {m.dtemp_filter.tau_s:g} s",
    ]
    for name, tri in fit.triads.items():
        unit, factor = SCALES[name]
        segs = ", ".join(f"[{s.t_min:.1f}, {s.t_max:.1f}]" for s in tri.bias_model.segments)
        basis = "relative to the calibration in PARAMS" if calibrated[name] else "absolute (no calibration)"
        lines.append(f"{name}: segments {segs} degC; bias {basis}")
        for j, a in enumerate(tri.axes):
            by_seg = " | ".join(f"{b * factor:.3g}->{c * factor:.3g}" for b, c in
                                zip(a.cv_rms_before_by_segment, a.cv_rms_after_by_segment, strict=True))
            extra = f", scale {a.scale_per_degc * 1e6:+.1f} ppm/degC" if a.scale_per_degc is not None else ""
            per_segment = f" (segments {by_seg})" if len(tri.bias_model.segments) > 1 else ""
            lines.append(f"  {'xyz'[j]}: {'+'.join(a.terms):<22} held-out RMS "
                         f"{a.cv_rms_before * factor:.4g} -> {a.cv_rms_after * factor:.4g} {unit}"
                         + per_segment + extra)
        slope = tri.bias_model.temperature_sensitivity(m.reference_temp)
        lines.append("  bias temperature sensitivity " + ", ".join(
            f"{'xyz'[j]} {slope[j] * factor:+.4g} +/- {a.temp_sensitivity_sd * factor:.2g}"
            for j, a in enumerate(tri.axes)) + f" {unit}/degC (1-sigma)")
    return "\n".join(lines)
