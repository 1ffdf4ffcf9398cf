"""PX4 ULog and ArduPilot DataFlash logs read as captures (station/acquisition/autopilot_log.py).

References: pyulog reads the same ULogs (pyulog's own sample logs, vendored, and logs written here);
pymavlink's DFReader, message by message, reads the same DataFlash logs; ArduPilot's correction is
applied here in closed form from its documented formula and must come back out exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from station.acquisition.autopilot_log import is_autopilot_log, log_notes, open_log
from station.acquisition.capture import read_capture
from station.acquisition.ulog_reader import read_ulog
from station.errors import InputFileError
from tests.autopilot_log_files import (
    ACCEL_IDS,
    imu_messages,
    imu_records,
    mag_messages,
    mag_records,
    ulog_from_captures,
    write_dataflash,
    write_ulog,
)

DATA = Path(__file__).parent / "data" / "px4-pyulog"
SAMPLES = sorted(DATA.glob("*.ulg"))


def _pyulog_topics(path: Path) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    log = ULog(str(path), ["sensor_accel", "sensor_gyro", "sensor_mag"])
    return {(d.name, d.multi_id): d.data for d in log.data_list}


@pytest.mark.parametrize("path", SAMPLES, ids=[p.name for p in SAMPLES])
def test_pyulogs_samples_decode_to_exactly_what_pyulog_reads(path: Path) -> None:
    reference = _pyulog_topics(path)
    ours = read_ulog(path)
    assert set(ours.topics) == set(reference) and len(reference) == 8  # three IMUs, two magnetometers
    for key, fields in reference.items():
        decoded = ours.topics[key]
        assert len(decoded) == len(fields["timestamp"])
        for name, values in fields.items():  # every field, bit for bit (float32 as pyulog gives it)
            assert decoded[name].dtype == values.dtype, (key, name)
            np.testing.assert_array_equal(decoded[name], values, err_msg=f"{key} {name}")
    assert ours.params == ULog(str(path)).initial_parameters


@pytest.mark.parametrize("path", SAMPLES, ids=[p.name for p in SAMPLES])
def test_each_instance_of_a_sample_is_its_sensor_topics(path: Path) -> None:
    reference = _pyulog_topics(path)
    log = open_log(path)
    assert log.kind == "ulog" and [imu.instance for imu in log.imus] == [0, 1, 2]
    captures = log.captures()
    for m, capture in captures.items():
        accel, gyro = reference["sensor_accel", m], reference["sensor_gyro", m]
        np.testing.assert_array_equal(capture.t, accel["timestamp_sample"] * 1e-6)
        np.testing.assert_array_equal(capture.acc, np.column_stack([accel[a] for a in "xyz"]))
        # the gyro is logged 28 ms (SITL: 24 ms) from the accelerometer at 1 Hz: each paired with its nearest
        np.testing.assert_array_equal(capture.gyro, np.column_stack([gyro[a] for a in "xyz"]))
        imu = log.imu(m)
        assert imu.device_id == int(accel["device_id"][0]) and imu.samples == len(accel["x"])
        assert imu.rate_hz == pytest.approx(1e6 / np.median(np.diff(accel["timestamp_sample"])))
        assert imu.gaps == 0
        assert imu.has_temperature == bool(np.any(accel["temperature"] != 0))
        assert (capture.temp is not None) == imu.has_temperature
        assert capture.device["accel_device_id"] == imu.device_id
    notes = " | ".join(log.notes())
    assert "raw driver output" in notes and "nothing taken out" in notes


def test_a_cut_or_damaged_ulog_reads_as_pyulog_reads_it(tmp_path: Path) -> None:
    whole = (DATA / "sample_log_small.ulg").read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(whole[:len(whole) * 2 // 3 + 7])  # ends inside a message
    reference = _pyulog_topics(cut)
    ours = read_ulog(cut)
    assert ours.truncated
    for key, fields in reference.items():
        np.testing.assert_array_equal(ours.topics[key]["timestamp"], fields["timestamp"])


def _sweep(n: int = 4000, rate: float = 250.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    t_us = (np.arange(n) * (1e6 / rate)).astype(np.uint64) + 1_000_000
    acc = rng.normal(0, 0.05, (n, 3)) + [0.0, 0.0, -9.80665]
    gyro = rng.normal(0, 0.01, (n, 3))
    temp = np.linspace(15.0, 55.0, n)
    return t_us, acc.astype(np.float32), gyro.astype(np.float32), temp.astype(np.float32)


def test_gaps_dropouts_and_the_true_rate(tmp_path: Path) -> None:
    t_us, acc, gyro, temp = _sweep(rate=200.0)
    keep = np.ones(len(t_us), bool)
    keep[1000:1010] = False  # one 55 ms gap
    keep[3000:3001] = False  # one 10 ms gap (two steps)
    a, g = imu_records(t_us[keep], acc[keep], gyro[keep], temp[keep], ACCEL_IDS[0], 2359308)
    topics = {("sensor_accel", 0): a, ("sensor_gyro", 0): g}
    path = write_ulog(tmp_path / "gaps.ulg", topics, {}, dropout_ms=55)
    log = open_log(path)
    (imu,) = log.imus
    assert imu.rate_hz == pytest.approx(200.0) and imu.gaps == 2 and imu.samples == keep.sum()
    capture = read_capture(path)  # one IMU: no --instance needed
    notes = log_notes(capture)
    assert any("instance 0 (device 1310988): 200 Hz" in n and "2 gaps" in n for n in notes)
    assert any("dropped data 1 time(s), 55 ms" in n for n in notes)


def test_several_imus_and_no_instance_names_them(tmp_path: Path) -> None:
    from station.acquisition.capture_data import Capture

    caps = {}
    for i, rate in enumerate((1000.0, 800.0, 250.0)):
        t_us, acc, gyro, temp = _sweep(n=2000, rate=rate, seed=i)
        caps[i] = Capture(t=t_us * 1e-6, acc=acc, gyro=gyro, temp=temp)
    path = ulog_from_captures(tmp_path / "three.ulg", caps)
    with pytest.raises(InputFileError) as refused:
        read_capture(path)
    text = str(refused.value)
    assert text.startswith(f"{path}: has 3 IMUs: ")
    for i, rate in enumerate(("1000 Hz", "800 Hz", "250 Hz")):
        assert f"instance {i} (device {ACCEL_IDS[i]}): {rate}, 2000 samples" in text
    assert text.endswith("choose one with --instance N")
    with pytest.raises(InputFileError, match="has no IMU instance 5; its IMUs are: instance 0"):
        read_capture(path, 5)
    capture = read_capture(path, 2)
    np.testing.assert_array_equal(capture.acc, caps[2].acc)
    with pytest.raises(InputFileError, match="not one; leave --instance out"):
        read_capture(DATA / "LICENSE.md", 1)


def test_a_gyro_at_another_rate_is_interpolated_to_the_accelerometer(tmp_path: Path) -> None:
    t_us, acc, gyro, temp = _sweep(n=3000, rate=1000.0)
    a, _ = imu_records(t_us, acc, gyro, temp, ACCEL_IDS[0], 2359308)
    t_g = t_us[::2] + 300  # half the rate, 0.3 ms later
    _, g = imu_records(t_g, acc[::2], gyro[::2], temp[::2], ACCEL_IDS[0], 2359308)
    path = write_ulog(tmp_path / "rates.ulg", {("sensor_accel", 0): a, ("sensor_gyro", 0): g}, {})
    capture = read_capture(path)
    inside = (t_us >= t_g[0]) & (t_us <= t_g[-1])
    expected = np.column_stack([np.interp(t_us[inside].astype(float), t_g.astype(float),
                                          gyro[::2, j].astype(float)) for j in range(3)])
    np.testing.assert_allclose(capture.gyro, expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(capture.acc, acc[inside].astype(float))
    assert any("linearly interpolated" in n for n in log_notes(capture))


def test_px4_thermal_parameters_are_named_and_not_applied_to_the_raw_topics(tmp_path: Path) -> None:
    t_us, acc, gyro, temp = _sweep()
    a, g = imu_records(t_us, acc, gyro, temp, ACCEL_IDS[1], 2359316)
    params = {"TC_A_ENABLE": 1, "TC_A2_ID": ACCEL_IDS[1], "TC_A2_TREF": 30.0, "TC_A2_X0_0": 0.1,
              "TC_G_ENABLE": 0, "TC_G0_ID": 2359316, "CAL_ACC1_ID": ACCEL_IDS[1], "CAL_ACC1_XOFF": 0.2}
    path = write_ulog(tmp_path / "tc.ulg", {("sensor_accel", 3): a, ("sensor_gyro", 3): g}, params)
    capture = read_capture(path, 3)
    np.testing.assert_array_equal(capture.acc, acc.astype(float))
    np.testing.assert_array_equal(capture.temp, temp.astype(float))
    note = next(n for n in log_notes(capture) if "raw driver output" in n)
    # matched by device id, not by index: TC_A2 and CAL_ACC1 for instance 3; TC_G0 is not enabled
    assert "TC_A2, CAL_ACC1 (matched by device id) would apply downstream; nothing taken out" in note


# --- ArduPilot -----------------------------------------------------------------------------------

def _ardupilot_poly(c: np.ndarray, temp: np.ndarray) -> np.ndarray:
    """P(T) of AP_InertialSensor_TCal: (c1 x + c2 x^2 + c3 x^3) 1e-6, x = T - 35, c (3 powers, 3 axes)."""
    x = (np.asarray(temp, float) - 35.0)[:, None]
    return (c[0] * x + c[1] * x**2 + c[2] * x**3) * 1e-6


def _ardupilot_params(n: int, acc_c: np.ndarray, gyr_c: np.ndarray, lo: float, hi: float, caltemp: float,
                      acc_off: np.ndarray, acc_scale: np.ndarray, gyr_off: np.ndarray) -> dict[str, float]:
    first = n == 1
    p = {f"INS_TCAL{n}_ENABLE": 1.0, f"INS_TCAL{n}_TMIN": lo, f"INS_TCAL{n}_TMAX": hi,
         f"INS_ACC{n}_CALTEMP": caltemp, f"INS_GYR{n}_CALTEMP": caltemp}
    for k in range(3):
        for j, a in enumerate("XYZ"):
            p[f"INS_TCAL{n}_ACC{k + 1}_{a}"] = float(acc_c[k, j])
            p[f"INS_TCAL{n}_GYR{k + 1}_{a}"] = float(gyr_c[k, j])
    for j, a in enumerate("XYZ"):
        p[("INS_ACCOFFS_" if first else f"INS_ACC{n}OFFS_") + a] = float(acc_off[j])
        p[("INS_ACCSCAL_" if first else f"INS_ACC{n}SCAL_") + a] = float(acc_scale[j])
        p[("INS_GYROFFS_" if first else f"INS_GYR{n}OFFS_") + a] = float(gyr_off[j])
    return p


@pytest.mark.parametrize("orientation", [0, 2, 8])
def test_ardupilots_correction_and_board_rotation_come_out_in_closed_form(tmp_path: Path, orientation: int):
    t_us, raw_acc, raw_gyro, temp = _sweep(n=3000, rate=400.0, seed=3)
    raw_acc, raw_gyro, temp = raw_acc.astype(float), raw_gyro.astype(float), temp.astype(float)
    rng = np.random.default_rng(5)
    acc_c, gyr_c = rng.normal(0, 300.0, (3, 3)), rng.normal(0, 30.0, (3, 3))
    acc_c[2] /= 30.0
    gyr_c[2] /= 30.0
    lo, hi, caltemp = 20.0, 50.0, 28.0  # the sweep runs 15..55 degC: both clamps are reached
    acc_off, acc_scale = np.array([0.1, -0.2, 0.3]), np.array([1.01, 0.99, 1.02])
    gyr_off = np.array([1e-3, 0, -2e-3])
    # PARM values are float32 in the log: the model here uses the values the log holds
    acc_c, gyr_c, acc_off, acc_scale, gyr_off = (np.float32(v).astype(float)
                                                 for v in (acc_c, gyr_c, acc_off, acc_scale, gyr_off))
    params = _ardupilot_params(2, acc_c, gyr_c, lo, hi, caltemp, acc_off, acc_scale, gyr_off)
    params["AHRS_ORIENTATION"] = float(orientation)
    # ArduPilot's forward model, written out: logged = R (((raw - P(T) + P(T_cal)) - OFFS) .* SCAL)
    tc = np.clip(temp, lo, hi)
    thermal_acc = _ardupilot_poly(acc_c, tc) - _ardupilot_poly(acc_c, np.full(len(tc), caltemp))
    thermal_gyr = _ardupilot_poly(gyr_c, tc) - _ardupilot_poly(gyr_c, np.full(len(tc), caltemp))
    rotation = {0: np.eye(3), 2: np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),  # yaw 90
                8: np.diag([1.0, -1, -1])}[orientation]  # roll 180
    logged_acc = ((raw_acc - thermal_acc - acc_off) * acc_scale) @ rotation.T
    logged_gyr = (raw_gyro - thermal_gyr - gyr_off) @ rotation.T
    path = write_dataflash(tmp_path / "ap.bin", [imu_messages(t_us, 1, logged_acc, logged_gyr, temp)], params)
    log = open_log(path)
    assert log.kind == "dataflash" and [i.instance for i in log.imus] == [1]
    capture = log.capture(1)
    # float32 in the log: the logged values carry 6e-8 relative rounding, the rest is exact
    np.testing.assert_allclose(capture.acc, raw_acc, rtol=0, atol=2e-6)
    np.testing.assert_allclose(capture.gyro, raw_gyro, rtol=0, atol=2e-7)
    # the offset taken out, against the closed form (not merely the raw samples coming back)
    kept = log.capture(1, remove_autopilot_correction=False)
    removed_gyro = capture.gyro - kept.gyro @ rotation
    np.testing.assert_allclose(removed_gyro, thermal_gyr + gyr_off, rtol=0, atol=1e-12)
    notes = " | ".join(log_notes(capture))
    assert "INS_TCAL2 (about 35 degC, 20..50 degC, CALTEMP accel 28 gyro 28 degC)" in notes
    assert "INS_ACC2OFFS/INS_ACC2SCAL, INS_GYR2OFFS taken out" in notes
    assert (f"AHRS_ORIENTATION {orientation} (board rotation) taken out" in notes) == (orientation != 0)
    assert "left in (as asked)" in " | ".join(log_notes(kept))


def test_dataflash_decodes_to_what_dfreader_reads(tmp_path: Path) -> None:
    from pymavlink.DFReader import DFReader_binary

    imu = []
    for i in range(3):
        t_us, acc, gyro, temp = _sweep(n=1500, rate=400.0, seed=i)
        imu.append(imu_messages(t_us + 7 * i, i, acc, gyro, temp))
    path = write_dataflash(tmp_path / "three.bin", imu, {"INS_GYRO_FILTER": 20.0, "INS_ACC_ID": 123.0})
    reader = DFReader_binary(str(path))
    seen: dict[int, list] = {}
    columns = ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ", "T")
    while (m := reader.recv_match(type="IMU")) is not None:
        seen.setdefault(m.I, []).append([getattr(m, c) for c in columns])
    params = dict(reader.params)
    reader.close()
    log = open_log(path)
    assert log.params == params
    assert log.imus[0].device_id == 123
    for i, rows in seen.items():
        rows = np.array(rows)
        capture = log.capture(i)
        np.testing.assert_array_equal(capture.t, rows[:, 0] * 1e-6)
        np.testing.assert_array_equal(capture.gyro, rows[:, 1:4])
        np.testing.assert_array_equal(capture.acc, rows[:, 4:7])
        np.testing.assert_array_equal(capture.temp, rows[:, 7])
        assert log.imu(i).samples == len(rows) and log.imu(i).rate_hz == pytest.approx(400.0)
    assert any("INS_GYRO_FILTER 20 Hz" in n for n in log.notes())


def test_what_is_not_a_log_is_refused_clearly(tmp_path: Path) -> None:
    fake = tmp_path / "notes.bin"
    fake.write_bytes(b"not a log at all")
    assert is_autopilot_log(fake)
    with pytest.raises(InputFileError, match="neither a PX4 ULog nor an ArduPilot DataFlash log"):
        read_capture(fake)
    with pytest.raises(InputFileError, match="missing.ulg: does not exist"):
        read_capture(tmp_path / "missing.ulg")
    t_us, acc, gyro, temp = _sweep(n=100)
    path = write_dataflash(tmp_path / "rot.bin", [imu_messages(t_us, 0, acc, gyro, temp)],
                           {"AHRS_ORIENTATION": 101.0})
    with pytest.raises(InputFileError, match="column 'AHRS_ORIENTATION'"):
        read_capture(path)
    empty = write_ulog(tmp_path / "empty.ulg", {}, {})
    with pytest.raises(InputFileError, match="has no sensor_accel and sensor_gyro topics"):
        read_capture(empty)


# --- magnetometers --------------------------------------------------------------------------------

def test_px4s_first_magnetometer_at_the_imus_times(tmp_path: Path) -> None:
    t_us, acc, gyro, temp = _sweep(n=2000, rate=200.0)
    a, g = imu_records(t_us, acc, gyro, temp, ACCEL_IDS[0], 2359308)
    rng = np.random.default_rng(8)
    t_mag = t_us[3::4] + 1700  # 50 Hz, starting after the IMU
    gauss = (rng.normal(0, 0.3, (len(t_mag), 3)) + [0.2, 0.0, 0.4]).astype(np.float32)
    topics = {("sensor_accel", 0): a, ("sensor_gyro", 0): g,
              ("sensor_mag", 0): mag_records(t_mag, gauss, 396825),
              ("sensor_mag", 1): mag_records(t_mag, gauss * 2, 396826)}
    capture = read_capture(write_ulog(tmp_path / "mag.ulg", topics, {}))
    expected = np.column_stack([np.interp(t_us * 1e-6, t_mag * 1e-6, gauss[:, j].astype(float) * 100.0)
                                for j in range(3)])
    np.testing.assert_allclose(capture.mag, expected, rtol=0, atol=1e-12)
    note = next(n for n in log_notes(capture) if n.startswith("magnetometer"))
    assert "sensor_mag 0 (device 396825), raw" in note and "50 Hz, linearly interpolated" in note
    assert "(4 IMU samples outside its span take its first or last value)" in note
    assert note.endswith("magnetometers [1] not read")
    sample = read_capture(DATA / "sample_log_small.ulg", 0)
    reference = _pyulog_topics(DATA / "sample_log_small.ulg")["sensor_mag", 0]
    field = np.column_stack([np.interp(sample.t, reference["timestamp_sample"] * 1e-6,
                                       reference[a].astype(float) * 100.0) for a in "xyz"])
    np.testing.assert_allclose(sample.mag, field, rtol=0, atol=1e-12)


@pytest.mark.parametrize("external", [False, True])
def test_ardupilots_compass_correction_comes_out_in_closed_form(tmp_path: Path, external: bool) -> None:
    t_us, acc, gyro, temp = _sweep(n=1200, rate=100.0, seed=4)
    rng = np.random.default_rng(9)
    raw_ut = rng.normal(0, 30.0, (len(t_us), 3)) + [10.0, -5.0, 40.0]
    offsets, scale = np.array([120.0, -80.0, 40.0]), 1.05  # COMPASS_OFS (mG, added), COMPASS_SCALE
    w = np.array([[1.02, 0.01, -0.02], [0.01, 0.97, 0.015], [-0.02, 0.015, 1.01]])  # DIA / ODI
    motor = rng.normal(0, 5.0, (len(t_us), 3))
    params = {"COMPASS_OFS_X": offsets[0], "COMPASS_OFS_Y": offsets[1], "COMPASS_OFS_Z": offsets[2],
              "COMPASS_SCALE": scale,
              "COMPASS_DIA_X": w[0, 0], "COMPASS_DIA_Y": w[1, 1], "COMPASS_DIA_Z": w[2, 2],
              "COMPASS_ODI_X": w[0, 1], "COMPASS_ODI_Y": w[0, 2], "COMPASS_ODI_Z": w[1, 2],
              "AHRS_ORIENTATION": 2.0, "COMPASS_EXTERNAL": float(external), "COMPASS_ORIENT": 8.0}
    w, offsets, scale = (np.float32(v).astype(float) for v in (w, offsets, scale))  # as PARM holds them
    # eq. (1) of station.acquisition.log_magnetometer, written out: logged = W ((R raw + OFS) s) + motor
    rotation = np.diag([1.0, -1, -1]) if external else np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    logged = ((raw_ut * 10.0) @ rotation.T + offsets) * scale @ w.T + np.rint(motor)
    path = write_dataflash(tmp_path / "mag.bin", [imu_messages(t_us, 0, acc, gyro, temp)], params,
                           [mag_messages(t_us, 0, logged, motor)])
    capture = read_capture(path)
    # whole milligauss in the log: 0.05 uT of rounding, through W^-1 / s
    np.testing.assert_allclose(capture.mag, raw_ut, rtol=0, atol=0.06)
    assert np.abs(capture.mag - raw_ut).mean() < 0.03
    note = next(n for n in log_notes(capture) if n.startswith("magnetometer"))
    orientation = "COMPASS_ORIENT 8" if external else "AHRS_ORIENTATION 2"
    assert (f"MAG 0, COMPASS_OFS, COMPASS_DIA/COMPASS_ODI, COMPASS_SCALE, the motor compensation (MOX..MOZ), "
            f"{orientation} taken out") in note
