"""``--plot`` of ``imu-station calibrate --across-temperature``: scale factor, misalignment and bias of
each triad against temperature, the soaks with their 1-sigma bars and the fitted curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from station.common.files import atomic_open
from station.engines.thermal.intrinsics import OFF_DIAGONAL_NAMES
from station.engines.thermal.intrinsics_fit import AcrossTemperature
from station.plots.thermal import UNITS as BIAS_UNITS


def plot_across_temperature(result: AcrossTemperature, path: str | Path, title: str) -> None:
    """Write a PNG: one row per triad; columns scale factor (ppm from its value at T_ref), misalignment
    (urad from T_ref) and bias, against temperature.

    Dots with bars are the soaks' estimates and 1-sigma; lines the fitted polynomials over the soaks'
    range, with their 1-sigma band.

    Parameters
    ----------
    result : AcrossTemperature
    path : str or Path
        The PNG to write (atomically).
    title : str
        The figure's title (the command that made it).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    triads = result.triads
    fig, axes = plt.subplots(len(triads), 3, figsize=(14, 4.0 * len(triads) + 0.6), squeeze=False)
    fig.subplots_adjust(left=0.07, right=0.98, top=0.88, bottom=0.09, wspace=0.32, hspace=0.45)
    temps = np.array([s.temp for s in result.soaks])
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"]
    for row, triad in enumerate(triads):
        unit, factor = BIAS_UNITS[triad]
        panels = (("scale", ("x", "y", "z"), "scale - K(T_ref) (ppm of K)"),
                  ("misalignment", OFF_DIAGONAL_NAMES, "misalignment - S(T_ref) (urad)"),
                  ("bias", ("x", "y", "z"), f"bias ({unit})"))
        for col, (q, names, label) in enumerate(panels):
            ax = axes[row, col]
            fit = result.fits[f"{triad}.{q}"]
            grid = np.linspace(fit.t_min, fit.t_max, 200)
            ref = fit.coeffs[:, 0]
            if q == "scale":
                scale, offset = 1e6 / ref, ref
            elif q == "misalignment":
                scale, offset = np.full(len(ref), 1e6), ref
            else:
                scale, offset = np.full(len(ref), factor), np.zeros(len(ref))
            values = np.array([s.values[triad][q] for s in result.soaks])
            sds = np.array([s.stddev[triad][q] for s in result.soaks])
            curve, band = fit.evaluate(grid), fit.stddev(grid)
            for c, name in enumerate(names):
                colour = colours[c % len(colours)]
                ax.errorbar(temps, (values[:, c] - offset[c]) * scale[c], yerr=sds[:, c] * np.abs(scale[c]),
                            fmt="o", ms=3, capsize=2, color=colour, label=name)
                line = (curve[:, c] - offset[c]) * scale[c]
                ax.plot(grid, line, color=colour, lw=1)
                half = band[:, c] * np.abs(scale[c])
                ax.fill_between(grid, line - half, line + half, color=colour, alpha=0.15, lw=0)
            ax.axvline(result.thermal.reference_temp, color="grey", ls=":", lw=1)
            ax.set_title(f"{triad} {q}: order {fit.order}", fontsize=9)
            ax.set_xlabel("temperature (degC)")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="best", ncol=2 if len(names) > 3 else 1)
    fig.suptitle(f"{title}\nT_ref {result.thermal.reference_temp:g} degC (dotted); soaks with 1-sigma bars, "
                 "fits with 1-sigma bands", fontsize=10)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
