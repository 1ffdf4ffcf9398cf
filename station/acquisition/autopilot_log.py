"""PX4 ULog (``.ulg``) and ArduPilot DataFlash (``.bin``) logs as the station's captures, one per IMU.

A flight controller carries two or three IMUs; each becomes a :class:`Capture` in SI units (m/s^2, rad/s,
degC, s) in the board's own axes, with what the autopilot had done to the samples taken back out:

- **PX4** ``sensor_accel`` / ``sensor_gyro`` (``multi_id`` = instance): the drivers' output, timed by
  ``timestamp_sample`` (us), in the board's axes (the driver's chip rotation applied, ``SENS_BOARD_ROT``
  not), **before** the thermal compensation and the calibration, which PX4's sensors module applies
  downstream (``TC_An``/``TC_Gn`` matched by device id, then ``CAL_ACCn_*``/``CAL_GYROn_*``; see
  :mod:`station.export.autopilot.px4`). PX4's own ``process_sensor_caldata.py`` fits these topics as they
  are, for that reason. So nothing is taken out; the notes say which of the log's parameters would apply.
  The accelerometer's and gyroscope's topics are separate: the gyro sample of the same time (nearest, or
  interpolated where the two rates differ) is paired with each accelerometer sample.
- **ArduPilot** ``IMU`` (``I`` = instance; ``IMU2``/``IMU3`` in older logs): logged **after** the
  corrections and the board rotation, ``AP_InertialSensor_Backend::_rotate_and_correct_accel``::

      logged = R_board (((raw - P(T) + P(T_cal)) - INS_ACCOFFS) .* INS_ACCSCAL)     (gyro: no scale)

  so, with ``remove_autopilot_correction``, each is undone in reverse order (eq. 1 inverted)::

      raw = (R_board^T logged) ./ INS_ACCSCAL + INS_ACCOFFS + P(T) - P(T_cal)

  R_board from ``AHRS_ORIENTATION`` (pymavlink's table of ArduPilot's rotations), the offsets and
  ``P(T) - P(T_cal)`` evaluated by the ArduPilot export's own functions
  (:func:`station.export.autopilot.ardupilot.ardupilot_offsets`), so the model is written once.

The log's first magnetometer comes with each IMU as the capture's ``mag`` (microtesla, at the IMU's
times; PX4 ``sensor_mag`` raw, ArduPilot ``MAG`` with its compass correction taken out):
:mod:`station.acquisition.log_magnetometer`.

Timing: the rate is the median timestamp step (the true rate, not the configured one); a step over 1.5
median steps is a gap. Both are in :class:`LogImu` and in the notes each command prints.

Why this module is long: the two autopilots' conversions stand side by side with the one API every
command and the multi-IMU calibration use (listing, choosing and reading an instance, the notes), so
that what each log holds and what is done to it reads in one place; the byte-level decoding is apart
(:mod:`station.acquisition.ulog_reader`, :mod:`station.acquisition.dataflash_reader`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from station.acquisition.capture_data import Capture
from station.errors import InputFileError

GAP_FACTOR = 1.5
LOG_SUFFIXES = (".ulg", ".bin")
AXES = ("X", "Y", "Z")
NOTES_KEY = "autopilot_log_notes"  # where a capture made from a log carries its notes (Capture.link)


@dataclass(frozen=True)
class LogImu:
    """One IMU instance found in a log."""

    instance: int  # 0-based as the autopilot numbers them (PX4 multi_id; ArduPilot IMU.I)
    device_id: int | None
    rate_hz: float  # the true rate from the timestamps (median), not the configured one
    samples: int
    gaps: int  # timestamp gaps > 1.5 median steps
    has_temperature: bool

    def describe(self) -> str:
        """``instance 1 (device 1310996): 250 Hz, 15000 samples, 2 gaps`` as the messages say it."""
        device = f" (device {self.device_id})" if self.device_id is not None else ""
        gaps = f", {self.gaps} gap{'s' if self.gaps != 1 else ''}" if self.gaps else ""
        temp = "" if self.has_temperature else ", no temperature"
        return f"instance {self.instance}{device}: {self.rate_hz:.6g} Hz, {self.samples} samples{gaps}{temp}"


def _timing(t_us: np.ndarray) -> tuple[float, int]:
    """Median-step rate (Hz) and the number of steps over 1.5 median steps."""
    if len(t_us) < 2:
        return float("nan"), 0
    step = np.diff(t_us.astype(np.float64))
    median = float(np.median(step))
    if median <= 0:
        return float("nan"), 0
    return 1e6 / median, int(np.count_nonzero(step > GAP_FACTOR * median))


def _has_temperature(temp: np.ndarray | None) -> bool:
    # PX4's simulation writes 0.0 for a sensor without one: a constant zero is no temperature
    return temp is not None and bool(np.isfinite(temp).any()) and not bool((temp == 0).all())


@dataclass
class AutopilotLog:
    """A PX4 or ArduPilot log: its IMUs, its parameters, and each IMU as a :class:`Capture`."""

    path: Path
    kind: str  # "ulog" | "dataflash"
    imus: list[LogImu]
    params: dict[str, float]
    info: dict[str, Any] = field(default_factory=dict)
    _raw: dict[int, dict[str, np.ndarray]] = field(default_factory=dict, repr=False)
    _log_notes: list[str] = field(default_factory=list, repr=False)
    _notes: list[str] = field(default_factory=list, repr=False)
    _mags: dict[int, Any] = field(default_factory=dict, repr=False)  # log_magnetometer.MagSeries by instance

    def imu(self, instance: int) -> LogImu:
        """The IMU ``instance``.

        Raises
        ------
        InputFileError
            The log has no such instance (naming those it has).
        """
        for imu in self.imus:
            if imu.instance == instance:
                return imu
        raise InputFileError(self.path, f"has no IMU instance {instance}; its IMUs are: {self.listing()}")

    def listing(self) -> str:
        """Every IMU, ``instance 0 (device ...): rate, samples``, separated by ``;``."""
        return "; ".join(imu.describe() for imu in self.imus) or "none"

    def choose(self, instance: int | None) -> int:
        """The instance to read: ``instance``, or the only one.

        Raises
        ------
        InputFileError
            Several IMUs and no instance given (naming them, asking for --instance), none, or no such one.
        """
        if not self.imus:
            what = ("sensor_accel and sensor_gyro topics (log them: SDLOG_PROFILE's 'thermal calibration' or "
                    "'high rate' bit)" if self.kind == "ulog" else "IMU messages (LOG_BITMASK's IMU bit)")
            raise InputFileError(self.path, f"has no {what}; record a log with the IMU logged")
        if instance is None:
            if len(self.imus) > 1:
                raise InputFileError(self.path, f"has {len(self.imus)} IMUs: {self.listing()}; choose one "
                                     "with --instance N")
            return self.imus[0].instance
        return self.imu(instance).instance

    def notes(self) -> list[str]:
        """What was converted or taken out of the captures made so far, one sentence each."""
        return list(dict.fromkeys(self._log_notes + self._notes))

    def captures(self, remove_autopilot_correction: bool = True) -> dict[int, Capture]:
        """Every IMU as a capture, by instance.

        Parameters
        ----------
        remove_autopilot_correction : bool
            See :meth:`capture`.

        Returns
        -------
        dict of int to Capture
        """
        return {imu.instance: self.capture(imu.instance, remove_autopilot_correction) for imu in self.imus}

    def capture(self, instance: int, remove_autopilot_correction: bool = True) -> Capture:
        """IMU ``instance`` as a capture: t (s), acc (m/s^2), gyro (rad/s), temp (degC) in the board's axes.

        Parameters
        ----------
        instance : int
            0-based, as the autopilot numbers it.
        remove_autopilot_correction : bool
            Take out what the autopilot applied before logging (ArduPilot: the board rotation, the
            offsets and scales, the temperature calibration; PX4's raw topics have none applied).

        Returns
        -------
        Capture
            With ``link[NOTES_KEY]`` the notes of this capture, and ``device`` naming the log's
            instance and device ids.

        Raises
        ------
        InputFileError
            No such instance, or a board rotation the station cannot undo.
        """
        from station.acquisition.log_magnetometer import field_at

        imu = self.imu(instance)
        if self.kind == "ulog":
            capture, notes = _ulog_capture(self, imu)
        else:
            capture, notes = _dataflash_capture(self, imu, remove_autopilot_correction)
        try:
            capture.mag, mag_notes = field_at(self._mags, capture.t, self.kind, self.params,
                                              remove_autopilot_correction)
        except ValueError as exc:
            raise InputFileError(self.path, f"its magnetometer's correction cannot be taken out: {exc}",
                                 column="COMPASS_ORIENT") from None
        notes += mag_notes
        timing = f"{imu.describe()} (rate from the timestamps)"
        notes = [timing, *notes]
        capture.link = {NOTES_KEY: [*self._log_notes, *notes], "gaps": imu.gaps, "rate_hz": imu.rate_hz}
        self._notes += notes
        return capture


def log_notes(capture: Capture) -> list[str]:
    """The notes a capture made from an autopilot log carries (none for other captures).

    Parameters
    ----------
    capture : Capture

    Returns
    -------
    list of str
    """
    return list(capture.link.get(NOTES_KEY, [])) if isinstance(capture.link, dict) else []


def read_log_capture(path: str | Path, instance: int | None = None,
                     remove_autopilot_correction: bool = True) -> Capture:
    """One IMU of a log as a capture: ``instance``, or the only one.

    Parameters
    ----------
    path : str or Path
    instance : int, optional
        Needed when the log has several IMUs.
    remove_autopilot_correction : bool
        See :meth:`AutopilotLog.capture`.

    Returns
    -------
    Capture

    Raises
    ------
    InputFileError
        Several IMUs and no ``instance`` (naming each: instance, device id, rate, samples), no such
        instance, or a log that cannot be read.
    """
    log = open_log(path)
    return log.capture(log.choose(instance), remove_autopilot_correction)


def is_autopilot_log(path: str | Path) -> bool:
    """A ``.ulg`` or ``.bin`` file, or a file that starts as a ULog or a DataFlash log does.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    from station.acquisition.dataflash_reader import is_dataflash
    from station.acquisition.ulog_reader import is_ulog

    path = Path(path)
    if path.suffix.lower() in LOG_SUFFIXES:
        return True
    return path.is_file() and (is_ulog(path) or is_dataflash(path))


def open_log(path: str | Path) -> AutopilotLog:
    """Read a PX4 ULog or an ArduPilot DataFlash log (told apart by their first bytes).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    AutopilotLog

    Raises
    ------
    InputFileError
        A file that does not exist, is neither kind of log, or cannot be decoded.
    """
    from station.acquisition.dataflash_reader import is_dataflash
    from station.acquisition.ulog_reader import is_ulog

    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "does not exist; give a PX4 log (.ulg) or an ArduPilot log (.bin)")
    if is_ulog(path):
        return _open_ulog(path)
    if is_dataflash(path):
        return _open_dataflash(path)
    raise InputFileError(path, "is neither a PX4 ULog nor an ArduPilot DataFlash log (its first bytes are "
                         "neither's); give the log the autopilot wrote, or a capture CSV or .h5")


# --- PX4 -------------------------------------------------------------------------------------------------

def _device_id(records: np.ndarray) -> int | None:
    if "device_id" not in (records.dtype.names or ()) or len(records) == 0:
        return None
    return int(np.median(records["device_id"]))


def _open_ulog(path: Path) -> AutopilotLog:
    from station.acquisition.ulog_reader import read_ulog

    data = read_ulog(path)
    log_notes = []
    if data.dropouts:
        lost = sum(d for _, d in data.dropouts)
        log_notes.append(f"the logger dropped data {len(data.dropouts)} time(s), {lost} ms in all "
                         "(ULog dropout messages): those stretches are gaps")
    if data.corrupt_bytes:
        log_notes.append(f"{data.corrupt_bytes} corrupt bytes skipped (read on from the next sync message)")
    if data.truncated:
        log_notes.append("the last message is cut by the end of the file: left out")
    accel = {m: r for (name, m), r in data.topics.items() if name == "sensor_accel"}
    gyro = {m: r for (name, m), r in data.topics.items() if name == "sensor_gyro"}
    imus, raw = [], {}
    for m in sorted(set(accel) & set(gyro)):
        a, g = accel[m], gyro[m]
        if len(a) < 1 or len(g) < 1:
            continue
        rate, gaps = _timing(a["timestamp_sample"])
        temp = a["temperature"] if "temperature" in (a.dtype.names or ()) else None
        imus.append(LogImu(m, _device_id(a), rate, len(a), gaps, _has_temperature(temp)))
        raw[m] = {"accel": a, "gyro": g}
    alone = sorted(set(accel) ^ set(gyro))
    if alone:
        log_notes.append(f"sensor_accel/sensor_gyro instance(s) {alone} have no partner topic: left out")
    from station.acquisition.log_magnetometer import px4_mags

    return AutopilotLog(path, "ulog", imus, dict(data.params), dict(data.info), raw, log_notes,
                        _mags=px4_mags(data.topics))


def _pair(t_a: np.ndarray, t_g: np.ndarray, gyro: np.ndarray) -> tuple[np.ndarray, np.ndarray, str | None]:
    """The gyro at each accelerometer time: kept accel rows, gyro rows, how (None: the times agree)."""
    if len(t_a) == len(t_g) and np.array_equal(t_a, t_g):
        return np.arange(len(t_a)), gyro, None
    ta, tg = t_a.astype(np.int64), t_g.astype(np.int64)
    inside = np.flatnonzero((ta >= tg[0]) & (ta <= tg[-1]))
    step_a = np.median(np.diff(ta)) if len(ta) > 1 else 0.0
    step_g = np.median(np.diff(tg)) if len(tg) > 1 else 0.0
    right = np.clip(np.searchsorted(tg, ta), 1, max(len(tg) - 1, 1))
    left = right - 1
    nearest = np.where(np.abs(tg[np.minimum(right, len(tg) - 1)] - ta) < np.abs(ta - tg[left]),
                       np.minimum(right, len(tg) - 1), left)
    offset = ta - tg[nearest]
    same_rate = step_g > 0 and abs(step_a / step_g - 1.0) < 0.01
    if same_rate and np.all(np.abs(offset) <= 0.5 * step_g) and len(np.unique(nearest)) == len(nearest):
        # one gyro sample per accelerometer sample: pairing keeps the gyro's noise as it is
        return (np.arange(len(ta)), gyro[nearest],
                f"each sensor_accel sample paired with the nearest sensor_gyro sample (median offset "
                f"{np.median(offset):.0f} us)")
    values = np.column_stack([np.interp(ta[inside], tg, gyro[:, j]) for j in range(3)])
    dropped = len(ta) - len(inside)
    return (inside, values, f"sensor_gyro ({1e6 / step_g if step_g else float('nan'):.6g} Hz) linearly "
            f"interpolated to the sensor_accel times ({1e6 / step_a if step_a else float('nan'):.6g} Hz)"
            + (f"; {dropped} accelerometer samples outside the gyro's span left out" if dropped else ""))


def _xyz(records: np.ndarray) -> np.ndarray:
    return np.column_stack([records[c].astype(np.float64) for c in ("x", "y", "z")])


def _px4_applied(log: AutopilotLog, sensor: str, device_id: int | None) -> list[str]:
    """The log's TC_* and CAL_* blocks PX4 would apply to ``device_id`` downstream of the raw topic."""
    p = log.params
    letter, cal = ("A", "CAL_ACC") if sensor == "accel" else ("G", "CAL_GYRO")
    found: list[str] = []
    if device_id is None:
        return found
    # in PX4's order: the thermal offset first, then the calibration
    found += [f"TC_{letter}{k}" for k in range(4)
              if p.get(f"TC_{letter}{k}_ID") == device_id and p.get(f"TC_{letter}_ENABLE") == 1]
    found += [f"{cal}{k}" for k in range(4) if p.get(f"{cal}{k}_ID") == device_id]
    return found


def _ulog_capture(log: AutopilotLog, imu: LogImu) -> tuple[Capture, list[str]]:
    a, g = log._raw[imu.instance]["accel"], log._raw[imu.instance]["gyro"]
    rows, gyro, how = _pair(a["timestamp_sample"], g["timestamp_sample"], _xyz(g))
    a = a[rows]
    temp = a["temperature"].astype(np.float64) if imu.has_temperature else None
    gyro_id = _device_id(g)
    notes = [] if how is None else [how]
    applied = _px4_applied(log, "accel", imu.device_id) + _px4_applied(log, "gyro", gyro_id)
    what = (f"the log's {', '.join(applied)} (matched by device id) would apply downstream; "
            if applied else "")
    notes.append(f"sensor_accel/sensor_gyro are PX4's raw driver output, before thermal compensation and "
                 f"calibration: {what}nothing taken out")
    board = log.params.get("SENS_BOARD_ROT", 0)
    if board:
        notes.append(f"axes: the board's own (SENS_BOARD_ROT {board:g}, board to vehicle, is not applied "
                     "to these topics)")
    if not imu.has_temperature:
        notes.append("sensor_accel carries no temperature (all zero or NaN): temp left unknown")
    device = _device(log, imu, gyro_id, "ulog")
    capture = Capture(t=a["timestamp_sample"].astype(np.float64) * 1e-6, acc=_xyz(a), gyro=gyro, temp=temp,
                      device=device, source=str(log.path))
    return capture, notes


def _device(log: AutopilotLog, imu: LogImu, gyro_id: int | None, protocol: str) -> dict[str, Any]:
    info = log.info
    model = str(info.get("ver_hw", "")) or ("PX4 board" if protocol == "ulog" else "ArduPilot board")
    device: dict[str, Any] = {"model": f"{model} IMU {imu.instance}", "protocol": protocol,
                              "rate_hz": round(imu.rate_hz, 6), "instance": imu.instance}
    firmware = info.get("ver_sw_release_str") or info.get("ver_sw")
    if firmware:
        device["firmware"] = str(firmware)
    if info.get("sys_uuid"):
        device["serial"] = f"{info['sys_uuid']}-imu{imu.instance}"
    if imu.device_id is not None:
        device["accel_device_id"] = imu.device_id
    if gyro_id is not None:
        device["gyro_device_id"] = gyro_id
    return device


# --- ArduPilot -------------------------------------------------------------------------------------------

def _open_dataflash(path: Path) -> AutopilotLog:
    from station.acquisition.dataflash_reader import read_dataflash
    from station.export.autopilot.ardupilot import names

    data = read_dataflash(path)
    imus = []
    for i, cols in sorted(data.imus.items()):
        t_us = cols["TimeUS"]
        rate, gaps = _timing(t_us)
        dev = data.params.get(names(i)["acc_id"]) if i <= 2 else None
        temp = cols.get("T")
        imus.append(LogImu(i, int(dev) if dev else None, rate, len(t_us), gaps, _has_temperature(temp)))
    log_notes = []
    filters = [f"{name} {data.params[name]:g} Hz" for name in ("INS_GYRO_FILTER", "INS_ACCEL_FILTER")
               if name in data.params]
    if data.imus:
        log_notes.append("IMU messages are ArduPilot's low-pass filtered samples"
                         + (f" ({', '.join(filters)})" if filters else "")
                         + ": noise above the filter is not the sensor's")
    from station.acquisition.log_magnetometer import dataflash_mags

    return AutopilotLog(path, "dataflash", imus, dict(data.params), {}, data.imus, log_notes,
                        _mags=dataflash_mags(data.mags))


def _dataflash_capture(log: AutopilotLog, imu: LogImu, remove: bool) -> tuple[Capture, list[str]]:
    from station.acquisition.dataflash_reader import board_rotation
    from station.export.autopilot import ardupilot

    cols = log._raw[imu.instance]
    t = cols["TimeUS"] * 1e-6
    acc = np.column_stack([cols[f"Acc{a}"] for a in AXES])
    gyro = np.column_stack([cols[f"Gyr{a}"] for a in AXES])
    temp = cols["T"].astype(np.float64) if imu.has_temperature else None
    notes = []
    p = log.params
    if not remove:
        notes.append("IMU messages are after ArduPilot's corrections and board rotation: left in (as asked)")
    else:
        orientation = int(p.get("AHRS_ORIENTATION", 0))
        if orientation:
            try:
                r = board_rotation(orientation)
            except ValueError as exc:
                raise InputFileError(log.path, f"{exc}: the station cannot take it out of the IMU messages; "
                                     "log with AHRS_ORIENTATION among 0..41",
                                     column="AHRS_ORIENTATION") from None
            # row vectors: v_board = R^T v_body is v_body @ R
            acc, gyro = acc @ r, gyro @ r
            notes.append(f"AHRS_ORIENTATION {orientation} (board rotation) taken out: samples in the board's "
                         "axes")
        if imu.instance > ardupilot.MAX_INSTANCE:
            notes.append(f"IMU {imu.instance + 1}'s offsets and temperature calibration are not read (the "
                         "station knows ArduPilot's first three IMUs' parameters): left in")
        else:
            n = ardupilot.names(imu.instance)
            tcal = p.get(f"{n['tcal']}ENABLE", 0) == 1
            if tcal and temp is None:
                raise InputFileError(log.path, f"{n['tcal']}ENABLE is 1 but IMU {imu.instance} logs no "
                                     "temperature: the temperature calibration cannot be taken out",
                                     column="T")
            needed = [f"{n['tcal']}TMIN", f"{n['tcal']}TMAX", n["acc_caltemp"], n["gyr_caltemp"]]
            missing = [k for k in needed if k not in p]
            if tcal and missing:
                raise InputFileError(log.path, f"{n['tcal']}ENABLE is 1 but the log lacks "
                                     f"{', '.join(missing)}: the temperature calibration cannot be taken out",
                                     column="PARM")
            scale = np.array([p.get(f"{n['acc_scal']}{a}", 1.0) or 1.0 for a in AXES])
            acc_off, gyr_off = ardupilot.ardupilot_offsets(p, imu.instance,
                                                          temp if temp is not None else np.zeros(len(t)))
            # eq. (1) inverted: raw = logged ./ scale + offsets + P(T) - P(T_cal)
            acc = acc / scale + acc_off
            gyro = gyro + gyr_off
            taken = []
            if tcal:
                taken.append(f"{n['tcal'].rstrip('_')} (about 35 degC, {p[needed[0]]:g}..{p[needed[1]]:g} "
                             f"degC, CALTEMP accel {p[needed[2]]:g} gyro {p[needed[3]]:g} degC)")
            if any(p.get(f"{n['acc_off']}{a}", 0.0) for a in AXES) or np.any(scale != 1.0):
                taken.append(f"{n['acc_off'].rstrip('_')}/{n['acc_scal'].rstrip('_')}")
            if any(p.get(f"{n['gyr_off']}{a}", 0.0) for a in AXES):
                taken.append(n["gyr_off"].rstrip("_"))
            notes.append(f"{', '.join(taken)} taken out (the log's parameters)" if taken
                         else "the log's parameters hold no correction for this IMU: nothing taken out")
    if not imu.has_temperature:
        notes.append("the IMU messages carry no temperature: temp left unknown")
    known = imu.instance <= ardupilot.MAX_INSTANCE
    gyro_id = p.get(ardupilot.names(imu.instance)["gyr_id"]) if known else None
    device = _device(log, imu, int(gyro_id) if gyro_id else None, "dataflash")
    return Capture(t=t, acc=acc, gyro=gyro, temp=temp, device=device, source=str(log.path)), notes
