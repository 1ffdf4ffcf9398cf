"""What ``imu-station calibrate --across-temperature`` prints: each soak's estimates, the fitted curves'
orders and the figures people quote (scale factor ppm/degC, misalignment change in urad, bias per
degC), as rich tables or JSON."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from station.console.thermal_report import SCALES
from station.engines.thermal.intrinsics import OFF_DIAGONAL_NAMES
from station.engines.thermal.intrinsics_fit import AcrossTemperature
from station.export.params.file import to_plain

if TYPE_CHECKING:
    from rich.console import Console

BIAS_UNITS = SCALES
"""Unit and factor from SI of each triad's bias in the tables: the thermal report's."""


def _pm(value: float, sd: float, digits: int = 1) -> str:
    if not np.isfinite(sd) or sd == 0:
        return f"{value:+.{digits}f}"
    return f"{value:+.{digits}f} ± {sd:.0f}" if sd >= 10 else f"{value:+.{digits}f} ± {sd:.2g}"


def across_dict(result: AcrossTemperature, sources: list[str]) -> dict[str, Any]:
    """The result as ``--json`` prints it: reference, orders and CV scores, figures, every soak.

    Parameters
    ----------
    result : AcrossTemperature
    sources : list of str
        The capture files, in the order given.

    Returns
    -------
    dict
        Plain data (SI units, figures in ppm/degC and urad as named).
    """
    figures: dict[str, Any] = {}
    for triad in result.triads:
        tc, tc_sd = result.scale_tc_ppm(triad)
        figures[triad] = {
            "scale_tc_ppm_per_degc": tc, "scale_tc_ppm_per_degc_stddev": tc_sd,
            "misalignment_change_urad": dict(zip(OFF_DIAGONAL_NAMES, result.misalignment_change_urad(triad),
                                                 strict=True)),
            "bias_per_degc": result.bias_sensitivity(triad),
        }
    return to_plain({
        "sources": sources,
        "reference_temp": result.thermal.reference_temp, "reference_reason": result.reference_reason,
        "orders": result.orders, "cv_scores": {k: f.cv_scores for k, f in result.fits.items()},
        "figures": figures,
        "soaks": [{"label": s.label, "temp": s.temp, "values": s.values, "stddev": s.stddev}
                  for s in result.soaks],
        "warnings": result.warnings,
    })


def print_across(result: AcrossTemperature, console: Console) -> None:
    """Per triad a table of the soaks (scale and misalignment as changes from T_ref, bias), the orders
    the cross-validation chose, and the figures.

    Parameters
    ----------
    result : AcrossTemperature
    console : rich.console.Console
        Where to print.
    """
    from rich.table import Table

    from station.common.text import MAX_MESSAGE
    from station.console.markup import markup_safe

    t_ref = result.thermal.reference_temp
    console.print(f"[bold]calibration across temperature[/]: {len(result.soaks)} soaks, "
                  f"{result.soaks[0].temp:.1f} to {result.soaks[-1].temp:.1f} degC; T_ref {t_ref:g} degC, "
                  f"{markup_safe(result.reference_reason)}")
    for triad in result.triads:
        unit, factor = BIAS_UNITS[triad]
        k_ref = result.fits[f"{triad}.scale"].coeffs[:, 0]
        s_ref = result.fits[f"{triad}.misalignment"].coeffs[:, 0]
        table = Table(title=f"{triad} at each soak (1-sigma); scale and misalignment as changes from T_ref")
        table.add_column("soak")
        table.add_column("T (degC)", justify="right")
        for axis in "xyz":
            table.add_column(f"scale {axis} (ppm)", justify="right")
        table.add_column("largest misalignment change (urad)", justify="right")
        for axis in "xyz":
            table.add_column(f"bias {axis} ({unit})", justify="right")
        for soak in result.soaks:
            v, sd = soak.values[triad], soak.stddev[triad]
            scale = [_pm((v["scale"][i] / k_ref[i] - 1) * 1e6, sd["scale"][i] / k_ref[i] * 1e6, 0)
                     for i in range(3)]
            change = (v["misalignment"] - s_ref) * 1e6
            c = int(np.argmax(np.abs(change)))
            mis = f"{OFF_DIAGONAL_NAMES[c]} {_pm(change[c], sd['misalignment'][c] * 1e6, 0)}"
            bias = [_pm(v["bias"][i] * factor, sd["bias"][i] * factor, 3) for i in range(3)]
            table.add_row(markup_safe(soak.label), f"{soak.temp:.2f}", *scale, mis, *bias)
        console.print(table)
        tried = len(result.fits[f"{triad}.bias"].cv_scores)
        console.print(f"{triad} polynomial orders in T by leave-one-out cross-validation (held-out chi2 "
                      f"per soak of orders {', '.join(str(p) for p in range(tried))}):")
        for q in ("bias", "scale", "misalignment"):
            scores = " ".join(f"{s:.3g}" for s in result.fits[f"{triad}.{q}"].cv_scores.values())
            console.print(f"  {q} {result.orders[f'{triad}.{q}']}  ({scores})")
        tc, tc_sd = result.scale_tc_ppm(triad)
        console.print(f"{triad} scale-factor temperature coefficient: "
                      + ", ".join(f"{'xyz'[i]} {_pm(tc[i], tc_sd[i])}" for i in range(3)) + " ppm/degC")
        change = result.misalignment_change_urad(triad)
        entries = ", ".join(f"{n} {c:.0f}" for n, c in zip(OFF_DIAGONAL_NAMES, change, strict=True))
        console.print(f"{triad} misalignment change over {result.soaks[0].temp:.0f}.."
                      f"{result.soaks[-1].temp:.0f} degC: {entries} urad")
        slope = result.bias_sensitivity(triad) * factor
        console.print(f"{triad} bias temperature sensitivity: "
                      + ", ".join(f"{'xyz'[i]} {slope[i]:+.4g}" for i in range(3)) + f" {unit}/degC")
    for w in result.warnings:
        console.print(f"[yellow]warning:[/] {markup_safe(w, MAX_MESSAGE)}")
