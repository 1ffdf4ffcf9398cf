"""Every estimator's noise file behind one call: ``build_noise_export(fmt, noise, ...) -> EstimatorExport``.

The formats (:data:`NOISE_FORMATS`) and what each writes, from the largest axis's N and K of the ``noise``
section (``kalibr.filter_values``) and the inflation factor F (:mod:`~station.export.estimators.inflation`):

==========  =====================================  ==================================================
format      file                                   values
==========  =====================================  ==================================================
kalibr      Kalibr ``imu.yaml``                    F N, F K (continuous densities)
vins        VINS-Fusion ``acc_n gyr_n acc_w gyr_w``  F N, F K
orbslam3    ORB-SLAM3 ``IMU.Noise*``, ``IMU.*Walk``    F N, F K
openvins    OpenVINS ``kalibr_imu_chain.yaml``      F N, F K
ekf2        PX4 QGroundControl ``.params``         F N / sqrt(dt), F K / sqrt(dt), dt = 10 ms
ekf3        ArduPilot ``.param``                   F N / sqrt(dt), F K / sqrt(dt), dt = 12 ms
==========  =====================================  ==================================================

(:mod:`~station.export.estimators.autopilot_ekf` derives the last two from the autopilots' sources.) The
``export`` command writes them from a parameter file, ``allan`` straight from a record.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from station.errors import EngineInputError
from station.export.autopilot import ardupilot, px4
from station.export.autopilot.shared import AutopilotExport, Param
from station.export.estimators import autopilot_ekf, inflation, kalibr, openvins
from station.export.params.file import ParamsFile

NOISE_FORMATS = ("kalibr", "vins", "orbslam3", "openvins", "ekf2", "ekf3")
ESTIMATORS = {"kalibr": "Kalibr", "vins": "VINS-Fusion", "orbslam3": "ORB-SLAM3", "openvins": "OpenVINS",
              "ekf2": "PX4 EKF2", "ekf3": "ArduPilot EKF3"}
DEFAULT_NAMES = {"kalibr": "kalibr_imu.yaml", "vins": "vins_imu.yaml", "orbslam3": "orbslam3_imu.yaml",
                 "openvins": "kalibr_imu_chain.yaml", "ekf2": "ekf2_noise.params", "ekf3": "ekf3_noise.param"}
"""The file each format writes into a directory."""
ROS_NAME = re.compile(r"[~/]?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")
"""A ROS graph resource name (wiki.ros.org/Names), so a topic cannot add lines or keys to the YAML."""
_CONTINUOUS_KEYS = {
    "kalibr": dict(kalibr.KEYS),
    "openvins": dict(kalibr.KEYS),
    "vins": {("accel", "N"): "acc_n", ("gyro", "N"): "gyr_n", ("accel", "K"): "acc_w",
             ("gyro", "K"): "gyr_w"},
    "orbslam3": {("gyro", "N"): "IMU.NoiseGyro", ("accel", "N"): "IMU.NoiseAcc",
                 ("gyro", "K"): "IMU.GyroWalk", ("accel", "K"): "IMU.AccWalk"},
}


@dataclass
class EstimatorExport:
    """One estimator's noise file: its text, each value written and where it comes from.

    Attributes
    ----------
    fmt, estimator : str
        The format (:data:`NOISE_FORMATS`) and the estimator's name.
    text : str
        The file's text.
    values : list of dict
        Per value: ``name``, ``value`` (as written, inflated), ``unit``, ``sensor``, ``term``, ``measured``
        (the N or K it comes from) and ``formula``; for ekf2/ekf3 also the ``documented`` range and the
        autopilot's ``default``.
    factor : float
        The inflation factor applied to every value.
    step_s : float, optional
        ekf2/ekf3: the filter's prediction step the values are for.
    notes : list of str
        What the user should know (values outside a documented range, the step used).
    """

    fmt: str
    estimator: str
    text: str
    values: list[dict[str, Any]]
    factor: float
    step_s: float | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def reason(self) -> str:
        """The inflation line printed with every write (:func:`inflation.reason`)."""
        return inflation.reason(self.factor)

    def to_dict(self) -> dict[str, Any]:
        """Plain data for ``--json``: estimator, values, inflation (factor and reason), step, notes."""
        out: dict[str, Any] = {"estimator": self.estimator, "values": self.values,
                               "inflation": {"factor": self.factor, "reason": self.reason}}
        if self.step_s is not None:
            out["filter_step_s"] = self.step_s
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    def lines(self) -> list[str]:
        """The values and the inflation line as the commands print them (:func:`value_lines`)."""
        return value_lines(self.to_dict())


def value_lines(report: dict[str, Any]) -> list[str]:
    """An estimator's values, one per line with its formula and source, then the inflation line.

    Parameters
    ----------
    report : dict
        :meth:`EstimatorExport.to_dict`, or a report that holds its keys.

    Returns
    -------
    list of str
        The lines, the last one the inflation factor and its reason.
    """
    out = [f"{report['estimator']} noise values:"]
    for v in report["values"]:
        out.append(f"  {v['name']:<28} {v['value']:<10.4g} {v['unit']:<16} = {v['formula']}, "
                   f"{v['sensor']} {v['term']} {v['measured']:.4g}")
    return [*out, f"inflation: {report['inflation']['reason']}"]


def _check_rate(rate_hz: float | None, what: str) -> float | None:
    if rate_hz is not None and not rate_hz > 0:
        raise EngineInputError(f"{what} {rate_hz:g}: give a rate in Hz, above 0")
    return rate_hz


def _continuous(fmt: str, noise: dict[str, Any], factor: float, rostopic: str,
                update_rate: float | None) -> tuple[str, list[dict[str, Any]]]:
    measured = kalibr.filter_values(noise)
    values = [{"name": name, "value": factor * measured[key], "unit": kalibr.UNIT[key], "sensor": key[0],
               "term": key[1], "measured": measured[key], "formula": f"{factor:g} x {key[1]}"}
              for key, name in _CONTINUOUS_KEYS[fmt].items()]
    if fmt == "kalibr":
        text = kalibr.kalibr_yaml(noise, rostopic=rostopic, update_rate=update_rate, factor=factor)
    elif fmt == "vins":
        text = kalibr.vins_snippet(noise, factor=factor)
    elif fmt == "orbslam3":
        text = kalibr.orbslam3_snippet(noise, update_rate=update_rate, factor=factor)
    else:
        text = openvins.openvins_imu_chain(noise, rostopic=rostopic, update_rate=update_rate, factor=factor)
    return text, values


def _ekf(target: autopilot_ekf.EkfTarget, noise: dict[str, Any], device: dict[str, Any], factor: float,
         step_s: float, station_id: str, exported: str) -> tuple[str, list[dict[str, Any]]]:
    values = autopilot_ekf.ekf_parameters(target, kalibr.filter_values(noise), step_s, factor)
    params = [Param(v["name"], v["value"], "float") for v in values]
    for v, p in zip(values, params, strict=True):
        v["value"] = float(p.text())  # what the autopilot stores (float32) and reads back
    result = AutopilotExport(target.autopilot, params)
    unit = ParamsFile(device=dict(device))
    render = px4.render_px4 if target.autopilot == "px4" else ardupilot.render_ardupilot
    text = render(result, unit, station_id, exported)
    names = {term: ", ".join(p.name for p in target.parameters if p.term == term) for term in ("N", "K")}
    comments = [f"{target.estimator} IMU process noise from imu-station allan (largest axis, N and K of the "
                "noise section), for the filter's step dt = " f"{step_s * 1e3:.4g} ms:",
                f"{names['N']} = F N / sqrt(dt); {names['K']} = F K / sqrt(dt)",
                *inflation.header_lines(factor)]
    return _insert_comments(text, [f"# {c}" for c in comments]), values


def _insert_comments(text: str, comments: list[str]) -> str:
    """``comments`` at the end of the file's opening comment block (before PX4's column header line)."""
    lines = text.splitlines()
    at = next((i for i, line in enumerate(lines) if not line.startswith("#")), len(lines))
    if at and lines[at - 1].startswith("# Vehicle-Id"):
        at -= 1
    return "\n".join([*lines[:at], *comments, *lines[at:]]) + "\n"


def build_noise_export(fmt: str, noise: dict[str, Any] | None, device: dict[str, Any] | None = None, *,
                       factor: float = inflation.DEFAULT_FACTOR, ekf_rate_hz: float | None = None,
                       rostopic: str = "/imu0", update_rate: float | None = None, station_id: str = "",
                       exported: str = "", source: str = "<params>") -> EstimatorExport:
    """The noise file of estimator ``fmt`` from a ``noise`` section.

    Parameters
    ----------
    fmt : str
        One of :data:`NOISE_FORMATS`.
    noise : dict or None
        The parameter file's noise section (None: refused, naming ``source``).
    device : dict, optional
        The unit (serial, model, firmware), for the PX4 and ArduPilot headers.
    factor : float
        The inflation factor, 1 to ``inflation.MAX_FACTOR``.
    ekf_rate_hz : float, optional
        ekf2/ekf3: the filter's prediction rate (default 1/10 ms for PX4, 1/12 ms for ArduPilot).
    rostopic : str
        kalibr/openvins: the IMU topic.
    update_rate : float, optional
        kalibr/orbslam3/openvins: the IMU's rate (default the record's).
    station_id, exported : str
        ekf2/ekf3: who exports and when, for the file's header.
    source : str
        Where ``noise`` came from, for messages.

    Returns
    -------
    EstimatorExport
        The text, each value with its source and formula, the factor and notes.

    Raises
    ------
    EngineInputError
        No noise section, a term the record does not show, a factor below 1, a rate not above 0, a topic
        that is not a ROS name, an unknown format.
    """
    if fmt not in NOISE_FORMATS:
        raise EngineInputError(f"unknown estimator format {fmt!r}; known: {', '.join(NOISE_FORMATS)}")
    if not noise:
        raise EngineInputError(f"{source}: has no noise section, so there are no noise values for "
                               f"{ESTIMATORS[fmt]}; run 'imu-station allan STILL_RECORD -o {source}' first")
    factor = inflation.check_factor(factor)
    if fmt in ("kalibr", "openvins") and not ROS_NAME.fullmatch(rostopic):
        raise EngineInputError(f"rostopic {rostopic!r} is not a ROS topic name: give letters, digits, "
                               "'_' and '/' (e.g. /imu0)")
    _check_rate(ekf_rate_hz, "--ekf-rate")
    _check_rate(update_rate, "the IMU rate")
    target = autopilot_ekf.TARGETS.get(fmt)
    if target is None:
        text, values = _continuous(fmt, noise, factor, rostopic, update_rate)
        return EstimatorExport(fmt, ESTIMATORS[fmt], text, values, factor)
    step_s = 1.0 / ekf_rate_hz if ekf_rate_hz is not None else target.step_s
    text, values = _ekf(target, noise, device or {}, factor, step_s, station_id, exported)
    why = target.step_source if ekf_rate_hz is None else f"--ekf-rate {ekf_rate_hz:g}"
    notes = [f"{target.estimator} values are for a prediction step of {step_s * 1e3:.4g} ms ({why}); they "
             "scale as 1/sqrt(step): give the filter's own rate with --ekf-rate if it differs",
             f"{target.estimator}'s noise parameters are one set per vehicle, not per IMU: with several "
             "IMUs, export the noisiest"]
    notes += autopilot_ekf.range_notes(target, values)
    return EstimatorExport(fmt, ESTIMATORS[fmt], text, values, factor, step_s=step_s, notes=notes)
