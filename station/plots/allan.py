"""The Allan deviation plot: log-log curves with 68 % bands, every fitted term as its own line, their sum, the
identified terms marked and the range of tau where the model holds shaded."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from station.common.files import atomic_write_bytes
from station.engines.allan.deviation import AllanCurve
from station.engines.allan.fit import TERMS, AxisNoise, basis
from station.engines.allan.terms import SENSOR_AXES, UNITS

COLORS = ("tab:red", "tab:green", "tab:blue")
MARKERS = {"Q": "v", "N": "o", "B": "s", "K": "^", "R": "D"}
PART_STYLES = {"GM": "-.", "S": (0, (1, 3))}  # Gauss-Markov processes, sinusoids; IEEE terms dotted


def _term_point(term: str, value: float, noise: AxisNoise, tau: np.ndarray) -> tuple[float, float]:
    """Where a term is marked on its own line: N at 1 s, Q at the shortest tau, K and R at the longest,
    B at the minimum of the fitted model (its floor 0.66428 B) or at the top of a Gauss-Markov hump."""
    if term == "B" and noise.gauss_markov is not None:  # the peak of the correlated bias's hump
        return 1.89 * noise.gauss_markov[1], value * math.sqrt(2.0 * math.log(2.0) / math.pi)
    if term == "B":
        fine = np.geomspace(tau[0], tau[-1], 400)
        return float(fine[np.argmin(noise.model(fine))]), value * math.sqrt(2.0 * math.log(2.0) / math.pi)
    at = {"Q": tau[0], "N": min(max(1.0, tau[0]), tau[-1]), "K": tau[-1], "R": tau[-1]}[term]
    return float(at), float(np.sqrt(basis(np.array([at]))[0, TERMS.index(term)]) * value)


def render_png(curve: AllanCurve, noise: list[AxisNoise], title: str = "") -> bytes:
    """One panel per sensor (gyroscope, accelerometer) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    by_axis = {a.axis: a for a in noise}
    sensors = [s for s, axes in SENSOR_AXES.items() if all(a in curve.axes for a in axes)]
    fig, panels = plt.subplots(1, len(sensors), figsize=(6.5 * len(sensors), 5.2), squeeze=False)
    fine = np.geomspace(curve.tau[0], curve.tau[-1], 300)
    for ax, sensor in zip(panels[0], sensors, strict=True):
        for color, name in zip(COLORS, SENSOR_AXES[sensor], strict=True):
            j = curve.axes.index(name)
            ax.fill_between(curve.tau, curve.ci_low[:, j], curve.ci_high[:, j], color=color, alpha=0.18, lw=0)
            ax.loglog(curve.tau, curve.adev[:, j], ".-", color=color, lw=1.2, ms=3, label=f"{name}")
            fit = by_axis.get(name)
            if fit is None or (not fit.coeffs and fit.noise_model is None):
                continue
            ax.loglog(fine, fit.model(fine), "--", color=color, lw=0.9, alpha=0.8)
            if fit.noise_model is not None:
                for label, part in fit.noise_model.parts(fine).items():
                    style = PART_STYLES.get(label[:2] if label[:2] in PART_STYLES else label[:1], ":")
                    ax.loglog(fine, np.sqrt(part), ls=style, color=color, lw=0.8, alpha=0.7)
            for term, est in fit.terms.items():
                if est.value is None:
                    continue
                if fit.noise_model is None:  # the term's own line: sigma^2 = basis column * value^2
                    own = np.sqrt(basis(fine)[:, TERMS.index(term)]) * est.value
                    ax.loglog(fine, own, ":", color=color, lw=0.8, alpha=0.7)
                point = _term_point(term, est.value, fit, curve.tau)
                ax.loglog(*point, MARKERS[term], color=color, mfc="white", ms=7, mew=1.5)
        valid = [model.valid_tau for a in SENSOR_AXES[sensor]
                 if a in by_axis and (model := by_axis[a].noise_model) is not None]
        if valid:
            ax.axvspan(max(v[0] for v in valid), min(v[1] for v in valid), color="gold", alpha=0.10, lw=0)
        unit = "rad/s" if sensor == "gyro" else "m/s$^2$"
        ax.set_title(f"{'gyroscope' if sensor == 'gyro' else 'accelerometer'}"
                     f" ({curve.duration_s / 3600:.3g} h at {curve.rate_hz:.4g} Hz)")
        ax.set_xlabel("averaging time tau [s]")
        ax.set_ylabel(f"Allan deviation [{unit}]")
        lo = np.nanmin(curve.ci_low[:, [curve.axes.index(a) for a in SENSOR_AXES[sensor]]])
        hi = np.nanmax(curve.ci_high[:, [curve.axes.index(a) for a in SENSOR_AXES[sensor]]])
        ax.set_ylim(lo / 3.0, hi * 2.0)  # the term lines run off the data; keep the curves in view
        ax.grid(True, which="both", alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        for term, marker in MARKERS.items():
            if any(by_axis[a].terms[term].value is not None for a in SENSOR_AXES[sensor] if a in by_axis):
                handles.append(ax.plot([], [], marker, color="gray", mfc="white", ls="")[0])
                labels.append(f"{term} [{UNITS[sensor][term][0]}]")
        handles.append(ax.plot([], [], "--", color="gray")[0])
        labels.append("fitted model: the sum of its terms")
        handles.append(ax.plot([], [], ":", color="gray")[0])
        labels.append("IEEE 952 terms")
        handles.append(ax.plot([], [], ls=PART_STYLES["GM"], color="gray")[0])
        labels.append("Gauss-Markov processes")
        handles.append(ax.plot([], [], ls=PART_STYLES["S"], color="gray")[0])
        labels.append("sinusoids")
        if valid:
            handles.append(ax.fill_between([], [], [], color="gold", alpha=0.25, lw=0))
            labels.append("valid range of the model (every axis)")
        ax.legend(handles, labels, fontsize=8, loc="best")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def write_png(path: str | Path, curve: AllanCurve, noise: list[AxisNoise], title: str = "") -> None:
    """Write the Allan plot of ``curve`` and its fitted ``noise`` to ``path`` as a PNG (atomically)."""
    atomic_write_bytes(path, render_png(curve, noise, title))
