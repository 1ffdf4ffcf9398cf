"""A flight controller's three IMUs in a climatic chamber, written as the autopilot's own log.

A board of three IMU instances, each with its own truth (``mocks.truth.UnitTruth``: biases, noise
and a thermal bias of eq. (3) there, ``b_T = c0 t^3 + c1 t^2 + c2 t + c3 dT^2 + c4 dT + c5 t dT + c6``),
is taken through a chamber programme (``mocks.chamber``): from ``t_min`` up to ``t_max``, a soak,
back down to ``t_min``, a soak. The instances' thermal truths differ on purpose:

- instance 0: a cubic in T alone (what PX4's and ArduPilot's own models hold exactly);
- instance 1: a cubic in T plus strong dT terms (``c4 dT``, ``c5 t dT``, ``c3 dT^2``): its bias
  while the temperature moves differs from its bias at rest, by several times the cubic's error;
- instance 2: a cubic in T plus a mild dT term.

Each instance warms itself a little above the air (eq. (1) of ``mocks.chamber``: 0, 2 and 4 degC,
time constant 300 s), so the three read different temperatures, as on a real board. The board lies
still from the first sample to the last, z up (the accelerometers read +g on z: upside down in the
autopilot's front-right-down body frame, which a thermal fit does not mind), and the values are
written in the IMUs' axes, as PX4's ``sensor_accel`` / ``sensor_gyro`` and ArduPilot's ``IMU``
messages carry them (m/s^2, rad/s, degC). The simulated rig starts every recording z up: another
pose would begin with a half turn, which no chamber log has. An autopilot logs filtered floats, not the
sensor's 16-bit codes: the truths here have no quantization.

The programme goes up and back down because the dT terms can only be told from the temperature
terms where the same temperature is crossed at different rates; a warm-up alone confounds them.

The log holds the parameters a board with no calibration applied logs (``TC_*_ENABLE`` 0 /
``INS_TCALn_ENABLE`` 0, offsets 0, scales 1, the device ids), and for PX4 a ``sensor_baro``
instance 0 (PX4's ``process_sensor_caldata.py`` needs one).

Device ids are PX4's layout (``DeviceStructure`` of ``drivers/device/Device.hpp``): bus type in
bits 0-2, bus 3-7, address 8-15, device type 16-23; ArduPilot's INS_ACC_ID values use the same
packing.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mocks.chamber import ChamberRun, ChamberSweep, chamber_sweep, scenario_sweep
from mocks.truth import STANDARD_GRAVITY, ThermalTruth, UnitTruth

LOG_FORMATS = ("ulog", "dataflash")
LOG_SUFFIXES = {"ulog": ".ulg", "dataflash": ".bin"}
INSTANCES = 3
# A log's chamber programme: -20 -> 60 -> -20 degC at 3 degC/min with 5 min soaks (63 min). At the
# default 10 Hz that is 38 000 samples per IMU: ArduPilot's script grows with their square.
LOG_SWEEP_DEFAULTS: dict[str, float] = {"t_min": -20.0, "t_max": 60.0, "rate_c_per_min": 3.0, "soak_s": 300.0}
LOG_RATE_HZ = 10.0
BOOT_US = 5_000_000  # the first sample 5 s after boot, as a log started by arming or by the SD profile
PUBLISH_LATENCY_US = 150  # sensor_* timestamp (publication) after timestamp_sample
SELF_HEATING_DEGC = (0.0, 2.0, 4.0)
SELF_HEATING_TAU_S = 300.0
T_REF = 25.0
SEA_LEVEL_PA = 101325.0
BARO_PA_PER_DEGC = 1.5  # a modest thermal drift of the barometer, so PX4's baro fit has something to fit
BUS_TYPE_SPI = 2
# (bus, device type) of the three IMUs: PX4's DRV_IMU_DEVTYPE_ICM42688P, ICM20602, BMI088 accel/gyro
DEVICES = ((1, 0x26, 0x26), (2, 0x22, 0x22), (3, 0x34, 0x35))
BARO_DEVICE_ID = 1 | (4 << 3) | (0x76 << 8) | (0x3D << 16)  # I2C bus 4, address 0x76, a BMP388

DEG = np.pi / 180.0


def device_id(bus_type: int, bus: int, address: int, devtype: int) -> int:
    """PX4's packed device id: bus type bits 0-2, bus 3-7, address 8-15, device type 16-23."""
    return (bus_type & 0x7) | ((bus & 0x1F) << 3) | ((address & 0xFF) << 8) | ((devtype & 0xFF) << 16)


@dataclass
class BoardImu:
    """One IMU instance of the simulated board: its truth and its accel and gyro device ids."""

    instance: int
    truth: UnitTruth
    accel_id: int
    gyro_id: int
    kind: str  # "cubic", "strong dT", "mild dT"


def _thermal(rng: np.random.Generator, per_degc: float, dt_lag_s: float, tdt: float,
             dt2: float) -> ThermalTruth:
    """Eq. (3) of ``mocks.truth``: a cubic in t = T - 25 degC (slope 0.5-1.5 ``per_degc``, curvature and
    cubic comparable over 40 degC) plus dT terms scaled by ``per_degc``: c4 ~ ``dt_lag_s`` (a bias that
    lags the temperature by that many seconds), c5 ~ ``tdt`` s/degC and c3 ~ ``dt2`` s^2/degC."""
    c = np.zeros((3, 7))
    sign = rng.choice([-1.0, 1.0], 3)
    c[:, 0] = rng.normal(0.0, per_degc / 400.0, 3)
    c[:, 1] = rng.normal(0.0, per_degc / 20.0, 3)
    c[:, 2] = sign * rng.uniform(0.5, 1.5, 3) * per_degc
    c[:, 3] = rng.normal(0.0, 1.0, 3) * per_degc * dt2
    c[:, 4] = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.7, 1.3, 3) * per_degc * dt_lag_s
    c[:, 5] = rng.normal(0.0, 1.0, 3) * per_degc * tdt
    c[:, 6] = rng.normal(0.0, 3.0 * per_degc, 3)
    return ThermalTruth(coeffs=c, t_ref=T_REF)


# (kind, dT lag s, t*dT s/degC, dT^2 s^2/degC) of each instance's thermal truth
KINDS = (("cubic", 0.0, 0.0, 0.0), ("strong dT", 240.0, 2.0, 500.0), ("mild dT", 30.0, 0.0, 0.0))


def board_imus(seed: int = 0, pure_cubic: bool = False, noise: bool = True) -> list[BoardImu]:
    """The three IMUs of the simulated board (module docstring).

    Parameters
    ----------
    seed : int
        Each instance is ``UnitTruth.random`` of its own seed, with the thermal truth replaced.
    pure_cubic : bool
        Every instance a cubic in T alone (no dT terms): a board whose thermal bias both autopilots'
        models hold exactly.
    noise : bool
        False: no noise terms (a validation sweep that measures the models, not the noise).

    Returns
    -------
    list of BoardImu
    """
    out = []
    for k, (kind, lag, tdt, dt2) in enumerate(KINDS):
        base = UnitTruth.random(seed * INSTANCES + k)
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), k, 0xB0A4D]))
        if pure_cubic:
            kind, lag, tdt, dt2 = "cubic", 0.0, 0.0, 0.0
        accel = replace(base.accel, resolution=None,
                        thermal=_thermal(rng, 0.3e-3 * STANDARD_GRAVITY, lag, tdt, dt2))
        gyro = replace(base.gyro, resolution=None, thermal=_thermal(rng, 0.01 * DEG, lag, tdt, dt2))
        truth = replace(base, accel=accel, gyro=gyro, serial=f"SIM-FC{int(seed):04d}-IMU{k}")
        if not noise:
            truth = truth.with_noise(None, None)
        bus, acc_type, gyro_type = DEVICES[k]
        out.append(BoardImu(k, truth, device_id(BUS_TYPE_SPI, bus, 0, acc_type),
                            device_id(BUS_TYPE_SPI, bus, 0, gyro_type), kind))
    return out


def log_sweep(options: Mapping[str, float] | None = None) -> ChamberSweep:
    """The chamber programme of a log: :data:`LOG_SWEEP_DEFAULTS` with ``options`` over them
    (``t_min``, ``t_max``, ``rate_c_per_min``, ``soak_s``)."""
    values = {**LOG_SWEEP_DEFAULTS, **(options or {})}
    return scenario_sweep(**values)


def parse_log_sweep(spec: str) -> ChamberSweep:
    """:func:`log_sweep` from ``"t_min=-20,t_max=60,rate_c_per_min=3,soak_s=300"`` (any subset).

    Raises
    ------
    ValueError
        Naming the part that is not ``key=value``, an unknown option, a value that is not a finite
        number, or one out of range.
    """
    options: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in spec.split(","))):
        key, sep, text = (x.strip() for x in part.partition("="))
        if not sep:
            raise ValueError(f"{part!r} is not key=value")
        if key not in LOG_SWEEP_DEFAULTS:
            raise ValueError(f"unknown chamber option {key!r}; known: {', '.join(LOG_SWEEP_DEFAULTS)}")
        try:
            options[key] = float(text)
        except ValueError:
            raise ValueError(f"chamber option {key}={text!r}: not a number") from None
        if not np.isfinite(options[key]):
            raise ValueError(f"chamber option {key}={text!r}: not a finite number")
    return log_sweep(options)


def board_sweep(imus: list[BoardImu], sweep: ChamberSweep, rate_hz: float = LOG_RATE_HZ,
                seed: int = 0, temp_noise_degc: float = 0.02) -> list[ChamberRun]:
    """Each IMU through ``sweep``, still and z up from the first sample, with its own self-heating.

    Parameters
    ----------
    imus : list of BoardImu
    sweep : ChamberSweep
        Its pose is replaced by ``+z`` (the rig's starting attitude) and its self-heating by the
        instance's.
    rate_hz : float
    seed : int
    temp_noise_degc : float
        Noise of each IMU's temperature reading.

    Returns
    -------
    list of ChamberRun
        One per IMU, on the same time base.
    """
    runs = []
    for imu in imus:
        own = replace(sweep, poses=("+z",), self_heating_degc=SELF_HEATING_DEGC[imu.instance % INSTANCES],
                      self_heating_tau_s=SELF_HEATING_TAU_S)
        runs.append(chamber_sweep(imu.truth, own, rate_hz=rate_hz, seed=seed * INSTANCES + imu.instance,
                                  temp_noise_degc=temp_noise_degc))
    return runs


def _time_us(run: ChamberRun) -> np.ndarray:
    return BOOT_US + np.round(run.recording.t * 1e6).astype(np.uint64)


def px4_params(imus: list[BoardImu]) -> dict[str, float | int]:
    """The calibration parameters of a PX4 board with nothing applied: TC_*_ENABLE 0, CAL_* at their
    defaults, each instance's device ids (ints are INT32 parameters, floats REAL32)."""
    out: dict[str, float | int] = {"SENS_BOARD_ROT": 0, "TC_A_ENABLE": 0, "TC_G_ENABLE": 0, "TC_B_ENABLE": 0}
    for imu in imus:
        k = imu.instance
        out[f"CAL_ACC{k}_ID"] = imu.accel_id
        out[f"CAL_GYRO{k}_ID"] = imu.gyro_id
        for axis in "XYZ":
            out[f"CAL_ACC{k}_{axis}OFF"] = 0.0
            out[f"CAL_ACC{k}_{axis}SCALE"] = 1.0
            out[f"CAL_GYRO{k}_{axis}OFF"] = 0.0
    return out


def ardupilot_params(imus: list[BoardImu]) -> dict[str, float]:
    """The calibration parameters of an ArduPilot board with nothing applied: INS_TCALn_ENABLE 0,
    offsets 0, scales 1, CALTEMP at its default -300 (never calibrated), each IMU's device ids."""
    out: dict[str, float] = {"AHRS_ORIENTATION": 0.0}
    for imu in imus:
        n = imu.instance + 1
        first = n == 1
        out[f"INS_TCAL{n}_ENABLE"] = 0.0
        out["INS_ACC_ID" if first else f"INS_ACC{n}_ID"] = float(imu.accel_id)
        out["INS_GYR_ID" if first else f"INS_GYR{n}_ID"] = float(imu.gyro_id)
        out[f"INS_ACC{n}_CALTEMP"] = -300.0
        out[f"INS_GYR{n}_CALTEMP"] = -300.0
        for axis in "XYZ":
            out[("INS_ACCOFFS_" if first else f"INS_ACC{n}OFFS_") + axis] = 0.0
            out[("INS_ACCSCAL_" if first else f"INS_ACC{n}SCAL_") + axis] = 1.0
            out[("INS_GYROFFS_" if first else f"INS_GYR{n}OFFS_") + axis] = 0.0
    return out


def _write_ulog(path: Path, imus: list[BoardImu], runs: list[ChamberRun], rate_hz: float, seed: int) -> Path:
    from mocks import ulog_writer as ul

    topics = []
    for imu, run in zip(imus, runs, strict=True):
        rec = run.recording
        sample = _time_us(run)
        common = {"timestamp": sample + PUBLISH_LATENCY_US, "timestamp_sample": sample,
                  "temperature": rec.temp, "samples": 1}
        for name, fields, values, dev in (("sensor_accel", ul.SENSOR_ACCEL, rec.acc, imu.accel_id),
                                          ("sensor_gyro", ul.SENSOR_GYRO, rec.gyro, imu.gyro_id)):
            data = ul.records(fields, len(sample), device_id=dev, x=values[:, 0], y=values[:, 1],
                              z=values[:, 2], **common)
            topics.append(ul.Topic(name, imu.instance, fields, data))
    first = runs[0].recording
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xBA40]))
    baro_temp = first.temp_true + rng.normal(0.0, 0.05, len(first.t))
    pressure = (SEA_LEVEL_PA + BARO_PA_PER_DEGC * (first.temp_true - T_REF)
                + rng.normal(0.0, 2.0, len(first.t)))
    stamps = _time_us(runs[0])
    topics.append(ul.Topic("sensor_baro", 0, ul.SENSOR_BARO,
                           ul.records(ul.SENSOR_BARO, len(stamps), timestamp=stamps + PUBLISH_LATENCY_US,
                                      timestamp_sample=stamps, device_id=BARO_DEVICE_ID, pressure=pressure,
                                      temperature=baro_temp)))
    info = {"sys_name": "PX4", "ver_hw": "IMU_STATION_SIM", "sys_uuid": f"SIMFC{int(seed):06d}"}
    return ul.write_ulog(path, topics, px4_params(imus), info, start_us=0,
                         messages=[(BOOT_US, f"simulated chamber sweep, {rate_hz:g} Hz, seed {seed}")])


def _write_dataflash(path: Path, imus: list[BoardImu], runs: list[ChamberRun], rate_hz: float) -> Path:
    from mocks import dataflash_writer as df

    messages = [df.imu_messages(_time_us(run), imu.instance, run.recording.acc, run.recording.gyro,
                                run.recording.temp, rate_hz) for imu, run in zip(imus, runs, strict=True)]
    return df.write_dataflash(path, messages, ardupilot_params(imus), params_time_us=BOOT_US // 2)


def write_board_log(path: str | Path, log_format: str, imus: list[BoardImu], runs: list[ChamberRun],
                    rate_hz: float, seed: int = 0) -> Path:
    """Write the runs of :func:`board_sweep` as a PX4 ULog (``ulog``) or an ArduPilot DataFlash log
    (``dataflash``).

    Raises
    ------
    ValueError
        An unknown format.
    """
    path = Path(path)
    if log_format == "ulog":
        return _write_ulog(path, imus, runs, rate_hz, seed)
    if log_format == "dataflash":
        return _write_dataflash(path, imus, runs, rate_hz)
    raise ValueError(f"log format {log_format!r}: use one of {', '.join(LOG_FORMATS)}")


def simulate_board_log(path: str | Path, log_format: str, seed: int = 0, sweep: ChamberSweep | None = None,
                       rate_hz: float = LOG_RATE_HZ, pure_cubic: bool = False,
                       noise: bool = True) -> tuple[list[BoardImu], list[ChamberRun]]:
    """:func:`board_imus`, :func:`board_sweep` and :func:`write_board_log` in one call.

    Returns
    -------
    tuple
        The board's IMUs (their truths) and the runs (true temperature, rate and thermal bias per sample).
    """
    imus = board_imus(seed, pure_cubic=pure_cubic, noise=noise)
    runs = board_sweep(imus, sweep or log_sweep(), rate_hz=rate_hz, seed=seed,
                       temp_noise_degc=0.02 if noise else 0.0)
    write_board_log(path, log_format, imus, runs, rate_hz, seed)
    return imus, runs
