"""Evaluation of the temperature model of the bias: what firmware computes, in numpy.

The bias added by temperature, per axis (the lecture's model, all seven terms):

    B(T, dT) = a t^3 + b t^2 + c t + e dT^2 + f dT + g t dT + h,     t = T - T_ref

with T in degC, dT in degC/s. Terms the fit left out have a zero coefficient. The
coefficients are piecewise over temperature segments; T is first clamped to the calibrated
range [t_min, t_max] and dT to [dt_min, dt_max], exactly as the firmware export does it.
This thermal bias adds to the static bias of the ``accel``/``gyro`` section:
raw = M true + b + B(T, dT).

The dT filter (how dT is estimated from the temperature stream) is stored with the model so
firmware estimates dT the same way; see :func:`estimate_dtemp`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from station.engines.thermal.intrinsics import TempPolynomial, slope_weights

TERMS = ("t3", "t2", "t", "dt2", "dt", "tdt", "1")


def term_matrix(t_rel: np.ndarray, dtemp: np.ndarray) -> np.ndarray:
    """Columns of the seven terms of the bias model in ``TERMS`` order (module docstring).

    Parameters
    ----------
    t_rel : ndarray, (N,)
        t = T - T_ref, degC.
    dtemp : ndarray, (N,)
        dT, degC/s.

    Returns
    -------
    ndarray, (N, 7)
    """
    t = np.asarray(t_rel, float)
    d = np.asarray(dtemp, float)
    return np.stack([t**3, t**2, t, d**2, d, t * d, np.ones_like(t)], axis=-1)


@dataclass
class ThermalSegment:
    """Coefficients (3 axes x 7 terms, ``TERMS`` order) valid for t_min <= T < t_max."""

    t_min: float
    t_max: float
    coeffs: np.ndarray

    def __post_init__(self) -> None:
        self.coeffs = np.asarray(self.coeffs, dtype=float).reshape(3, len(TERMS))


@dataclass
class ThermalBias:
    """The thermal bias model of one triad."""

    segments: list[ThermalSegment]
    dt_min: float = -1.0
    dt_max: float = 1.0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def t_min(self) -> float:
        """Lower end of the calibrated temperature range, degC."""
        return self.segments[0].t_min

    @property
    def t_max(self) -> float:
        """Upper end of the calibrated temperature range, degC."""
        return self.segments[-1].t_max

    def evaluate(self, temp: np.ndarray, dtemp: np.ndarray, reference_temp: float) -> np.ndarray:
        """Thermal bias B(T, dT) of the module docstring, as firmware evaluates it.

        Clamps T to [t_min, t_max] and dT to [dt_min, dt_max]; picks the segment whose
        range holds T (the last segment holds t_max itself).

        Parameters
        ----------
        temp, dtemp : ndarray, (N,)
            Temperature (degC) and its filtered rate (degC/s).
        reference_temp : float
            T_ref, degC.

        Returns
        -------
        ndarray, (N, 3)
        """
        temp = np.clip(np.asarray(temp, float), self.t_min, self.t_max)
        dtemp = np.clip(np.asarray(dtemp, float), self.dt_min, self.dt_max)
        starts = np.array([s.t_min for s in self.segments[1:]])
        index = np.searchsorted(starts, temp, side="right")
        terms = term_matrix(temp - reference_temp, dtemp)
        coeffs = np.stack([s.coeffs for s in self.segments])  # (S, 3, 7)
        return np.einsum("nk,njk->nj", terms, coeffs[index])

    def temperature_sensitivity(self, reference_temp: float) -> np.ndarray:
        """The bias's temperature sensitivity per axis (the slope of :func:`slope_weights`), in the triad's
        unit per degC.

        Parameters
        ----------
        reference_temp : float
            T_ref, degC.

        Returns
        -------
        ndarray, (3,)
        """
        temp, w = slope_weights(self.t_min, self.t_max)
        return np.asarray(w @ self.evaluate(temp, np.zeros_like(temp), reference_temp))

    def to_dict(self) -> dict[str, Any]:
        """The ``accel``/``gyro`` entry of the ``thermal`` section (``shared/specs/params-file.md``)."""
        return {
            "terms": list(TERMS),
            "clamp": {"temp": [self.t_min, self.t_max], "dtemp": [self.dt_min, self.dt_max]},
            "segments": [
                {"t_min": s.t_min, "t_max": s.t_max, "coeffs": s.coeffs.tolist()} for s in self.segments
            ],
            **self.extra,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ThermalBias:
        """Read an entry written by :meth:`to_dict`; refuses unknown terms or no segments (ValueError).

        Parameters
        ----------
        d : dict

        Returns
        -------
        ThermalBias
        """
        if list(d.get("terms", TERMS)) != list(TERMS):
            raise ValueError(f"thermal terms {d.get('terms')} are not the known {list(TERMS)}")
        clamp = d.get("clamp", {})
        dt_min, dt_max = clamp.get("dtemp", [-1.0, 1.0])
        segments = [ThermalSegment(s["t_min"], s["t_max"], s["coeffs"]) for s in d["segments"]]
        if not segments:
            raise ValueError("thermal model has no segments")
        known = {"terms", "clamp", "segments"}
        return cls(segments, float(dt_min), float(dt_max), {k: v for k, v in d.items() if k not in known})


@dataclass
class DtempFilter:
    """How dT is estimated from the sampled temperature, the same in the station and firmware.

    ``ema``: a first-order low-pass of T with time constant ``tau_s`` (alpha = dt / (tau + dt),
    on each sample's own dt), then the difference quotient of the filtered T, low-passed again
    with the same time constant. State starts at the first sample with dT = 0.
    """

    kind: str = "ema"
    tau_s: float = 10.0

    def to_dict(self) -> dict[str, Any]:
        """The ``dtemp_filter`` entry of the ``thermal`` section."""
        return {"kind": self.kind, "tau_s": self.tau_s}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DtempFilter:
        """Read an entry written by :meth:`to_dict`; refuses a filter kind other than ``ema`` (ValueError).

        Parameters
        ----------
        d : dict

        Returns
        -------
        DtempFilter
        """
        if d.get("kind") != "ema":
            raise ValueError(f"dT filter kind {d.get('kind')!r} is unknown; this station knows 'ema'")
        return cls("ema", float(d["tau_s"]))


def _ema_scan(alpha: np.ndarray, x: np.ndarray, y0: float) -> np.ndarray:
    """y_i = y_{i-1} + alpha_i (x_i - y_{i-1}) for all i, from y_{-1} = y0, without a Python loop per sample.

    Unrolled, y_i = P_i y0 + sum_k (P_i / P_k) alpha_k x_k with P_i = prod_{j<=i} (1 - alpha_j).
    The products are taken as exponentials of cumulative log sums, restarted every 4096
    samples or whenever they have decayed by e^-600 (so that 1 / P_k stays finite); every
    step is the same recursion.
    """
    n = len(x)
    out = np.empty(n)
    log_a = np.log1p(-alpha)
    c = np.cumsum(log_a)
    start, y = 0, y0
    while start < n:
        base = c[start - 1] if start else 0.0
        window = c[start:start + 4096]
        stop = start + max(int(np.searchsorted(-(window - base), 600.0, side="right")), 1)
        # A fresh sum per block: the global one carries rounding from every earlier sample.
        d = np.cumsum(log_a[start:stop])
        s = np.cumsum(np.exp(-d) * alpha[start:stop] * x[start:stop])
        out[start:stop] = np.exp(d) * (y + s)
        y = out[stop - 1]
        start = stop
    return out


def estimate_dtemp(t_s: np.ndarray, temp: np.ndarray, filt: DtempFilter) -> np.ndarray:
    """dT from timestamps and temperatures with the filter ``filt`` (see :class:`DtempFilter`).

    Firmware runs the recursion sample by sample; here it is evaluated as two vectorised
    first-order scans (``_ema_scan``) with each sample's own dt, equal to the sample loop to
    rounding (within 1e-9 of the largest dT, far below float32). A sample whose dt is not
    positive leaves the state as it was and repeats the last dT. An unknown (NaN) reading
    counts as the last known one, and the filter starts at the first known reading, as the
    firmware's ``imu_calib_dtemp_update`` does.

    Parameters
    ----------
    t_s : ndarray, (N,)
        Sample times, s.
    temp : ndarray, (N,)
        Temperatures, degC (NaN where unknown).
    filt : DtempFilter

    Returns
    -------
    ndarray, (N,)
        dT, degC/s.
    """
    t_s = np.asarray(t_s, float)
    temp = np.asarray(temp, float)
    out = np.zeros_like(temp)
    known = np.isfinite(temp)
    if len(temp) < 2 or not known.any():
        return out
    if not known.all():
        last_known = np.maximum.accumulate(np.where(known, np.arange(len(temp)), -1))
        temp = temp[np.where(last_known >= 0, last_known, np.argmax(known))]
    dt = np.diff(t_s)
    valid = dt > 0
    safe_dt = np.where(valid, dt, 1.0)
    alpha = np.where(valid, safe_dt / (filt.tau_s + safe_dt), 0.0)
    tf = np.concatenate([[temp[0]], _ema_scan(alpha, temp[1:], temp[0])])
    slope = np.where(valid, np.diff(tf) / safe_dt, 0.0)
    out[1:] = _ema_scan(alpha, slope, 0.0)
    return out


@dataclass
class ThermalModel:
    """The ``thermal`` section: reference temperature, dT filter, per-triad bias models and, where a
    calibration across temperature made them, per-triad scale-factor and misalignment polynomials
    (``station.engines.thermal.intrinsics``; keys ``accel``/``gyro``)."""

    reference_temp: float
    dtemp_filter: DtempFilter
    accel: ThermalBias | None = None
    gyro: ThermalBias | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    scale: dict[str, TempPolynomial] = field(default_factory=dict)
    misalignment: dict[str, TempPolynomial] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The ``thermal`` section of the parameter file (``shared/specs/params-file.md``)."""
        out: dict[str, Any] = {
            "reference_temp": self.reference_temp,
            "dtemp_filter": self.dtemp_filter.to_dict(),
        }
        for name in ("accel", "gyro"):
            model = getattr(self, name)
            out[name] = model.to_dict() if model is not None else None
        for key in ("scale", "misalignment"):
            entries: dict[str, TempPolynomial] = getattr(self, key)
            if entries:
                out[key] = {name: poly.to_dict() for name, poly in entries.items()}
        out.update(self.extra)
        return out

    def keeping_intrinsics(self, held: ThermalModel | None) -> ThermalModel:
        """This model (a new bias fit) with the scale-factor and misalignment polynomials of ``held`` (the
        section it replaces), which a bias fit alone does not make: a file calibrated across temperature
        keeps that calibration when its thermal bias is fitted again.

        Parameters
        ----------
        held : ThermalModel or None
            The thermal section already in the file.

        Returns
        -------
        ThermalModel

        Raises
        ------
        ValueError
            ``held`` has polynomials about another reference temperature (they are relative to the
            ``accel``/``gyro`` sections' values at that temperature).
        """
        if held is None or not (held.scale or held.misalignment):
            return self
        if abs(held.reference_temp - self.reference_temp) > 1e-9:
            raise ValueError(f"the file's calibration across temperature is about {held.reference_temp:g} "
                             f"degC and this fit about {self.reference_temp:g} degC; fit about "
                             f"{held.reference_temp:g} degC (--reference-temp {held.reference_temp:g})")
        return replace(self, scale=dict(held.scale), misalignment=dict(held.misalignment))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ThermalModel:
        """Read a section written by :meth:`to_dict`; keys it does not know are kept in ``extra``.

        Parameters
        ----------
        d : dict

        Returns
        -------
        ThermalModel
        """
        known = {"reference_temp", "dtemp_filter", "accel", "gyro", "scale", "misalignment"}
        drifts = {}
        for key, components in (("scale", 3), ("misalignment", 6)):
            entries = d.get(key) or {}
            unknown = set(entries) - {"accel", "gyro"}
            if unknown:
                raise ValueError(f"thermal.{key} has {sorted(unknown)}; it holds 'accel' and 'gyro'")
            drifts[key] = {name: TempPolynomial.from_dict(entry, components)
                           for name, entry in entries.items() if entry}
        return cls(
            reference_temp=float(d["reference_temp"]),
            dtemp_filter=DtempFilter.from_dict(d["dtemp_filter"]),
            accel=ThermalBias.from_dict(d["accel"]) if d.get("accel") else None,
            gyro=ThermalBias.from_dict(d["gyro"]) if d.get("gyro") else None,
            extra={k: v for k, v in d.items() if k not in known},
            scale=drifts["scale"],
            misalignment=drifts["misalignment"],
        )
