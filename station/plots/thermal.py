"""``--plot`` of ``imu-station thermal``: bias against temperature, the fit and its segments."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from protocols.units import STANDARD_GRAVITY
from station.common.files import atomic_open
from station.engines.thermal.fit import ThermalFit

UNITS = {"accel": ("mg", 1e3 / STANDARD_GRAVITY), "gyro": ("deg/h", 3600.0 * 180.0 / np.pi)}


def plot_thermal(fit: ThermalFit, path: str | Path) -> None:
    """Write a PNG: one row per triad, one column per axis.

    Dots are the block means of the measured bias (pose offsets and the scale-factor term
    removed, so every pose lines up), red while heating, blue while cooling, grey when steady
    (|dT| under a quarter of its 95th percentile); the line is the model at dT = 0 across the
    calibrated range, flat beyond it where firmware clamps T; dotted lines mark the joins.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    triads = list(fit.triads.values())
    fig, axes = plt.subplots(len(triads), 3, figsize=(13, 3.8 * len(triads) + 0.6), squeeze=False)
    fig.subplots_adjust(left=0.07, right=0.98, top=0.88, bottom=0.09, wspace=0.28, hspace=0.5)
    thr = 0.25 * float(np.percentile(np.abs(fit.block_dtemp), 95))
    classes = [(fit.block_dtemp > thr, "tab:red", "heating"), (fit.block_dtemp < -thr, "tab:blue", "cooling"),
               (np.abs(fit.block_dtemp) <= thr, "0.6", "steady")]
    t_ref = fit.model.reference_temp
    for row, tri in enumerate(triads):
        unit, factor = UNITS[tri.name]
        bm = tri.bias_model
        lo, hi = bm.t_min, bm.t_max
        pad = 0.08 * (hi - lo)
        grid = np.linspace(lo - pad, hi + pad, 400)
        curve = bm.evaluate(grid, np.zeros_like(grid), t_ref)
        shown = tri.bias - tri.pose_offsets[fit.block_pose] - tri.scale_part
        for j in range(3):
            ax = axes[row, j]
            for sel, colour, label in classes:
                ax.plot(fit.block_temp[sel], shown[sel, j] * factor, ".", color=colour, ms=2, label=label)
            inside = (grid >= lo) & (grid <= hi)
            ax.plot(grid[inside], curve[inside, j] * factor, color="black", lw=1.5, label="model at dT = 0")
            ax.plot(grid[grid < lo], curve[grid < lo, j] * factor, color="black", lw=1, ls="--")
            ax.plot(grid[grid > hi], curve[grid > hi, j] * factor, color="black", lw=1, ls="--",
                    label="clamped")
            for seg in bm.segments[1:]:
                ax.axvline(seg.t_min, color="grey", ls=":", lw=1)
            a = tri.axes[j]
            ax.set_title(f"{tri.name} {'xyz'[j]}: {'+'.join(a.terms)}\nheld-out RMS "
                         f"{a.cv_rms_before * factor:.3g} -> {a.cv_rms_after * factor:.3g} {unit}",
                         fontsize=9)
            ax.set_xlabel("temperature (degC)")
            ax.set_ylabel(f"bias ({unit})")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best", markerscale=4)
    title = (f"thermal fit: T_ref {t_ref:g} degC, dT filter tau {fit.model.dtemp_filter.tau_s:g} s, "
             f"poses {', '.join(fit.poses)}")
    if fit.warnings:
        title += f"  ({len(fit.warnings)} warning{'s' if len(fit.warnings) > 1 else ''})"
    fig.suptitle(title, fontsize=10)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
