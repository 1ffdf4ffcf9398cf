"""The certificate's plots as inline SVG: pose residuals, Allan deviation, thermal bias, scale factor and
misalignment against temperature, turn-on repeatability per soak, magnetometer sphere.

Each takes the parameter file's section (and, where it needs the samples, the capture it came
from) and returns the ``<svg>`` text; colours and markers follow the station's PNGs
(``station/plots/allan.py``, ``station/plots/thermal.py``).
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from station.common.units import PEOPLE
from station.engines.allan.deviation import allan_curve, integrate_rates
from station.engines.allan.fit import TERMS, basis, model_avar
from station.engines.allan.terms import SENSOR_AXES
from station.engines.calibration.common import pose_vector
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.blocks import block_ids, still_poses
from station.engines.thermal.intrinsics import OFF_DIAGONAL_NAMES
from station.engines.thermal.model import ThermalModel
from station.plots.allan import COLORS
from station.plots.svg import new_figure, to_svg

PAGE_WIDTH_IN = 7.3  # A4 less the certificate's margins: drawn at this width, 7 pt text prints at 7 pt
MIN_ALLAN_SAMPLES = 1000  # below this a measured curve says nothing the model does not
THERMAL_BLOCK_S = 30.0  # block means of the sweep drawn against the model: the bias moves slowly


class Samples(Protocol):
    """What the plots read of a capture (``station.acquisition.capture.Capture`` is one): SI arrays."""

    t: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    temp: np.ndarray | None
    step: np.ndarray | None
    mag: np.ndarray | None

    @property
    def rate_hz(self) -> float:
        """Sample rate, Hz."""

    def __len__(self) -> int:
        """Samples."""

    def segments(self) -> list[tuple[str, slice]]:
        """Runs of one step label: [(label, slice), ...]."""


class Calibrated(Protocol):
    """What the plots read of a parameter file (``station.export.params.file.ParamsFile`` is one)."""

    @property
    def accel(self) -> SensorCalibration | None:
        """The accelerometer's intrinsics."""

    @property
    def gyro(self) -> SensorCalibration | None:
        """The gyroscope's intrinsics."""

    @property
    def thermal(self) -> ThermalModel | None:
        """The temperature model of the biases."""


def pose_residuals(capture: Samples, params: Calibrated) -> list[dict[str, Any]]:
    """Per static pose of ``capture``: the corrected mean's departure from gravity and the gyro's mean.

    The accelerometer residual is ``C (mean(raw) - b) - |g| u`` with C the correction, b the bias,
    u the pose's up vector and |g| the median corrected magnitude over the poses (the local gravity
    the calibration scaled to); the gyroscope's is its corrected mean (the Earth's rate is in it).

    Parameters
    ----------
    capture : Samples
        A labelled capture (pose labels ``+x``, ``-y``, ...).
    params : Calibrated
        The calibration (``accel`` needed; ``gyro`` used when present).

    Returns
    -------
    list of dict
        ``pose``, ``accel_mg`` (3,) and ``gyro_dph`` (3,) or None, in capture order.
    """
    if params.accel is None:
        return []
    poses = []
    for label, part in capture.segments():
        up = pose_vector(label)
        if up is not None:
            poses.append((label, up, capture.acc[part].mean(axis=0), capture.gyro[part].mean(axis=0)))
    if not poses:
        return []
    acc = np.array([params.accel.correction @ (a - params.accel.bias) for _, _, a, _ in poses])
    g = float(np.median(np.linalg.norm(acc, axis=1)))
    out = []
    for (label, up, _, w), a in zip(poses, acc, strict=True):
        gyro = None
        if params.gyro is not None:
            gyro = params.gyro.correction @ (w - params.gyro.bias) * PEOPLE["deg/h"]
        out.append({"pose": label, "accel_mg": (a - g * up) * PEOPLE["mg"], "gyro_dph": gyro})
    return out


def residuals_svg(residuals: list[dict[str, Any]]) -> str:
    """Bars per pose and axis: accelerometer residual (mg) and, where calibrated, gyroscope mean (deg/h)."""
    return to_svg(residuals_figure(residuals))


def residuals_figure(residuals: list[dict[str, Any]]) -> Any:
    """The figure of :func:`residuals_svg`, drawn at the page's width; with more than six poses the
    labels (``+x+y``) are turned 45 degrees so that neighbours never run together."""
    has_gyro = residuals[0]["gyro_dph"] is not None
    fig, axes = new_figure(PAGE_WIDTH_IN, 2.0, 1, 2 if has_gyro else 1)
    x = np.arange(len(residuals))
    width = 0.26
    panels = [("accel_mg", "accelerometer: corrected mean - g (mg)")]
    if has_gyro:
        panels.append(("gyro_dph", "gyroscope: corrected mean (deg/h, Earth rate in it)"))
    turned = len(residuals) > 6
    for ax, (key, title) in zip(axes[0], panels, strict=True):
        values = np.array([r[key] for r in residuals])
        for j, colour in enumerate(COLORS):
            ax.bar(x + (j - 1) * width, values[:, j], width, color=colour, label="xyz"[j])
        ax.axhline(0.0, color="0.3", lw=0.8)
        ax.set_xticks(x, [r["pose"] for r in residuals], fontsize=7, rotation=45 if turned else 0,
                      ha="right" if turned else "center", rotation_mode="anchor")
        ax.tick_params(axis="y", labelsize=7)
        ax.set_title(title, fontsize=8)
        ax.set_xlabel("pose (axis up)", fontsize=7)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=7, ncol=3, handlelength=1.0, columnspacing=0.8, loc="best")
    fig.tight_layout(pad=0.4)
    return fig


def measured_allan(capture: Samples) -> Any:
    """The Allan curve of a still capture's six axes (gx gy gz ax ay az), or None when too short."""
    if len(capture) < MIN_ALLAN_SAMPLES:
        return None
    rates = np.column_stack([capture.gyro, capture.acc])
    return allan_curve(integrate_rates(rates, capture.rate_hz), capture.rate_hz, SENSOR_AXES["gyro"]
                       + SENSOR_AXES["accel"])


def allan_svg(noise: dict[str, Any], curve: Any = None) -> str:
    """Allan deviation per sensor: the fitted model, its 1-sigma band, each term's line, the curve if given
    (:func:`allan_figure`)."""
    return to_svg(allan_figure(noise, curve))


def allan_figure(noise: dict[str, Any], curve: Any = None) -> Any:
    """The figure of :func:`allan_svg`, its legends below the panels at 7 pt.

    The band is the model evaluated with every term at its value -/+ its 1-sigma (eq. C.1 of
    IEEE 952 through :func:`~station.engines.allan.fit.model_avar`); the measured curve, when a
    still capture is given, is drawn with its 68 % interval as ``imu-station allan --plot`` draws it.
    """
    sensors = [s for s in ("gyro", "accel") if isinstance(noise.get(s), dict)]
    record = noise.get("record") or {}
    lo, hi = (record.get("tau_range_s") or [0.01, 1e3])[:2]
    tau = np.geomspace(float(lo), float(hi), 200)
    fig, axes = new_figure(PAGE_WIDTH_IN, 2.5, 1, len(sensors))
    for ax, sensor in zip(axes[0], sensors, strict=True):
        terms = noise[sensor]
        sd = terms.get("stddev") or {}
        for j, (colour, axis) in enumerate(zip(COLORS, SENSOR_AXES[sensor], strict=True)):
            coeffs = {t: _axis_value(terms.get(t), j) for t in TERMS}
            sigma = {t: _axis_value(sd.get(t), j) or 0.0 for t in TERMS}
            upper = {t: None if v is None else v + sigma[t] for t, v in coeffs.items()}
            lower = {t: None if v is None else max(v - sigma[t], 0.0) for t, v in coeffs.items()}
            ax.fill_between(tau, np.sqrt(model_avar(tau, lower)), np.sqrt(model_avar(tau, upper)),
                            color=colour, alpha=0.18, lw=0)
            ax.loglog(tau, np.sqrt(model_avar(tau, coeffs)), "--", color=colour, lw=1.2,
                      label=f"{axis} model")
            for t, value in coeffs.items():
                if value is not None:
                    ax.loglog(tau, np.sqrt(basis(tau)[:, TERMS.index(t)]) * value, ":", color=colour, lw=0.8,
                              alpha=0.7)
            if curve is not None and axis in curve.axes:
                k = curve.axes.index(axis)
                ax.fill_between(curve.tau, curve.ci_low[:, k], curve.ci_high[:, k], color=colour, alpha=0.12,
                                lw=0)
                ax.loglog(curve.tau, curve.adev[:, k], ".-", color=colour, lw=1.0, ms=3,
                          label=f"{axis} measured")
        unit = "rad/s" if sensor == "gyro" else "m/s$^2$"
        ax.set_title("gyroscope" if sensor == "gyro" else "accelerometer", fontsize=8)
        ax.set_xlabel("averaging time tau [s]", fontsize=7)
        ax.set_ylabel(f"Allan deviation [{unit}]", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="both", alpha=0.3)
        # below the axes, never over the curves: six entries at a size that prints legibly
        ax.legend(fontsize=7, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False,
                  handlelength=1.6, columnspacing=1.0)
    fig.tight_layout(pad=0.4)
    return fig


def _axis_value(values: Any, j: int) -> float | None:
    if not isinstance(values, list) or j >= len(values) or values[j] is None:
        return None
    return float(values[j])


def thermal_points(sweep: Samples, params: Calibrated) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The sweep's bias against temperature, as the model should follow it: per triad, block
    temperatures (B,) and bias (B, 3) in SI.

    Still samples (``thermal.blocks.still_poses``) are averaged in blocks of about
    :data:`THERMAL_BLOCK_S`; the bias is the block mean less the calibration's bias, less a constant
    per pose (gravity or the Earth's rate through the intrinsics) taken as the pose's mean departure
    from the model, so every pose lines up on the model where the data agree with it.

    Parameters
    ----------
    sweep : Samples
        A capture with temperature (the thermal section's).
    params : Calibrated
        Its ``thermal`` section, and ``accel``/``gyro`` for their static bias where present.

    Returns
    -------
    dict
        ``accel`` and/or ``gyro`` to (temperatures, bias); empty without temperature or still blocks.
    """
    model = params.thermal
    if model is None or sweep.temp is None:
        return {}
    temp = np.asarray(sweep.temp, dtype=float)
    pose, _ = still_poses(sweep.t, sweep.acc, sweep.gyro, sweep.step)
    ids = block_ids(pose, np.isfinite(temp), max(int(THERMAL_BLOCK_S * sweep.rate_hz), 2))
    used = ids >= 0
    if not used.any():
        return {}
    count = np.bincount(ids[used])
    block_temp = np.bincount(ids[used], weights=temp[used]) / count
    block_pose = np.zeros(len(count), dtype=int)
    block_pose[ids[used]] = pose[used]
    out = {}
    for name, raw in (("accel", sweep.acc), ("gyro", sweep.gyro)):
        bias = getattr(model, name)
        if bias is None:
            continue
        means = np.column_stack([np.bincount(ids[used], weights=raw[used, j]) / count for j in range(3)])
        static = getattr(params, name)
        if static is not None:
            means = means - static.bias
        departure = means - bias.evaluate(block_temp, np.zeros_like(block_temp), model.reference_temp)
        for p in np.unique(block_pose):
            means[block_pose == p] -= departure[block_pose == p].mean(axis=0)
        out[name] = (block_temp, means)
    return out


def thermal_svg(params: Calibrated, points: dict[str, tuple[np.ndarray, np.ndarray]] | None = None) -> str:
    """The thermal bias model at dT = 0 per triad and axis across its range (dashed where clamped),
    with the sweep's block means (:func:`thermal_points`) where given."""
    model = params.thermal
    assert model is not None  # the caller draws this only for a file with a thermal section
    triads = [(name, bias) for name in ("accel", "gyro") if (bias := getattr(model, name)) is not None]
    fig, axes = new_figure(PAGE_WIDTH_IN, 2.1, 1, len(triads))
    for ax, (name, bias) in zip(axes[0], triads, strict=True):
        unit = "mg" if name == "accel" else "deg/h"
        pad = 0.1 * max(bias.t_max - bias.t_min, 1.0)
        grid = np.linspace(bias.t_min - pad, bias.t_max + pad, 300)
        curve = bias.evaluate(grid, np.zeros_like(grid), model.reference_temp) * PEOPLE[unit]
        inside = (grid >= bias.t_min) & (grid <= bias.t_max)
        measured = (points or {}).get(name)
        for j, colour in enumerate(COLORS):
            if measured is not None:
                ax.plot(measured[0], measured[1][:, j] * PEOPLE[unit], "o", color=colour, ms=3.5, mfc="white",
                        mew=1.0, zorder=3)  # open circles over the line: data and model both visible
            ax.plot(grid[inside], curve[inside, j], color=colour, lw=1.5, label="xyz"[j])
            for beyond in (grid < bias.t_min, grid > bias.t_max):
                ax.plot(grid[beyond], curve[beyond, j], color=colour, lw=1, ls="--")
        for seg in bias.segments[1:]:
            ax.axvline(seg.t_min, color="grey", ls=":", lw=1)
        ax.axvline(model.reference_temp, color="0.3", lw=0.8)
        ax.set_title(f"{'accelerometer' if name == 'accel' else 'gyroscope'} bias at dT = 0", fontsize=8)
        ax.set_xlabel("temperature (degC)", fontsize=7)
        ax.set_ylabel(f"bias ({unit})", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3, handlelength=1.2, columnspacing=0.8)
    fig.tight_layout(pad=0.4)
    return to_svg(fig)


def intrinsics_svg(params: Calibrated) -> str:
    """Per triad the scale factor's change (ppm of K) and the misalignment's (urad) against temperature, as
    the thermal section's polynomials give them (``station.engines.thermal.intrinsics``, equation (2));
    dashed beyond the calibrated range, where T is clamped."""
    model = params.thermal
    assert model is not None  # the caller draws this only for a file with scale or misalignment polynomials
    triads = [name for name in ("accel", "gyro") if name in model.scale or name in model.misalignment]
    fig, axes = new_figure(PAGE_WIDTH_IN, 1.9 * len(triads), len(triads), 2)
    for row, name in zip(axes, triads, strict=True):
        static = getattr(params, name)
        k = static.scale if static is not None else np.ones(3)
        title = "accelerometer" if name == "accel" else "gyroscope"
        panels = ((model.scale.get(name), 1e6 / k, "xyz", "scale factor change (ppm)"),
                  (model.misalignment.get(name), np.full(6, 1e6), OFF_DIAGONAL_NAMES,
                   "misalignment change (urad)"))
        for ax, (poly, factor, labels, ylabel) in zip(row, panels, strict=True):
            ax.set_title(f"{title}: {ylabel.split(' change')[0]}", fontsize=8)
            if poly is None:
                ax.text(0.5, 0.5, "not calibrated across temperature", ha="center", va="center", fontsize=7,
                        transform=ax.transAxes)
                ax.set_axis_off()
                continue
            pad = 0.1 * (poly.t_max - poly.t_min)
            grid = np.linspace(poly.t_min - pad, poly.t_max + pad, 300)
            curve = poly.evaluate(grid, model.reference_temp) * factor
            inside = (grid >= poly.t_min) & (grid <= poly.t_max)
            colours = [*COLORS, "tab:purple", "tab:brown", "tab:olive"]
            for c, label in enumerate(labels):
                ax.plot(grid[inside], curve[inside, c], color=colours[c], lw=1.5, label=label)
                for beyond in (grid < poly.t_min, grid > poly.t_max):
                    ax.plot(grid[beyond], curve[beyond, c], color=colours[c], lw=1, ls="--")
            ax.axvline(model.reference_temp, color="0.3", lw=0.8)
            ax.set_xlabel("temperature (degC)", fontsize=7)
            ax.set_ylabel(ylabel, fontsize=7)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=6, ncol=3, handlelength=1.2, columnspacing=0.8)
    fig.tight_layout(pad=0.4)
    return to_svg(fig)


def turn_on_svg(block: dict[str, Any]) -> str:
    """A chamber campaign's turn-on bias repeatability (1-sigma over the power-ups) at each soak, per triad
    and axis (``characterisation.across_temperature.turn_on``)."""
    soaks = block["turn_on"]
    temp = np.array([float(s["soak_c"]) for s in soaks])
    fig, axes = new_figure(PAGE_WIDTH_IN, 2.0, 1, 2)
    # In the datasheet's units of turn-on repeatability (``station.report.datasheet``): mg and deg/s.
    triads = (("accel", "mg", PEOPLE["mg"]), ("gyro", "deg/s", PEOPLE["deg"]))
    for ax, (name, unit, factor) in zip(axes[0], triads, strict=True):
        values = np.array([[np.nan if v is None else float(v) for v in s[f"{name}_bias_repeatability"]]
                           for s in soaks]) * factor
        for j, colour in enumerate(COLORS):
            ax.plot(temp, values[:, j], "o-", color=colour, ms=3.5, lw=1, label="xyz"[j])
        ax.set_title(f"{'accelerometer' if name == 'accel' else 'gyroscope'} turn-on bias repeatability",
                     fontsize=8)
        ax.set_xlabel("soak temperature (degC)", fontsize=7)
        ax.set_ylabel(f"1-sigma ({unit})", fontsize=7)
        ax.set_ylim(bottom=0)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3, handlelength=1.2, columnspacing=0.8)
    fig.tight_layout(pad=0.4)
    return to_svg(fig)


def mag_svg(section: dict[str, Any], mag: np.ndarray) -> str:
    """The corrected field directions on the unit sphere (three projections) with the fit's coverage.

    Parameters
    ----------
    section : dict
        The ``mag`` section (``correction``, ``bias``, ``coverage``).
    mag : ndarray, (N, 3)
        The raw field of the magnetometer capture, microtesla.
    """
    correction = np.asarray(section["correction"], float)
    corrected = (np.asarray(mag, float) - np.asarray(section["bias"], float)) @ correction.T
    unit = corrected / np.linalg.norm(corrected, axis=1, keepdims=True)
    if len(unit) > 4000:  # a picture of the coverage, not of every sample
        unit = unit[:: math.ceil(len(unit) / 4000)]
    fig, axes = new_figure(PAGE_WIDTH_IN, 2.0, 1, 3)
    circle = np.linspace(0.0, 2.0 * math.pi, 200)
    for ax, (a, b) in zip(axes[0], ((0, 1), (0, 2), (1, 2)), strict=True):
        ax.plot(np.cos(circle), np.sin(circle), color="0.5", lw=0.8)
        ax.plot(unit[:, a], unit[:, b], ".", color="tab:blue", ms=1.5, alpha=0.5)
        ax.set_aspect("equal")
        ax.set_xlim(-1.1, 1.1)
        ax.set_ylim(-1.1, 1.1)
        ax.set_xlabel(f"{'xyz'[a]} (unit field)", fontsize=7)
        ax.set_ylabel(f"{'xyz'[b]}", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    coverage = section.get("coverage")
    shown = f"{coverage * 100:.0f} %" if isinstance(coverage, int | float) else "not stated"
    fig.suptitle(f"corrected field directions; coverage of the sphere {shown}", fontsize=8)
    fig.tight_layout(pad=0.4)
    return to_svg(fig)
