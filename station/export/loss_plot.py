"""``--plot`` of ``imu-station export --format px4|ardupilot``: the offset the autopilot subtracts
against ours, across temperature, so what the single cubic loses is seen where it is lost."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from protocols.units import STANDARD_GRAVITY
from station.export.autopilot import AutopilotExport, reference_temp, thermal_range
from station.export.params_file import ParamsFile
from station.files import atomic_open

UNITS = {"accel": ("mg", 1e3 / STANDARD_GRAVITY), "gyro": ("deg/h", 3600.0 * 180.0 / np.pi)}
DTEMP_STEPS = 9


def plot_losses(params: ParamsFile, result: AutopilotExport, path: str | Path) -> None:
    """Write a PNG: one row per triad, one column per axis.

    Black: the bias our model removes, b + B(T, dT = 0); grey band: B over the dT clamp range
    (what the dT terms add while the unit heats or cools); orange dashed: what the target
    subtracts. Outside the calibrated range both clamp.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if result.offsets is None:
        raise ValueError("the export carries no offset function to plot")
    span = thermal_range(params)
    t_ref = reference_temp(params)
    lo, hi = span if span is not None else (t_ref - 20.0, t_ref + 20.0)
    temp = np.linspace(lo - 5.0, hi + 5.0, 400)
    theirs = dict(zip(("accel", "gyro"), result.offsets(temp), strict=True))
    triads = [name for name in ("accel", "gyro") if getattr(params, name) is not None]
    fig, axes = plt.subplots(len(triads), 3, figsize=(13, 3.6 * len(triads) + 0.6), squeeze=False,
                             layout="constrained")
    for row, name in enumerate(triads):
        unit, factor = UNITS[name]
        bias = getattr(params, name).bias
        model = getattr(params.thermal, name) if params.thermal is not None else None
        ours = np.tile(bias, (len(temp), 1))
        band = None
        if model is not None:
            ours = ours + model.evaluate(temp, np.zeros_like(temp), t_ref)
            curves = [bias + model.evaluate(temp, np.full_like(temp, d), t_ref)
                      for d in np.linspace(model.dt_min, model.dt_max, DTEMP_STEPS)]
            band = (np.min(curves, axis=0), np.max(curves, axis=0))
        worst = np.max(np.abs(theirs[name] - ours), axis=0)
        for j in range(3):
            ax = axes[row, j]
            if band is not None:
                ax.fill_between(temp, band[0][:, j] * factor, band[1][:, j] * factor, color="0.85",
                                label="ours over the dT clamp")
            ax.plot(temp, ours[:, j] * factor, color="black", lw=1.5, label="ours at dT = 0")
            ax.plot(temp, theirs[name][:, j] * factor, color="tab:orange", lw=1.5, ls="--",
                    label=result.target)
            if model is not None:
                for seg in model.segments[1:]:
                    ax.axvline(seg.t_min, color="grey", ls=":", lw=1)
            # A flat offset would otherwise be drawn on a 1e-8 scale that magnifies float32 rounding.
            centre = float(np.mean(ours[:, j])) * factor
            low, high = ax.get_ylim()
            half = max(0.5 * (high - low), 0.01 * abs(centre), 0.01)
            if high - low < 2 * half:
                ax.set_ylim(centre - half, centre + half)
            ax.ticklabel_format(axis="y", useOffset=False)
            ax.set_title(f"{name} {'xyz'[j]}: largest difference {worst[j] * factor:.3g} {unit}", fontsize=9)
            ax.set_xlabel("temperature (degC)")
            ax.set_ylabel(f"offset ({unit})")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle(f"{result.target} export: offset subtracted against temperature (T_ref {t_ref:g} degC)",
                 fontsize=10)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
