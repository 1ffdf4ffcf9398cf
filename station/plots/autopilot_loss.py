"""``--plot`` of ``imu-station export --format px4|ardupilot``: the offset the autopilot subtracts
against ours, across temperature, so what the single cubic loses is seen where it is lost."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from protocols.units import STANDARD_GRAVITY
from station.common.files import atomic_open
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import ThermalModel

UNITS = {"accel": ("mg", 1e3 / STANDARD_GRAVITY), "gyro": ("deg/h", 3600.0 * 180.0 / np.pi)}
DTEMP_STEPS = 9


def plot_losses(triads: dict[str, SensorCalibration | None], thermal: ThermalModel | None,
                target: str, offsets: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                span: tuple[float, float] | None, t_ref: float, path: str | Path) -> None:
    """Write a PNG: one row per triad, one column per axis.

    Black: the bias our model removes, b + B(T, dT = 0); grey band: B over the dT clamp range
    (what the dT terms add while the unit heats or cools); orange dashed: what the target
    subtracts (``offsets(temp)``: accel and gyro, each (n, 3)). Outside the calibrated range
    (``span``, degC) both clamp.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo, hi = span if span is not None else (t_ref - 20.0, t_ref + 20.0)
    temp = np.linspace(lo - 5.0, hi + 5.0, 400)
    theirs = dict(zip(("accel", "gyro"), offsets(temp), strict=True))
    names = [name for name in ("accel", "gyro") if triads.get(name) is not None]
    fig, axes = plt.subplots(len(names), 3, figsize=(13, 3.6 * len(names) + 0.6), squeeze=False,
                             layout="constrained")
    for row, name in enumerate(names):
        unit, factor = UNITS[name]
        bias = triads[name].bias  # type: ignore[union-attr]  # names holds the triads present
        model = getattr(thermal, name) if thermal is not None else None
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
                    label=target)
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
    fig.suptitle(f"{target} export: offset subtracted against temperature (T_ref {t_ref:g} degC)",
                 fontsize=10)
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)
