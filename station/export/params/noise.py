"""What ``imu-station allan`` writes: the ``noise`` section of the parameter file and the curve CSV.

Units are spelled out beside every number; gyroscope terms are also given in the units of datasheets
(deg/sqrt(h), deg/h, ...), accelerometer terms in m/s/sqrt(h) and micro-g.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from station.common.files import atomic_write_text
from station.engines.allan.deviation import AllanCurve
from station.engines.allan.equivalent import white_walk_equivalent
from station.engines.allan.fit import ML_METHOD, TERMS, AxisNoise
from station.engines.allan.model import NoiseModel
from station.engines.allan.terms import NAMES, SENSOR_AXES, UNITS

METHOD = ("overlapping Allan deviation (demeaned cumulative sum), IEEE 952 model fitted with weights from "
          "Greenhall-Riley EDF; where it does not describe the curve, the simplest of every combination of "
          "IEEE terms, up to three Gauss-Markov processes, the sensor's filter and sinusoids that does")
DEG = 180.0 / math.pi



def _per_axis(values: list[float | None]) -> list[float | None] | None:
    """Per-axis list, or None (YAML null) when no axis shows the term."""
    return None if all(v is None for v in values) else values


def _by_likelihood(axis: AxisNoise, term: str) -> bool:
    return (axis.terms[term].method or "").startswith(ML_METHOD)


def model_keys(models: list[NoiseModel], step_s: float, horizon_s: float | None) -> dict[str, Any]:
    """The keys of each axis's chosen model (:mod:`station.engines.allan.model`): ``GM`` (per axis a list of
    [sigma, tau_c]), ``valid_tau``, their 1-sigma, the filter, sinusoids, how the model was chosen, and the
    white noise and random walk equivalent to the whole model for filters that take only those
    (:mod:`station.engines.allan.equivalent`, over ``step_s`` .. ``horizon_s``, default each axis's valid
    range's end)."""
    out: dict[str, Any] = {
        "GM": [[[g.sigma.value, g.tau_c.value] for g in m.gauss_markov] for m in models],
        "valid_tau": [list(m.valid_tau) for m in models],
        "GM_stddev": [[[g.sigma.stddev, g.tau_c.stddev] for g in m.gauss_markov] for m in models],
    }
    if any(m.filter_s is not None for m in models):
        out["filter_time_constant_s"] = [None if m.filter_s is None else m.filter_s.value for m in models]
    if any(m.sinusoids for m in models):
        out["sinusoids"] = [[[s.amplitude.value, s.freq_hz.value] for s in m.sinusoids] for m in models]
    out["model"] = {"terms": [m.describe() for m in models], "method": [m.method for m in models],
                    "outside_band": [m.outside for m in models], "points": [m.points for m in models]}
    pairs = [white_walk_equivalent(m, step_s, horizon_s or m.valid_tau[1]) for m in models]
    out["filter_equivalent"] = {"N": [n for n, _ in pairs], "K": [k for _, k in pairs], "step_s": step_s,
                                "horizon_s": [horizon_s or m.valid_tau[1] for m in models]}
    return out


def sensor_noise(noise: list[AxisNoise], sensor: str, step_s: float = 0.01, horizon_s: float | None = None
                 ) -> dict[str, Any]:
    """The ``noise.gyro`` / ``noise.accel`` mapping of params-file.md, with stddev, reasons and readings
    (``step_s`` and ``horizon_s``: see :func:`model_keys`)."""
    units = UNITS[sensor]
    out: dict[str, Any] = {}
    for term in TERMS:
        out[term] = _per_axis([a.terms[term].value for a in noise])
    out["stddev"] = {t: _per_axis([a.terms[t].stddev for a in noise]) for t in TERMS}
    out["reasons"] = {t: [a.terms[t].reason for a in noise] for t in TERMS
                      if any(a.terms[t].reason for a in noise)}
    out["methods"] = {t: [a.terms[t].method for a in noise] for t in TERMS
                      if any(a.terms[t].method for a in noise)}
    # where the likelihood gave a term, the IEEE 952 fit's value beside it (the term itself elsewhere)
    adev_fit = {}
    for t in TERMS:
        if any(_by_likelihood(a, t) for a in noise):
            fit = [(a.terms[t].adev_value, a.terms[t].adev_stddev) if _by_likelihood(a, t)
                   else (a.terms[t].value, a.terms[t].stddev) for a in noise]
            adev_fit[t] = {"value": [v for v, _ in fit], "stddev": [sd for _, sd in fit]}
    if adev_fit:
        out["adev_fit"] = adev_fit
    out["datasheet_units"] = {
        f"{t} [{units[t][1]}]": _per_axis([None if (v := a.terms[t].value) is None else v * units[t][2]
                                           for a in noise])
        for t in TERMS}
    out["slope_line"] = {
        t: {"at_tau_1s": [a.terms[t].slope_line_at_1s for a in noise],
            "value": [a.terms[t].slope_value for a in noise],
            "tau_s": [a.terms[t].slope_tau for a in noise],
            "reason": [a.terms[t].slope_reason for a in noise]}
        for t in TERMS}
    models = [a.noise_model for a in noise]
    if any(m is not None for m in models):
        out.update(model_keys([m for m in models if m is not None], step_s, horizon_s))
    out["crossing_tau_N_K_s"] = [a.crossing_tau_nk for a in noise]
    out["reduced_chi2"] = [a.reduced_chi2 for a in noise]
    return out


def noise_section(noise: list[AxisNoise], curve: AllanCurve, record: dict[str, Any],
                  horizon_s: float | None = None) -> dict[str, Any]:
    """The whole ``noise`` section: per-sensor terms, units, method and the record they came from
    (``horizon_s``: the filters' horizon of the equivalent N and K, :func:`model_keys`)."""
    by_axis = {a.axis: a for a in noise}
    section: dict[str, Any] = {
        "method": METHOD,
        "units": {s: {t: UNITS[s][t][0] for t in TERMS} for s in UNITS},
        "model": ("sigma^2(tau) = 3 Q^2/tau^2 + N^2/tau + (2 ln2/pi) B^2 + K^2 tau/3 + R^2 tau^2/2 + sum "
                  "over GM [sigma, T] of sigma^2 (T/tau)^2 (2 tau/T - 3 + 4 exp(-tau/T) - exp(-2 tau/T)); "
                  "filter_time_constant_s T_f: N^2/tau becomes the GM term of sigma^2 = N^2/(2 T_f), "
                  "T = T_f; sinusoids [A, f]: A^2 sin^4(pi f tau)/(pi f tau)^2"),
    }
    for sensor, axes in SENSOR_AXES.items():
        if all(a in by_axis for a in axes):
            section[sensor] = sensor_noise([by_axis[a] for a in axes], sensor, 1.0 / curve.rate_hz, horizon_s)
    section["record"] = {"samples": curve.n_samples, "rate_hz": curve.rate_hz, "duration_s": curve.duration_s,
                         "tau_range_s": [float(curve.tau[0]), float(curve.tau[-1])], **record}
    return section


def curve_csv(curve: AllanCurve) -> str:
    """tau, one deviation column per axis, then n, and per axis its EDF and 68 % interval."""
    cols = ["tau"] + list(curve.axes) + ["n"]
    cols += [f"edf_{a}" for a in curve.axes]
    cols += [f"{a}_lo" for a in curve.axes] + [f"{a}_hi" for a in curve.axes]
    block = np.column_stack([curve.tau, curve.adev, curve.n, curve.edf, curve.ci_low, curve.ci_high])
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    fmt = ["%.9g"] + ["%.9g"] * len(curve.axes) + ["%d"] + ["%.6g"] * (3 * len(curve.axes))
    np.savetxt(buf, block, delimiter=",", fmt=fmt)
    return buf.getvalue()


def write_curve_csv(path: str | Path, curve: AllanCurve) -> None:
    """Write the Allan curve as CSV (:func:`curve_csv`) to ``path`` (atomically)."""
    atomic_write_text(path, curve_csv(curve))


def summary_lines(section: dict[str, Any]) -> list[str]:
    """Human-readable table of the terms, both unit systems, for the terminal."""
    lines = []
    for sensor in ("gyro", "accel"):
        if sensor not in section:
            continue
        s = section[sensor]
        lines.append(f"{sensor}:")
        for t in TERMS:
            si, alt, factor = UNITS[sensor][t]
            vals = s[t] or [None, None, None]
            sds = s["stddev"][t] or [None, None, None]
            cells = []
            for axis, v, sd in zip(SENSOR_AXES[sensor], vals, sds, strict=True):
                if v is None:  # the file's null, in words (the reasons of N and K follow)
                    cells.append(f"{axis} not resolved")
                else:
                    cells.append(f"{axis} {v:.4g}" + (f" +/- {sd:.2g}" if sd is not None else "")
                                 + f" ({v * factor:.4g} {alt})")
            lines.append(f"  {t} {NAMES[t]} [{si}]: " + " | ".join(cells))
        for t, fit in s.get("adev_fit", {}).items():
            cells = [f"{axis} " + ("not resolved" if v is None else f"{v:.4g}")
                     for axis, v in zip(SENSOR_AXES[sensor], fit["value"], strict=True)]
            lines.append(f"  {t} by the IEEE 952 fit of the curve, for comparison: " + " | ".join(cells))
        for axis, procs, valid, what in zip(SENSOR_AXES[sensor], s.get("GM") or [[]] * 3,
                                            s.get("valid_tau") or [None] * 3,
                                            (s.get("model") or {}).get("terms") or [None] * 3, strict=True):
            if what is None:
                continue
            gm = "; ".join(f"sigma {p[0]:.3g} {UNITS[sensor]['B'][0]}, tau_c {p[1]:.3g} s" for p in procs)
            lines.append(f"  {axis} model {what}" + (f" (Gauss-Markov {gm})" if gm else "")
                         + f", valid for tau {valid[0]:.3g} .. {valid[1]:.4g} s")
        for t, reasons in s["reasons"].items():
            if t not in ("N", "K"):  # the optional terms' absence is the normal case
                continue
            axes_of: dict[str, list[str]] = {}
            for axis, r in zip(SENSOR_AXES[sensor], reasons, strict=True):
                if r:
                    axes_of.setdefault(r, []).append(axis)
            for r, axes in sorted(axes_of.items()):
                lines.append(f"  {t} of {', '.join(axes)}: {r}")
    return lines
