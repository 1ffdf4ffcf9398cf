"""Calibration across temperature: bias, scale factor and misalignment of both triads as polynomials
in T, from one turntable calibration per temperature soak (issue 27).

Niu et al. ("Fast thermal calibration of low-grade inertial sensors and IMUs", Sensors 13, 2013)
model every intrinsic parameter of a low-grade IMU as a low-order polynomial in temperature,
calibrated from sequences repeated at several soak temperatures. Here each soak s at temperature
T_s gives, per triad, the turntable estimates ``station.engines.calibration.turntable`` makes (bias
b, scale K, the six off-diagonal misalignment entries of S) with their 1-sigma sigma_s. Each
component y of each quantity is fitted as

    y(T) = sum_{p=0..P} a_p t^p,     t = T - T_ref                                           (1)

by weighted least squares, weights 1 / sigma_s^2:

    a = (A' W A)^-1 A' W y,     A_sp = t_s^p,  W = diag(1 / sigma_s^2)                       (2)

with the coefficient covariance

    C = r (A' W A)^-1,     r = max(1, chi^2 / (C_q (n - P - 1)))                             (3)

where chi^2 is the weighted residual sum over the quantity's C_q components and n soaks: the
reported 1-sigma are trusted unless the soaks scatter more than they say (a Birge ratio; without
usable 1-sigma the fit is unweighted and r is the residual variance itself).

The order P of each quantity of each triad (one order for its three or six components) is chosen
by leave-one-out cross-validation, as the thermal bias engine chooses its terms: the held-out
error of soak s is sum_c ((y_cs - yhat_cs(-s)) / sigma_cs)^2, and of the orders 0..min(max_order,
n - 2) the one-standard-error rule (``station.engines.thermal.design.one_se``) keeps the lowest
whose mean held-out error is within one standard error of the best.

The result is written as the parameter file's sections: ``accel``/``gyro`` at T_ref (a_0 of each
quantity), ``thermal.accel``/``thermal.gyro`` the bias change b(T) - b(T_ref) (one segment, the
t, t^2, t^3 terms; no dT terms, a soak has none), ``thermal.scale`` and ``thermal.misalignment``
the a_1..a_P of scale and misalignment, equation (2) of ``station.engines.thermal.intrinsics``,
so that M(T) = diag(K + k(t)) (I + S + s(t)) there reproduces (1). T is clamped to the soaks'
range.

The figures people quote are computed from the fitted curves: the scale factor's temperature
coefficient per axis in ppm/degC (the least-squares slope of k(T) / K over the range, equation (5)
of ``station.engines.thermal.model``, as ``ThermalBias.temperature_sensitivity`` does for the bias)
and each misalignment entry's change over the range (max - min, urad).

Why this module is long: it holds the engine's input and result types (the result with the figures
computed from it) and the few stages of one pipeline a reader follows in order (per-soak values,
weighted fit, leave-one-out order, sections at T_ref); each stage is short.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from station.engines.calibration.common import CalibrationReport
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.design import Candidate, one_se
from station.engines.thermal.fit import TAU_WITHOUT_RATE_S  # the filter stored without dT terms
from station.engines.thermal.intrinsics import OFF_DIAGONAL, TempPolynomial, slope_weights
from station.engines.thermal.model import TERMS, DtempFilter, ThermalBias, ThermalModel, ThermalSegment
from station.errors import EngineInputError

TRIADS = ("accel", "gyro")
QUANTITIES = ("bias", "scale", "misalignment")
MIN_SOAKS = 2
MIN_SPAN_DEGC = 5.0
MAX_ORDER = 3  # the powers thermal.scale and thermal.misalignment can hold
NOMINAL_TEMP_DEGC = 25.0
NOMINAL_WITHIN_DEGC = 10.0  # a soak this close to 25 degC is the reference; else the range's middle


@dataclass
class SoakCalibration:
    """One soak's turntable calibration.

    Attributes
    ----------
    temp : float
        The unit's mean temperature over the capture, degC.
    report : CalibrationReport
        From ``station.engines.calibration.turntable.calibrate_turntable``.
    label : str
        The capture file or soak name.
    """

    temp: float
    report: CalibrationReport
    label: str = ""


@dataclass
class SoakValues:
    """What one soak measured, per triad and quantity: ``values[triad][quantity]`` (3 or 6
    components; misalignment in ``OFF_DIAGONAL`` order) and their 1-sigma in ``stddev``."""

    label: str
    temp: float
    values: dict[str, dict[str, np.ndarray]]
    stddev: dict[str, dict[str, np.ndarray]]


@dataclass
class QuantityFit:
    """Equation (1) for every component of one quantity of one triad.

    Attributes
    ----------
    coeffs : ndarray, (C, P + 1)
        a_0..a_P per component (ascending powers of t = T - T_ref).
    cov : ndarray, (C, P + 1, P + 1)
        Their covariance, equation (3).
    cv_scores : dict of int to float
        Mean held-out error (chi-square per soak) of each order tried.
    birge : float
        r of equation (3).
    weighted : bool
        False where the soaks gave no usable 1-sigma (an unweighted fit).
    """

    triad: str
    quantity: str
    reference_temp: float
    t_min: float
    t_max: float
    coeffs: np.ndarray
    cov: np.ndarray
    cv_scores: dict[int, float]
    birge: float
    weighted: bool = True

    @property
    def order(self) -> int:
        """P, the polynomial's order."""
        return int(self.coeffs.shape[1] - 1)

    def _basis(self, temp: np.ndarray) -> np.ndarray:
        t = np.clip(np.atleast_1d(np.asarray(temp, float)), self.t_min, self.t_max) - self.reference_temp
        return np.stack([t**p for p in range(self.order + 1)], axis=-1)

    def evaluate(self, temp: np.ndarray) -> np.ndarray:
        """y(T) of equation (1), T clamped to the soaks' range.

        Parameters
        ----------
        temp : array_like, (N,)
            degC.

        Returns
        -------
        ndarray, (N, C)
        """
        return self._basis(temp) @ self.coeffs.T

    def stddev(self, temp: np.ndarray) -> np.ndarray:
        """1-sigma of y(T): sqrt(a' C a) with a the basis of equation (1) at T.

        Parameters
        ----------
        temp : array_like, (N,)
            degC.

        Returns
        -------
        ndarray, (N, C)
        """
        basis = self._basis(temp)
        return np.sqrt(np.maximum(np.einsum("np,cpq,nq->nc", basis, self.cov, basis), 0.0))

    def polynomial(self) -> TempPolynomial | None:
        """The drift a_1 t + ... + a_P t^P as a :class:`TempPolynomial` (None for order 0).

        Returns
        -------
        TempPolynomial or None
        """
        if self.order == 0:
            return None
        sd = np.sqrt(np.maximum(np.diagonal(self.cov, axis1=1, axis2=2), 0.0))
        return TempPolynomial(self.t_min, self.t_max, tuple(range(1, self.order + 1)), self.coeffs[:, 1:],
                              sd[:, 1:])


@dataclass
class AcrossTemperature:
    """The calibration across temperature (module docstring).

    Attributes
    ----------
    accel, gyro : SensorCalibration
        At ``thermal.reference_temp``, with 1-sigma (gyro None where a soak had none).
    thermal : ThermalModel
        Bias change, scale and misalignment polynomials per triad.
    soaks : list of SoakValues
        Each soak's estimates and 1-sigma, in temperature order.
    orders : dict of str to int
        Chosen order per ``"triad.quantity"``.
    fits : dict of str to QuantityFit
        The fit per ``"triad.quantity"`` (its ``cv_scores`` say why the order).
    reference_reason : str
        How T_ref was chosen.
    warnings : list of str
    """

    accel: SensorCalibration
    gyro: SensorCalibration | None
    thermal: ThermalModel
    soaks: list[SoakValues]
    orders: dict[str, int]
    fits: dict[str, QuantityFit] = field(default_factory=dict)
    reference_reason: str = ""
    warnings: list[str] = field(default_factory=list)

    @property
    def triads(self) -> tuple[str, ...]:
        """The triads fitted."""
        return TRIADS if self.gyro is not None else ("accel",)

    def scale_tc_ppm(self, triad: str) -> tuple[np.ndarray, np.ndarray]:
        """Scale-factor temperature coefficient per axis and its 1-sigma, ppm/degC: the least-squares
        slope of k(T) / K over the calibrated range (equation (5) of ``station.engines.thermal.model``).

        Parameters
        ----------
        triad : str

        Returns
        -------
        tuple of ndarray, (3,)
        """
        fit = self.fits[f"{triad}.scale"]
        k_ref = fit.coeffs[:, 0]
        poly = fit.polynomial()
        if poly is None:
            return np.zeros(3), np.zeros(3)
        temp, w = slope_weights(fit.t_min, fit.t_max)
        gain = w @ fit._basis(temp)  # the slope is linear in the coefficients: its variance g' C g
        sd = np.sqrt(np.maximum(np.einsum("p,cpq,q->c", gain, fit.cov, gain), 0.0)) / np.abs(k_ref)
        return poly.temperature_coefficient(fit.reference_temp) / k_ref * 1e6, sd * 1e6

    def misalignment_change_urad(self, triad: str) -> np.ndarray:
        """Each misalignment entry's change over the calibrated range (max - min of s(T)), urad, in
        ``OFF_DIAGONAL`` order.

        Parameters
        ----------
        triad : str

        Returns
        -------
        ndarray, (6,)
        """
        fit = self.fits[f"{triad}.misalignment"]
        poly = fit.polynomial()
        return np.zeros(6) if poly is None else poly.change_over_range(fit.reference_temp) * 1e6

    def bias_sensitivity(self, triad: str) -> np.ndarray:
        """The bias's temperature sensitivity per axis (slope over the range), the triad's unit per degC.

        Parameters
        ----------
        triad : str

        Returns
        -------
        ndarray, (3,)
        """
        fit = self.fits[f"{triad}.bias"]
        temp, w = slope_weights(fit.t_min, fit.t_max)
        return np.asarray(w @ fit.evaluate(temp))


def soak_values(soak: SoakCalibration) -> SoakValues:
    """Bias, scale and misalignment (off-diagonal, ``OFF_DIAGONAL`` order) of each triad of one soak,
    with their 1-sigma (NaN where the calibration gave none).

    Parameters
    ----------
    soak : SoakCalibration

    Returns
    -------
    SoakValues
    """
    values: dict[str, dict[str, np.ndarray]] = {}
    stddev: dict[str, dict[str, np.ndarray]] = {}
    for triad in TRIADS:
        cal: SensorCalibration | None = getattr(soak.report, triad)
        if cal is None:
            continue
        rows, cols = np.array(OFF_DIAGONAL).T
        values[triad] = {"bias": cal.bias.copy(), "scale": cal.scale,
                         "misalignment": cal.misalignment[rows, cols]}

        def sd_of(key: str, shape: tuple[int, ...], cal: SensorCalibration = cal) -> np.ndarray:
            given = cal.stddev.get(key)
            if given is None:
                return np.full(shape, np.nan)
            return np.asarray(given, float).reshape(shape)

        stddev[triad] = {"bias": sd_of("bias", (3,)), "scale": sd_of("scale", (3,)),
                         "misalignment": sd_of("misalignment", (3, 3))[rows, cols]}
    return SoakValues(soak.label, float(soak.temp), values, stddev)


def weighted_polyfit(t: np.ndarray, y: np.ndarray, sd: np.ndarray,
                     order: int) -> tuple[np.ndarray, np.ndarray]:
    """Equation (2) per component: coefficients and (A' W A)^-1, unscaled.

    Parameters
    ----------
    t : ndarray, (n,)
        T - T_ref, degC.
    y, sd : ndarray, (n, C)
        Values and their 1-sigma (positive).
    order : int

    Returns
    -------
    tuple of ndarray
        Coefficients (C, order + 1), ascending powers; their unscaled covariance (C, order + 1, order + 1).
    """
    a = np.stack([t**p for p in range(order + 1)], axis=-1)
    coeffs, covs = [], []
    for c in range(y.shape[1]):
        aw = a / sd[:, c, None]
        # lstsq on the whitened system, not the normal equations: t^3 at 40 degC is 6e4
        beta = np.linalg.lstsq(aw, y[:, c] / sd[:, c], rcond=None)[0]
        coeffs.append(beta)
        covs.append(np.linalg.pinv(aw.T @ aw))
    return np.array(coeffs), np.array(covs)


def loo_scores(t: np.ndarray, y: np.ndarray, sd: np.ndarray, order: int) -> np.ndarray:
    """Held-out error of each soak (module docstring): sum over components of the left-out soak's
    residual over its 1-sigma, squared, with the polynomial fitted on the other soaks.

    Parameters
    ----------
    t : ndarray, (n,)
    y, sd : ndarray, (n, C)
    order : int

    Returns
    -------
    ndarray, (n,)
    """
    out = np.zeros(len(t))
    for s in range(len(t)):
        keep = np.arange(len(t)) != s
        coeffs, _ = weighted_polyfit(t[keep], y[keep], sd[keep], order)
        predicted = coeffs @ (t[s] ** np.arange(order + 1))
        out[s] = float(np.sum(((y[s] - predicted) / sd[s]) ** 2))
    return out


def fit_quantity(triad: str, quantity: str, temps: np.ndarray, y: np.ndarray, sd: np.ndarray,
                 reference_temp: float, max_order: int) -> QuantityFit:
    """Equations (1)-(3) for one quantity of one triad, its order by leave-one-out cross-validation.

    Parameters
    ----------
    triad, quantity : str
    temps : ndarray, (n,)
        Soak temperatures, degC.
    y, sd : ndarray, (n, C)
        The soaks' values and 1-sigma (NaN or non-positive 1-sigma anywhere: unweighted).
    reference_temp : float
    max_order : int
        Highest order tried (also at most n - 2 and ``MAX_ORDER``).

    Returns
    -------
    QuantityFit
    """
    n, components = y.shape
    weighted = bool(np.all(np.isfinite(sd)) and np.all(sd > 0))
    sd_used = sd if weighted else np.ones_like(y)
    t = temps - reference_temp
    top = max(0, min(max_order, n - 2, MAX_ORDER))
    candidates, scores = [], {}
    for order in range(top + 1):
        sse = loo_scores(t, y, sd_used, order)
        candidates.append(Candidate((), False, order + 1, sse))
        scores[order] = float(sse.mean())
    chosen = one_se(candidates, np.ones(n)).params - 1
    coeffs, cov = weighted_polyfit(t, y, sd_used, chosen)
    basis = np.stack([t**p for p in range(chosen + 1)], axis=-1)
    chi2 = float(np.sum(((y - basis @ coeffs.T) / sd_used) ** 2))
    dof = components * (n - chosen - 1)
    ratio = chi2 / dof if dof > 0 else 1.0
    birge = max(1.0, ratio) if weighted else ratio
    return QuantityFit(triad, quantity, reference_temp, float(temps.min()), float(temps.max()), coeffs,
                       cov * birge, scores, birge, weighted)


def choose_reference(temps: np.ndarray, reference_temp: float | None) -> tuple[float, str]:
    """T_ref: the one given, else the soak temperature nearest 25 degC if within 10 degC of it, else
    the middle of the soaks' range (rounded to 0.1 degC).

    Parameters
    ----------
    temps : ndarray, (n,)
    reference_temp : float or None

    Returns
    -------
    tuple
        T_ref (degC) and how it was chosen.
    """
    if reference_temp is not None:
        return float(reference_temp), "as given"
    nearest = float(temps[np.argmin(np.abs(temps - NOMINAL_TEMP_DEGC))])
    if abs(nearest - NOMINAL_TEMP_DEGC) <= NOMINAL_WITHIN_DEGC:
        return round(nearest, 2), f"the soak nearest {NOMINAL_TEMP_DEGC:g} degC"
    value = round(0.5 * (float(temps.min()) + float(temps.max())), 1)
    return value, (f"the middle of the soaks' range: no soak within {NOMINAL_WITHIN_DEGC:g} degC of "
                   f"{NOMINAL_TEMP_DEGC:g}")


def _check(soaks: Sequence[SoakCalibration]) -> np.ndarray:
    if len(soaks) < MIN_SOAKS:
        raise EngineInputError(f"{len(soaks)} soak given: a calibration across temperature needs captures at "
                               f"{MIN_SOAKS} or more temperatures (5 or more to choose the curves' order)")
    temps = np.array([float(s.temp) for s in soaks])
    bad = [s.label or str(k) for k, s in enumerate(soaks) if not np.isfinite(s.temp)]
    if bad:
        raise EngineInputError(f"soak {', '.join(bad)} has no temperature; record with the temperature "
                               "channel (capture column 'temp')")
    if any(s.report.accel is None for s in soaks):
        raise EngineInputError("a soak has no accelerometer calibration; calibrate each capture with the "
                               "turntable method")
    span = float(temps.max() - temps.min())
    if span < MIN_SPAN_DEGC:
        raise EngineInputError(f"the soaks span {span:.1f} degC ({temps.min():.1f} to {temps.max():.1f}); "
                               f"a calibration across temperature needs at least {MIN_SPAN_DEGC:g} degC: "
                               "capture at temperatures further apart")
    return temps


def _sensor_at_reference(triad: str, fits: dict[str, QuantityFit], soaks: list[SoakValues],
                         reports: list[SensorCalibration]) -> SensorCalibration:
    """The triad's section at T_ref: a_0 of each quantity, with 1-sigma (matrix by first-order
    propagation of M_ij = K_i (delta_ij + S_ij))."""
    value = {q: fits[f"{triad}.{q}"].coeffs[:, 0] for q in QUANTITIES}
    sd = {q: np.sqrt(np.maximum(fits[f"{triad}.{q}"].cov[:, 0, 0], 0.0)) for q in QUANTITIES}
    mis, mis_sd = np.zeros((3, 3)), np.zeros((3, 3))
    for c, (i, j) in enumerate(OFF_DIAGONAL):
        mis[i, j], mis_sd[i, j] = value["misalignment"][c], sd["misalignment"][c]
    unit = np.eye(3) + mis
    matrix_sd = np.sqrt((unit * sd["scale"][:, None]) ** 2 + (value["scale"][:, None] * mis_sd) ** 2)
    stddev: dict[str, Any] = {"bias": sd["bias"], "scale": sd["scale"], "misalignment": mis_sd,
                              "matrix": matrix_sd}
    extra: dict[str, Any] = {"soaks": len(soaks), "reference_temp": fits[f"{triad}.bias"].reference_temp,
                             "residual": "mean of the soaks' residual RMS"}
    gsens = [r.extra.get("g_sensitivity") for r in reports]
    gsens_sd = [r.stddev.get("g_sensitivity") for r in reports]
    if triad == "gyro" and all(g is not None for g in gsens) and all(s is not None for s in gsens_sd):
        # the g-sensitivity is not modelled against T: its inverse-variance mean over the soaks
        g = np.array(gsens, float)
        w = 1.0 / np.maximum(np.array(gsens_sd, float), 1e-30) ** 2
        extra["g_sensitivity"] = (np.sum(w * g, axis=0) / np.sum(w, axis=0)).tolist()
        stddev["g_sensitivity"] = np.sqrt(1.0 / np.sum(w, axis=0))
    rms = [r.residual_rms for r in reports if r.residual_rms is not None]
    method = (f"turntable across temperature: {len(soaks)} soaks {soaks[0].temp:.1f} to {soaks[-1].temp:.1f} "
              f"degC, at T_ref {fits[f'{triad}.bias'].reference_temp:g} degC")
    return SensorCalibration.from_parts(value["scale"], mis, value["bias"], method=method,
                                        residual_rms=float(np.mean(rms)) if rms else None, stddev=stddev,
                                        extra=extra)


def _thermal_bias(fit: QuantityFit) -> ThermalBias:
    """b(T) - b(T_ref) as the one-segment thermal bias model (the t, t^2, t^3 terms)."""
    coeffs, sd = np.zeros((3, len(TERMS))), np.zeros((3, len(TERMS)))
    coeff_sd = np.sqrt(np.maximum(np.diagonal(fit.cov, axis1=1, axis2=2), 0.0))
    for p in range(1, fit.order + 1):
        column = TERMS.index("t" if p == 1 else f"t{p}")
        coeffs[:, column], sd[:, column] = fit.coeffs[:, p], coeff_sd[:, p]
    return ThermalBias([ThermalSegment(fit.t_min, fit.t_max, coeffs)],
                       extra={"stddev": sd.tolist(), "fit": "across temperature (soaks)"})


def fit_across_temperature(soaks: Sequence[SoakCalibration], reference_temp: float | None = None,
                           max_order: int = 3) -> AcrossTemperature:
    """Bias, scale factor and misalignment of both triads as polynomials in T (module docstring,
    equations (1)-(3); Niu et al. 2013), from one turntable calibration per soak.

    Parameters
    ----------
    soaks : sequence of SoakCalibration
        At least two, spanning at least 5 degC (five or more for the order to be chosen freely).
    reference_temp : float or None
        T_ref, degC; None: the soak nearest 25 degC (within 10 degC), else the range's middle.
    max_order : int
        Highest polynomial order tried (at most 3, and n_soaks - 2).

    Returns
    -------
    AcrossTemperature

    Raises
    ------
    EngineInputError
        Fewer than two soaks, a span under 5 degC, a soak without temperature or accelerometer.
    """
    temps = _check(soaks)
    order_idx = np.argsort(temps, kind="stable")
    soaks = [soaks[k] for k in order_idx]
    temps = temps[order_idx]
    values = [soak_values(s) for s in soaks]
    t_ref, reason = choose_reference(temps, reference_temp)
    warnings: list[str] = []
    triads = TRIADS if all("gyro" in v.values for v in values) else ("accel",)
    if triads == ("accel",) and any("gyro" in v.values for v in values):
        warnings.append("some soaks have no gyroscope calibration: the gyroscope is left out")
    fits: dict[str, QuantityFit] = {}
    for triad in triads:
        for q in QUANTITIES:
            y = np.array([v.values[triad][q] for v in values])
            sd = np.array([v.stddev[triad][q] for v in values])
            fit = fit_quantity(triad, q, temps, y, sd, t_ref, max_order)
            if not fit.weighted:
                warnings.append(f"{triad} {q}: the soaks gave no 1-sigma; fitted unweighted")
            fits[f"{triad}.{q}"] = fit
    sections: dict[str, SensorCalibration | None] = {"gyro": None}
    for triad in triads:
        reports = [getattr(s.report, triad) for s in soaks]
        sections[triad] = _sensor_at_reference(triad, fits, values, reports)
    thermal = ThermalModel(
        reference_temp=t_ref, dtemp_filter=DtempFilter(tau_s=TAU_WITHOUT_RATE_S),
        accel=_thermal_bias(fits["accel.bias"]),
        gyro=_thermal_bias(fits["gyro.bias"]) if "gyro" in triads else None,
        extra={"across_temperature": {"soaks": [{"label": v.label, "temp": v.temp} for v in values],
                                      "orders": {k: f.order for k, f in fits.items()}}},
    )
    for triad in triads:
        for q, target in (("scale", thermal.scale), ("misalignment", thermal.misalignment)):
            poly = fits[f"{triad}.{q}"].polynomial()
            if poly is not None:
                target[triad] = poly
    accel = sections["accel"]
    assert accel is not None  # every soak has one (_check)
    return AcrossTemperature(accel, sections["gyro"], thermal, values,
                             {k: f.order for k, f in fits.items()}, fits, reason, warnings)
