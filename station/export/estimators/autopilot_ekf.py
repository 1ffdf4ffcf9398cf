"""IMU process noise for the autopilots' filters: PX4 EKF2 and ArduPilot EKF3, from the ``noise`` section.

Both filters take the IMU's delta angles and delta velocities as the input of their prediction and, at each
prediction step of length dt, add a variance set by a parameter that is a 1-sigma rate (acceleration) noise,
not a density. PX4, ``src/modules/ekf2/EKF/covariance.cpp`` (``Ekf::predictCovariance``)::

    d_ang_var = (delta_ang_dt * EKF2_GYR_NOISE)^2           delta-angle input variance   [rad^2]
    d_vel_var = (delta_vel_dt * EKF2_ACC_NOISE)^2           delta-velocity input variance [(m/s)^2]
    P_bg += (dt * EKF2_GYR_B_NOISE)^2                       gyro bias state, rad/s
    P_ba += (dt * EKF2_ACC_B_NOISE)^2                       accel bias state, m/s^2

dt the filter's period, ``EKF2_PREDICT_US`` (module.yaml: default 10000 us, 1000..20000; the IMU is
down-sampled to it). ArduPilot, ``libraries/AP_NavEKF3/AP_NavEKF3_core.cpp``
(``NavEKF3_core::CovariancePrediction``)::

    daxVar = (dt * EK3_GYRO_P_NSE)^2,   dvxVar = (dt * EK3_ACC_P_NSE)^2
    P_bg += (dt * EK3_GBIAS_P_NSE)^2,   P_ba += (dt * EK3_ABIAS_P_NSE)^2

(earlier EKF3 versions hold delta-angle and delta-velocity biases and add (dt^2 * EK3_GBIAS_P_NSE)^2: the
same in rate units), dt the down-sampled IMU period, ``EKF_TARGET_DT`` = 12 ms (``AP_NavEKF3_core.h``; the
first whole number of IMU samples from 12 ms less half a sample, e.g. 12.5 ms at 400 Hz).

From the continuous model of the noise section (IEEE 952, Kalibr's wiki "IMU Noise Model"), over one step:

    white noise N: delta angle variance N^2 dt = (dt sigma)^2,        sigma = N / sqrt(dt)    (1)
    random walk K: bias variance growth K^2 dt = (dt sigma_b)^2,      sigma_b = K / sqrt(dt)  (2)

the discretisation Kalibr's wiki gives (sigma_gd = sigma_g / sqrt(dt), sigma_bgd = sigma_bg sqrt(dt)) read
for the filter's step: (1) is sigma_gd itself, and (2) is sigma_bgd / dt since both filters scale their
parameter by dt. So the parameters depend on the filter's period, not on the IMU's rate, and both carry the
inflation factor F: value = F N / sqrt(dt), F K / sqrt(dt). N and K are the largest axis's equivalents to the
whole model (``kalibr.filter_values``): neither filter has a Gauss-Markov or bias-instability state, both
model the bias as a random walk, so B enters only through that equivalent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

EKF2_DT_S = 0.010
"""PX4's ``EKF2_PREDICT_US`` default, 10000 us."""
EKF3_DT_S = 0.012
"""ArduPilot's ``EKF_TARGET_DT`` (``AP_NavEKF3_core.h``)."""


@dataclass(frozen=True)
class EkfParameter:
    """One noise parameter of an autopilot's filter.

    Attributes
    ----------
    name : str
        The parameter's name.
    sensor, term : str
        What it is made from: ``gyro``/``accel`` and ``N``/``K`` of the noise section.
    unit : str
        Its unit, as the autopilot documents it.
    documented : tuple of float
        The range the autopilot's parameter metadata gives (the filter clamps only far above it).
    default : float
        The autopilot's default (for the comparison in the report).
    """

    name: str
    sensor: str
    term: str
    unit: str
    documented: tuple[float, float]
    default: float


@dataclass(frozen=True)
class EkfTarget:
    """An autopilot's filter: its parameters, its default step and where it comes from, where it clamps."""

    fmt: str
    estimator: str
    autopilot: str
    step_s: float
    step_source: str
    clamp: str
    parameters: tuple[EkfParameter, ...]


EKF2 = EkfTarget("ekf2", "PX4 EKF2", "px4", EKF2_DT_S, "EKF2_PREDICT_US 10000 us, PX4's default", "above 1", (
    EkfParameter("EKF2_GYR_NOISE", "gyro", "N", "rad/s", (0.0001, 0.1), 0.015),
    EkfParameter("EKF2_ACC_NOISE", "accel", "N", "m/s^2", (0.01, 1.0), 0.35),
    EkfParameter("EKF2_GYR_B_NOISE", "gyro", "K", "rad/s^2", (0.0, 0.01), 0.001),
    EkfParameter("EKF2_ACC_B_NOISE", "accel", "K", "m/s^3", (0.0, 0.01), 0.003),
))
EKF3 = EkfTarget("ekf3", "ArduPilot EKF3", "ardupilot", EKF3_DT_S, "EKF_TARGET_DT 12 ms, AP_NavEKF3_core.h",
                 "above 1 (EK3_ACC_P_NSE above 5)", (
    EkfParameter("EK3_GYRO_P_NSE", "gyro", "N", "rad/s", (0.0001, 0.1), 0.015),
    EkfParameter("EK3_ACC_P_NSE", "accel", "N", "m/s^2", (0.01, 1.0), 0.35),
    EkfParameter("EK3_GBIAS_P_NSE", "gyro", "K", "rad/s^2", (0.00001, 0.001), 0.001),
    EkfParameter("EK3_ABIAS_P_NSE", "accel", "K", "m/s^3", (0.00001, 0.02), 0.02),
))
TARGETS = {t.fmt: t for t in (EKF2, EKF3)}


def per_step_sigma(density: float, step_s: float, factor: float = 1.0) -> float:
    """An EKF noise parameter from a continuous density: ``factor * density / sqrt(step_s)``, eqs. (1)-(2).

    Parameters
    ----------
    density : float
        N (unit/sqrt(Hz)) or K (unit/s/sqrt(Hz)) of the noise section.
    step_s : float
        The filter's prediction step, s.
    factor : float
        The inflation factor (:mod:`station.export.estimators.inflation`).

    Returns
    -------
    float
        The parameter, in the unit (N) or unit/s (K).
    """
    return factor * density / math.sqrt(step_s)


def ekf_parameters(target: EkfTarget, values: dict[tuple[str, str], float], step_s: float,
                   factor: float) -> list[dict[str, Any]]:
    """Every parameter of ``target`` from the noise section's four values.

    Parameters
    ----------
    target : EkfTarget
        :data:`EKF2` or :data:`EKF3`.
    values : dict
        ``(sensor, term) -> value``, the largest axis's N and K (``kalibr.filter_values``).
    step_s : float
        The filter's prediction step, s.
    factor : float
        The inflation factor.

    Returns
    -------
    list of dict
        Per parameter: ``name``, ``value``, ``unit``, ``measured`` (the N or K it comes from), ``term``,
        ``sensor``, ``formula``, ``documented`` range and the autopilot's ``default``.
    """
    out = []
    for p in target.parameters:
        measured = values[(p.sensor, p.term)]
        out.append({"name": p.name, "value": per_step_sigma(measured, step_s, factor), "unit": p.unit,
                    "measured": measured, "sensor": p.sensor, "term": p.term,
                    "formula": f"{factor:g} x {p.term} / sqrt({step_s:g} s)",
                    "documented": list(p.documented), "default": p.default})
    return out


def range_notes(target: EkfTarget, parameters: list[dict[str, Any]]) -> list[str]:
    """A note for each value outside the range the autopilot documents (written as computed all the same).

    Parameters
    ----------
    target : EkfTarget
        The filter.
    parameters : list of dict
        :func:`ekf_parameters`' output, after float32 rounding.

    Returns
    -------
    list of str
        One note per value outside its documented range.
    """
    notes = []
    for p in parameters:
        lo, hi = p["documented"]
        if not lo <= p["value"] <= hi:
            side = "below" if p["value"] < lo else "above"
            notes.append(f"{p['name']} {p['value']:.4g} {p['unit']} is {side} the range {target.estimator} "
                         f"documents ({lo:g}..{hi:g}); written as computed: a ground station may warn, the "
                         f"filter clamps only {target.clamp}")
    return notes
