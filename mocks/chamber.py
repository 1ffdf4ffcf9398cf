"""A climatic-chamber sweep of the simulated unit: temperature ramps and soaks, one pose or several.

The chamber air follows a piecewise-linear profile: from ``start_degc`` up to ``high_degc``,
a soak, down to ``low_degc``, a soak, back to ``start_degc``, repeated ``cycles`` times, at
``ramp_degc_per_min`` (one speed, or one per cycle). The unit may warm itself on top of that
(power-on self-heating)::

    T(t) = T_chamber(t) + rise (1 - exp(-t / tau))                                     (1)

The unit sits on a fixture in one pose, or a turntable cycles it through several poses
(``pose_hold_s`` each, joined by smooth moves). Samples come from :func:`mocks.rig.simulate`
with the unit's own truth (its ``ThermalTruth`` polynomial included); the chamber adds, per
triad, a bias of any function of the true T and dT, a hysteresis that remembers whether the
unit was last heated or cooled, and for the accelerometer an optional scale factor that drifts
linearly with temperature::

    raw = (I + diag(s (T - T_ref))) M f + b + b_T(T, dT) + extra(T, dT) + a m(t) + n       (2)

with m(t) = +1 after the last heating, -1 after the last cooling (held through soaks; 0
before the first ramp): packaging stress that relaxes one way or the other, which no function
of T and dT alone can follow.

quantized once, after everything is added, to the unit's resolution. The temperature is read
through a sensor with Gaussian noise and an optional resolution (real sensors report steps
of 1/16 or 1/256 degC).

The ``chamber`` scenario of the simulated unit (``mocks.device``, ``sim://?scenario=chamber``,
``imu-station simulate --scenario chamber``) is :func:`scenario_sweep`: the unit lying flat
(+z up) from ``t_min`` up to ``t_max`` and back at ``rate_c_per_min``, soaking ``soak_s`` at
each end, then held at ``t_min``; its samples carry the unit's own thermal bias (eq. (3) of
``mocks.truth``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from mocks.rig import Move, Recording, Segment, Static, TemperatureProfile, ramp, simulate
from mocks.truth import STANDARD_GRAVITY, SensorTruth, ThermalTruth, UnitTruth

BiasFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class ChamberSweep:
    """The chamber programme and the fixture: temperatures, speeds, soaks, poses."""

    low_degc: float = -10.0
    high_degc: float = 60.0
    start_degc: float = 25.0
    ramp_degc_per_min: float | Sequence[float] = 1.0
    soak_s: float = 600.0
    cycles: int = 1
    self_heating_degc: float = 0.0
    self_heating_tau_s: float = 300.0
    poses: Sequence[str] = ("+z",)
    pose_hold_s: float = 60.0
    move_s: float = 2.0

    def __post_init__(self) -> None:
        if not self.low_degc <= self.start_degc <= self.high_degc:
            raise ValueError(f"start {self.start_degc} degC must lie within "
                             f"[{self.low_degc}, {self.high_degc}]")
        if self.cycles < 1 or not self.poses:
            raise ValueError("a sweep needs at least one cycle and one pose")
        if any(r <= 0 for r in self.rates_degc_per_min()):
            raise ValueError("ramp_degc_per_min must be positive")

    def rates_degc_per_min(self) -> list[float]:
        """The ramp speed of each cycle (one number: the same for every cycle)."""
        rates = np.atleast_1d(np.asarray(self.ramp_degc_per_min, float))
        if len(rates) == 1:
            return [float(rates[0])] * self.cycles
        if len(rates) != self.cycles:
            raise ValueError(f"{len(rates)} ramp speeds for {self.cycles} cycles: give one, or one per cycle")
        return [float(r) for r in rates]

    def chamber_points(self) -> list[tuple[float, float]]:
        """(time s, chamber degC) corners of the programme."""
        points = [(0.0, self.start_degc)]
        t, temp = 0.0, self.start_degc
        legs = [(self.high_degc, self.soak_s), (self.low_degc, self.soak_s), (self.start_degc, 0.0)]
        for per_min in self.rates_degc_per_min():
            rate = per_min / 60.0
            for target, soak in legs:
                if target != temp:
                    t += abs(target - temp) / rate
                    temp = target
                    points.append((t, temp))
                if soak > 0:
                    t += soak
                    points.append((t, temp))
        return points

    def profile(self) -> UnitTemperature:
        """The unit's true temperature over time, eq. (1), held at the last corner after the end."""
        return UnitTemperature(ramp(self.chamber_points()), self.self_heating_degc, self.self_heating_tau_s)

    @property
    def duration_s(self) -> float:
        """Length of the whole programme, s."""
        return self.chamber_points()[-1][0]

    def segments(self) -> list[Segment]:
        """The fixture's motion: hold one pose throughout, or cycle the poses until the end."""
        if len(self.poses) == 1:
            return [Static(self.poses[0], self.duration_s)]
        segments: list[Segment] = []
        t, i = 0.0, 0
        while t < self.duration_s:
            segments += [Move(self.move_s), Static(self.poses[i % len(self.poses)], self.pose_hold_s)]
            t += self.move_s + self.pose_hold_s
            i += 1
        return segments


class UnitTemperature:
    """The unit's true temperature, eq. (1), and its exact rate (what the rig passes on as dT).

    Parameters
    ----------
    chamber : the chamber air temperature over time.
    rise_degc, tau_s : the unit's self-heating above the air, and its time constant.
    """

    def __init__(self, chamber: TemperatureProfile, rise_degc: float = 0.0, tau_s: float = 300.0):
        self.chamber = chamber
        self.rise = float(rise_degc)
        self.tau = float(tau_s)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """T(t) of eq. (1), degC, for times ``t`` in s."""
        t = np.asarray(t, float)
        return self.chamber(t) + self.rise * (1.0 - np.exp(-np.maximum(t, 0.0) / self.tau))

    def rate(self, t: np.ndarray) -> np.ndarray:
        """dT/dt of eq. (1), degC/s.

        Parameters
        ----------
        t : ndarray, (N,)
            s.

        Returns
        -------
        ndarray, (N,)
        """
        t = np.asarray(t, float)
        heating = self.rise / self.tau * np.exp(-np.maximum(t, 0.0) / self.tau)
        return self.chamber.rate(t) + np.where(t >= 0, heating, 0.0)


@dataclass
class ChamberRun:
    """A chamber recording and the thermal truth behind it.

    ``thermal_accel``/``thermal_gyro`` (N, 3): the whole temperature-dependent bias each
    sample carries (the truth polynomial, the chamber's extra function and the hysteresis), at
    the true T and dT; ``scale_accel`` (N, 3): the part of the raw accel from the scale drift
    of eq. (2).
    """

    recording: Recording
    sweep: ChamberSweep
    thermal_accel: np.ndarray
    thermal_gyro: np.ndarray
    scale_accel: np.ndarray

    def to_capture(self):  # -> station.acquisition.capture.Capture (imported lazily)
        """The recording as the station's capture (what a capture file would hold)."""
        return self.recording.to_capture()


def _finish(sensor: SensorTruth, raw: np.ndarray) -> np.ndarray:
    """Saturate and quantize as eq. (2) of ``mocks.truth`` does, once every term is in."""
    raw = np.clip(raw, -sensor.saturation, sensor.saturation)
    if sensor.resolution:
        raw = np.round(raw / sensor.resolution) * sensor.resolution
    return raw


def _heating_memory(dtemp: np.ndarray) -> np.ndarray:
    """m(t) of eq. (2): the sign of the last non-zero dT, 0 before the first."""
    sign = np.sign(dtemp)
    index = np.where(sign != 0, np.arange(len(sign)), -1)
    last = np.maximum.accumulate(index)
    return np.where(last >= 0, sign[np.maximum(last, 0)], 0.0)


def chamber_sweep(
    truth: UnitTruth,
    sweep: ChamberSweep | None = None,
    rate_hz: float = 10.0,
    seed: int = 0,
    accel_bias: BiasFunction | None = None,
    gyro_bias: BiasFunction | None = None,
    accel_scale_per_degc: Sequence[float] | None = None,
    accel_hysteresis: Sequence[float] | None = None,
    gyro_hysteresis: Sequence[float] | None = None,
    scale_t_ref: float = 25.0,
    temp_noise_degc: float = 0.02,
    temp_resolution_degc: float | None = None,
) -> ChamberRun:
    """Record ``truth`` through the chamber programme ``sweep``, eq. (1)-(2).

    ``accel_bias``/``gyro_bias``: extra bias functions f(T, dT) -> (N, 3) of the true
    temperature and rate, added to the truth's own thermal polynomial. ``*_hysteresis``: the
    amplitude a (3,) of eq. (2). ``accel_scale_per_degc``: s (3,), relative to ``scale_t_ref``.
    Same arguments, same arrays.

    Parameters
    ----------
    truth : UnitTruth
    sweep : ChamberSweep, optional
        Default ``ChamberSweep()``.
    rate_hz : float
    seed : int
    accel_bias, gyro_bias : callable, optional
    accel_scale_per_degc : sequence of float, optional
    accel_hysteresis, gyro_hysteresis : sequence of float, optional
    scale_t_ref : float
        degC.
    temp_noise_degc : float
        Noise of the temperature reading.
    temp_resolution_degc : float, optional
        Resolution of the temperature reading.

    Returns
    -------
    ChamberRun
    """
    sweep = sweep or ChamberSweep()
    # Quantization is applied once at the end, after the chamber's own terms.
    plain = replace(truth, accel=replace(truth.accel, resolution=None, saturation=np.inf),
                    gyro=replace(truth.gyro, resolution=None, saturation=np.inf))
    rec = simulate(plain, sweep.segments(), rate_hz=rate_hz, seed=seed, temperature=sweep.profile(),
                   temp_noise_degc=temp_noise_degc)
    temp, dtemp = rec.temp_true, rec.dtemp_true
    thermal_acc = truth.accel.thermal.bias(temp, dtemp)
    thermal_gyr = truth.gyro.thermal.bias(temp, dtemp)
    acc, gyro = rec.acc.copy(), rec.gyro.copy()
    if accel_bias is not None:
        extra = np.asarray(accel_bias(temp, dtemp), float).reshape(len(temp), 3)
        acc += extra
        thermal_acc = thermal_acc + extra
    if gyro_bias is not None:
        extra = np.asarray(gyro_bias(temp, dtemp), float).reshape(len(temp), 3)
        gyro += extra
        thermal_gyr = thermal_gyr + extra
    memory = _heating_memory(dtemp)
    for amplitude, raw, thermal in ((accel_hysteresis, acc, thermal_acc),
                                    (gyro_hysteresis, gyro, thermal_gyr)):
        if amplitude is not None:
            extra = memory[:, None] * np.asarray(amplitude, float).reshape(3)
            raw += extra
            thermal += extra
    scale_part = np.zeros_like(acc)
    if accel_scale_per_degc is not None:
        s = np.asarray(accel_scale_per_degc, float).reshape(3)
        scale_part = (temp - scale_t_ref)[:, None] * s * (rec.true_specific_force @ truth.accel.matrix.T)
        acc += scale_part
    rec.acc = _finish(truth.accel, acc)
    rec.gyro = _finish(truth.gyro, gyro)
    rec.truth = truth
    if temp_resolution_degc:
        rec.temp = np.round(rec.temp / temp_resolution_degc) * temp_resolution_degc
    return ChamberRun(rec, sweep, thermal_acc, thermal_gyr, scale_part)


def cubic_rate_unit(seed: int, accel_per_degc: float = 0.3e-3 * STANDARD_GRAVITY,
                    gyro_per_degc: float = 0.01 * np.pi / 180.0, rate_lag_s: float = 60.0,
                    t_ref: float = 25.0) -> UnitTruth:
    """``UnitTruth.random(seed)`` whose thermal bias is a cubic in T plus a dT term, per axis::

        b_T = c3 t^3 + c2 t^2 + c1 t + f dT + h,   t = T - t_ref

    with c1 ~ N(0, per_degc), c2 ~ N(0, per_degc / 20 degC), c3 ~ N(0, per_degc / 400 degC^2)
    (curvature comparable to the slope over a 40 degC span), f ~ N(0, per_degc * rate_lag_s)
    (a bias that follows the temperature some tens of seconds late) and h ~ N(0, 5 per_degc).

    Parameters
    ----------
    seed : int
    accel_per_degc, gyro_per_degc : float
        Scale of the coefficients, m/s^2/degC and rad/s/degC.
    rate_lag_s : float
    t_ref : float
        degC.

    Returns
    -------
    UnitTruth
    """
    truth = UnitTruth.random(seed)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xC4A3]))

    def coeffs(per_degc: float) -> np.ndarray:
        c = np.zeros((3, 7))
        c[:, 0] = rng.normal(0.0, per_degc / 400.0, 3)
        c[:, 1] = rng.normal(0.0, per_degc / 20.0, 3)
        c[:, 2] = rng.normal(0.0, per_degc, 3)
        c[:, 4] = rng.normal(0.0, per_degc * rate_lag_s, 3)
        c[:, 6] = rng.normal(0.0, 5.0 * per_degc, 3)
        return c

    return replace(truth, accel=replace(truth.accel, thermal=ThermalTruth(coeffs(accel_per_degc), t_ref)),
                   gyro=replace(truth.gyro, thermal=ThermalTruth(coeffs(gyro_per_degc), t_ref)))


# The chamber scenario's options (URL and --chamber names) and their defaults: -20 -> +60 -> -20 degC
# at 1 degC/min with 10 min soaks, 3 h in all.
SCENARIO_DEFAULTS: dict[str, float] = {"t_min": -20.0, "t_max": 60.0, "rate_c_per_min": 1.0, "soak_s": 600.0}


def scenario_sweep(t_min: float = -20.0, t_max: float = 60.0, rate_c_per_min: float = 1.0,
                   soak_s: float = 600.0) -> ChamberSweep:
    """The programme of the simulated unit's ``chamber`` scenario.

    Parameters
    ----------
    t_min, t_max : the temperatures the chamber sweeps between, degC; it starts at ``t_min``.
    rate_c_per_min : ramp speed, degC/min.
    soak_s : hold at ``t_max`` and then at ``t_min``, s.

    Returns
    -------
    ChamberSweep
        One pose (+z up); up from ``t_min`` to ``t_max``, a soak, down to ``t_min``, a soak.

    Raises
    ------
    ValueError
        Naming the option out of range.
    """
    if not t_min < t_max:
        raise ValueError(f"t_min {t_min:g} must be below t_max {t_max:g}")
    if not rate_c_per_min > 0:
        raise ValueError(f"rate_c_per_min {rate_c_per_min:g} must be positive")
    if not soak_s >= 0:
        raise ValueError(f"soak_s {soak_s:g} must not be negative")
    return ChamberSweep(low_degc=t_min, high_degc=t_max, start_degc=t_min, ramp_degc_per_min=rate_c_per_min,
                        soak_s=soak_s)


def sweep_from_options(options: Mapping[str, str]) -> ChamberSweep:
    """:func:`scenario_sweep` from text options (``t_min``, ``t_max``, ``rate_c_per_min``, ``soak_s``).

    Raises
    ------
    ValueError
        Naming an unknown option, a value that is not a number, or one out of range.

    Parameters
    ----------
    options : mapping of str to str

    Returns
    -------
    ChamberSweep
    """
    values = dict(SCENARIO_DEFAULTS)
    for key, text in options.items():
        if key not in SCENARIO_DEFAULTS:
            raise ValueError(f"unknown chamber option {key!r}; known: {', '.join(SCENARIO_DEFAULTS)}")
        try:
            values[key] = float(text)
        except ValueError:
            raise ValueError(f"chamber option {key}={text!r}: not a number") from None
        if not np.isfinite(values[key]):
            raise ValueError(f"chamber option {key}={text!r}: not a finite number")
    return scenario_sweep(**values)


def parse_chamber_spec(spec: str) -> ChamberSweep:
    """:func:`sweep_from_options` from ``"t_min=-20,t_max=60,rate_c_per_min=1,soak_s=600"`` (any subset).

    Raises
    ------
    ValueError
        Naming the part that is not ``key=value`` or the option at fault.

    Parameters
    ----------
    spec : str

    Returns
    -------
    ChamberSweep
    """
    options: dict[str, str] = {}
    for part in filter(None, (p.strip() for p in spec.split(","))):
        key, sep, value = part.partition("=")
        if not sep:
            raise ValueError(f"{part!r} is not key=value")
        options[key.strip()] = value.strip()
    return sweep_from_options(options)


def describe_scenario(sweep: ChamberSweep) -> str:
    """One line for a person: range, speed, soaks and length of a :func:`scenario_sweep` programme.

    Parameters
    ----------
    sweep : ChamberSweep

    Returns
    -------
    str
    """
    rate = sweep.rates_degc_per_min()[0]
    return (f"{sweep.low_degc:g} -> {sweep.high_degc:g} -> {sweep.low_degc:g} degC at {rate:g} degC/min, "
            f"soaks of {sweep.soak_s:g} s, {sweep.duration_s:g} s of device clock, then held at "
            f"{sweep.low_degc:g} degC")
