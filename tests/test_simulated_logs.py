"""Simulated flight-controller logs: the ULog and DataFlash writers read back by pyulog and pymavlink,
``simulate --log-format``, thermal from a log end to end (thermal --instance -> export px4/ardupilot
--instance, the files parsed back and evaluated with each autopilot's formula against the truth).
PX4's and ArduPilot's own scripts are not in the repository (ArduPilot's is GPL-3.0): they are run side
by side with ours by ``benchmarks/autopilot_thermal.py``, not here.

The autopilots' formulas are written here again from the README beside their scripts
(``../shared/peers/autopilot-thermal/README.md``), independently of ``station.export.autopilot``:

    PX4        offset = X0 + X1 d + X2 d^2 + X3 d^3,   d = clip(T, TMIN, TMAX) - TREF
    ArduPilot  offset = P(clamp(T) - 35) - P(clamp(T_cal) - 35),   P(x) = (c1 x + c2 x^2 + c3 x^3) 1e-6

Curves are compared after removing their mean over the range: a constant offset belongs to the
calibration's offsets (and PX4's script fits the accel about its median), not to the thermal model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from autopilot_params import px4_values, read_ardupilot

from mocks import dataflash_writer as df
from mocks import ulog_writer as ul
from mocks.autopilot_sweep import board_imus, log_sweep, parse_log_sweep, simulate_board_log
from station import cli

DEG_H = 180.0 / np.pi * 3600.0
MG = 1e3 / 9.80665
# a small programme: -10 -> 50 -> -10 degC at 6 degC/min, 2 min soaks (24 min), 5 Hz: 7200 samples per IMU
SMALL = "t_min=-10,t_max=50,rate_c_per_min=6,soak_s=120"
SMALL_RATE = 5.0


def run_cli(args: list[object], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def px4_offset(values: dict[str, float], prefix: str, temp: np.ndarray) -> np.ndarray:
    """PX4's thermal offset of block ``prefix`` (e.g. ``TC_G1_``), (N, 3)."""
    d = np.clip(temp, values[f"{prefix}TMIN"], values[f"{prefix}TMAX"]) - values[f"{prefix}TREF"]
    return np.column_stack([sum(values[f"{prefix}X{k}_{axis}"] * d**k for k in range(4))
                            for axis in range(3)])


def ardupilot_offset(values: dict[str, float], n: int, sensor: str, temp: np.ndarray,
                     caltemp: float = -300.0) -> np.ndarray:
    """ArduPilot's thermal offset of IMU ``n`` (1-based), ``sensor`` ACC or GYR, (N, 3)."""
    lo, hi = values[f"INS_TCAL{n}_TMIN"], values[f"INS_TCAL{n}_TMAX"]

    def poly(x: np.ndarray) -> np.ndarray:
        return np.column_stack([sum(values[f"INS_TCAL{n}_{sensor}{k}_{a}"] * x**k for k in (1, 2, 3)) * 1e-6
                                for a in "XYZ"])

    return poly(np.clip(temp, lo, hi) - 35.0) - poly(np.clip(np.full_like(temp, caltemp), lo, hi) - 35.0)


def variation(curve: np.ndarray) -> np.ndarray:
    """Per axis max |curve - its mean|: the part of a curve that is not a constant."""
    return np.max(np.abs(curve - curve.mean(axis=0)), axis=0)


# --- the writers, read back by the autopilots' own readers -----------------------------------------------

def test_ulog_writer_reads_back_exactly_with_pyulog(tmp_path: Path) -> None:
    pyulog = pytest.importorskip("pyulog")
    sweep = parse_log_sweep("t_min=0,t_max=20,rate_c_per_min=10,soak_s=30")
    imus, runs = simulate_board_log(tmp_path / "s.ulg", "ulog", seed=4, sweep=sweep, rate_hz=SMALL_RATE)
    log = pyulog.ULog(str(tmp_path / "s.ulg"))
    assert not log.file_corruption
    topics = {(d.name, d.multi_id): d.data for d in log.data_list}
    assert set(topics) == {(name, k) for name in ("sensor_accel", "sensor_gyro") for k in range(3)} | {
        ("sensor_baro", 0)}
    for imu, run in zip(imus, runs, strict=True):
        rec = run.recording
        for name, values, dev in (("sensor_accel", rec.acc, imu.accel_id),
                                  ("sensor_gyro", rec.gyro, imu.gyro_id)):
            data = topics[name, imu.instance]
            for j, axis in enumerate("xyz"):
                np.testing.assert_array_equal(data[axis], values[:, j].astype(np.float32))
            np.testing.assert_array_equal(data["temperature"], rec.temp.astype(np.float32))
            np.testing.assert_array_equal(data["device_id"], dev)
            np.testing.assert_array_equal(data["timestamp_sample"], 5_000_000 + np.round(rec.t * 1e6))
            assert np.all(data["timestamp"] > data["timestamp_sample"])
    params = log.initial_parameters
    assert params["TC_A_ENABLE"] == 0 and params["TC_G_ENABLE"] == 0
    assert params["CAL_ACC2_ID"] == imus[2].accel_id and params["CAL_GYRO2_ID"] == imus[2].gyro_id
    assert params["CAL_ACC1_XSCALE"] == 1.0
    assert log.msg_info_dict["sys_name"] == "PX4"
    # the board lies still, z up, from the first sample (no turn into its pose)
    np.testing.assert_allclose(topics["sensor_accel", 0]["z"], 9.8, atol=0.5)
    assert np.abs(topics["sensor_gyro", 0]["x"]).max() < 0.1


def test_ulog_writer_formats_and_padding(tmp_path: Path) -> None:
    pyulog = pytest.importorskip("pyulog")
    assert ul.dtype_of(ul.SENSOR_ACCEL).itemsize % 8 == 0 and ul.SENSOR_ACCEL[-1].name == "_padding0"
    # the trailing padding is in the format but never logged; a struct of 8-byte multiple has none
    assert ul.logged_size(ul.SENSOR_ACCEL) == ul.dtype_of(ul.SENSOR_ACCEL).itemsize - 4 == 44
    assert ul.logged_size(ul.SENSOR_BARO) == ul.dtype_of(ul.SENSOR_BARO).itemsize == 32
    n = 4
    t = np.arange(n, dtype=np.uint64) * 1000 + 10
    baro = ul.records(ul.SENSOR_BARO, n, timestamp=t, timestamp_sample=t, device_id=7,
                      pressure=np.linspace(1e5, 1.01e5, n), temperature=21.5)
    path = ul.write_ulog(tmp_path / "b.ulg", [ul.Topic("sensor_baro", 0, ul.SENSOR_BARO, baro)],
                         {"AN_INT": 3, "A_FLOAT": 0.25}, {"ver_hw": "X"}, messages=[(5, "hello")])
    log = pyulog.ULog(str(path))
    data = log.data_list[0].data
    np.testing.assert_array_equal(data["pressure"], baro["pressure"])
    assert log.initial_parameters == {"AN_INT": 3, "A_FLOAT": 0.25}
    assert isinstance(log.initial_parameters["AN_INT"], int)
    assert [m.message for m in log.logged_messages] == ["hello"]
    with pytest.raises(ValueError, match="do not match"):
        ul.Topic("sensor_baro", 0, ul.SENSOR_ACCEL, baro)


def test_dataflash_writer_reads_back_exactly_with_dfreader(tmp_path: Path) -> None:
    pytest.importorskip("pymavlink")
    from pymavlink import DFReader

    sweep = parse_log_sweep("t_min=0,t_max=20,rate_c_per_min=10,soak_s=30")
    imus, runs = simulate_board_log(tmp_path / "s.bin", "dataflash", seed=4, sweep=sweep, rate_hz=SMALL_RATE)
    reader = DFReader.DFReader_binary(str(tmp_path / "s.bin"))
    rows: dict[int, list[list[float]]] = {0: [], 1: [], 2: []}
    params = {}
    while (msg := reader.recv_msg()) is not None:
        if msg.get_type() == "IMU":
            rows[msg.I].append([msg.TimeUS, msg.GyrX, msg.GyrY, msg.GyrZ, msg.AccX, msg.AccY, msg.AccZ,
                                msg.T])
        elif msg.get_type() == "PARM":
            params[msg.Name] = msg.Value
    for imu, run in zip(imus, runs, strict=True):
        got = np.array(rows[imu.instance])
        rec = run.recording
        np.testing.assert_array_equal(got[:, 0], 5_000_000 + np.round(rec.t * 1e6))
        np.testing.assert_array_equal(got[:, 1:4], rec.gyro.astype(np.float32))
        np.testing.assert_array_equal(got[:, 4:7], rec.acc.astype(np.float32))
        np.testing.assert_array_equal(got[:, 7], rec.temp.astype(np.float32))
    assert params["INS_TCAL1_ENABLE"] == 0 and params["AHRS_ORIENTATION"] == 0
    assert params["INS_ACC_ID"] == imus[0].accel_id and params["INS_GYR3_ID"] == imus[2].gyro_id
    assert params["INS_ACC2OFFS_X"] == 0 and params["INS_ACC3SCAL_Z"] == 1
    assert df.IMU_DTYPE.itemsize == 54 and df.PARM_DTYPE.itemsize == 35
    with pytest.raises(ValueError, match="16 characters"):
        df.parm_messages({"A_NAME_OF_MORE_THAN_16": 1.0})


def test_board_truths_differ_and_one_is_strongly_dt_dependent() -> None:
    imus = board_imus(0)
    assert [imu.kind for imu in imus] == ["cubic", "strong dT", "mild dT"]
    dt_terms = [np.abs(imu.truth.gyro.thermal.coeffs[:, 3:6]).max() for imu in imus]
    assert dt_terms[0] == 0 and dt_terms[1] > 5 * dt_terms[2] > 0
    assert len({imu.accel_id for imu in imus}) == 3
    assert not np.allclose(imus[0].truth.gyro.bias, imus[1].truth.gyro.bias)
    assert all(imu.truth.gyro.thermal.coeffs[:, 3:6].max() == 0 for imu in board_imus(0, pure_cubic=True))
    assert log_sweep().duration_s == pytest.approx(2 * 80 / 3 * 60 + 600)


# --- simulate --log-format ----------------------------------------------------------------------------------

def test_simulate_log_format_writes_and_refuses(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sweep.bin"
    code, text, _ = run_cli(["simulate", "--scenario", "chamber", "--log-format", "dataflash", "--chamber",
                             "t_min=0,t_max=10,rate_c_per_min=10,soak_s=10", "--rate", "2", "-o", out],
                            capsys)
    assert code == 0 and out.exists()
    assert "3 IMU instances" in text and "thermal truth strong dT" in text and "2 Hz" in text
    log = ["--scenario", "chamber", "--log-format", "ulog", "-o"]
    for args, message in (
            (["--log-format", "ulog", "-o", tmp_path / "x.ulg"], "give --scenario chamber"),
            (["--scenario", "chamber", "--log-format", "ulog"], "needs both"),
            (["--scenario", "chamber", "-o", tmp_path / "x.ulg"], "needs both"),
            ([*log, tmp_path / "x.ulg", "--faults", "drop=0.1"], "--faults: for a served unit only"),
            ([*log, tmp_path / "x.ulg", "--chamber", "t_max=x"], "not a number"),
            ([*log, tmp_path / "x.ulg", "--rate", "5000"], "1..1000"),
            ([*log, tmp_path], "is a directory"),
            ([*log, tmp_path / "no" / "x.ulg"], "cannot write")):
        code, _, err = run_cli(["simulate", *args], capsys)
        assert code == 4, args
        assert message in err and "Traceback" not in err


# --- thermal from a log, end to end ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same noisy board (seed 3) through the small programme as a ULog and as a DataFlash log."""
    folder = tmp_path_factory.mktemp("logs")
    for fmt, name in (("ulog", "sweep.ulg"), ("dataflash", "sweep.bin")):
        assert cli.main(["simulate", "--scenario", "chamber", "--log-format", fmt, "--chamber", SMALL,
                         "--rate", str(int(SMALL_RATE)), "--seed", "3", "-o", str(folder / name)]) == 0
    return folder


# Largest |exported cubic - truth's curve at dT = 0| (constant removed) over the range, per instance,
# gyro deg/h and accel mg: about twice what this noisy, fast (6 degC/min, 24 min, 5 Hz) log gives. The
# truths vary by ~2000 deg/h and ~20 mg over the range. Instance 1's dT terms are strong enough that a
# short log separates them from T only so far (a dT step at each ramp corner and the dT filter's lag):
# hence its wider bound.
E2E_TOLERANCES = {0: (15.0, 0.25), 1: (250.0, 1.2), 2: (35.0, 0.35)}


@pytest.mark.parametrize("instance", [1, 0, 2])
def test_thermal_log_to_px4_and_ardupilot_per_instance(small_logs: Path, tmp_path: Path, instance: int,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("pyulog")
    imu = board_imus(3)[instance]
    k, n = instance, instance + 1
    board = tmp_path / "board.yaml"
    code, out, err = run_cli(["thermal", small_logs / "sweep.ulg", "--instance", k, "-o", board], capsys)
    assert code == 0, err
    assert f"instance {k} (device {imu.accel_id})" in err + out
    ids = ["--device-id", imu.accel_id, "--gyro-device-id", imu.gyro_id]
    # PX4 without ids given: the file's device section holds the log's (the TC_* blocks bind to them).
    code, px4_report, err = run_cli(["export", board, "-f", "px4", "--instance", k, "-o",
                                     tmp_path / "b.params"], capsys)
    assert code == 0, err
    assert f"accel {imu.accel_id}, gyro {imu.gyro_id}" in px4_report
    # the loss from our richer model is printed: the dT terms PX4 cannot hold, with their size
    assert "thermal model as one cubic" in px4_report
    if imu.kind == "strong dT":
        assert "dT terms" in px4_report
    code, ap_report, err = run_cli(["export", board, "-f", "ardupilot", "--instance", k, "-o",
                                    tmp_path / "b.param", *ids], capsys)
    assert code == 0, err
    assert "thermal model as one cubic" in ap_report

    px4 = px4_values(tmp_path / "b.params")
    assert px4["TC_A_ENABLE"] == 1 and px4["TC_G_ENABLE"] == 1
    assert px4[f"TC_A{k}_ID"] == imu.accel_id and px4[f"TC_G{k}_ID"] == imu.gyro_id
    assert not any(name.startswith(f"TC_{s}{j}") for name in px4 for s in "AG" for j in range(4) if j != k)
    # the range is the instance's logged temperatures: -10..50 degC air, the IMU up to 2k degC above it by
    # self-heating (the lowest temperatures only in the first seconds, before it warms)
    assert -10.1 < px4[f"TC_G{k}_TMIN"] < -9.0
    assert 49.9 + 1.5 * k < px4[f"TC_G{k}_TMAX"] < 50.1 + 2.0 * k
    assert px4[f"TC_G{k}_TMIN"] < px4[f"TC_G{k}_TREF"] < px4[f"TC_G{k}_TMAX"]
    ap = read_ardupilot(tmp_path / "b.param")
    first = k == 0
    assert ap[f"INS_TCAL{n}_ENABLE"] == 1
    assert ap["INS_ACC_ID" if first else f"INS_ACC{n}_ID"] == imu.accel_id
    assert ap["INS_GYR_ID" if first else f"INS_GYR{n}_ID"] == imu.gyro_id
    assert not any(name.startswith("INS_TCAL") and not name.startswith(f"INS_TCAL{n}_") for name in ap)
    assert ap[f"INS_TCAL{n}_TMIN"] == pytest.approx(px4[f"TC_G{k}_TMIN"], abs=0.01)

    # each format's curve against the truth's at dT = 0 (the part a cubic in T can hold), inside the range
    temp = np.linspace(px4[f"TC_G{k}_TMIN"] + 1.0, px4[f"TC_G{k}_TMAX"] - 1.0, 200)
    zero = np.zeros_like(temp)
    truth_gyro = imu.truth.gyro.thermal.bias(temp, zero)
    truth_acc = imu.truth.accel.thermal.bias(temp, zero)
    assert np.all(variation(truth_gyro) * DEG_H > 300)
    gyro_tol, acc_tol = E2E_TOLERANCES[k]
    for name, offsets in (("px4", (px4_offset(px4, f"TC_A{k}_", temp), px4_offset(px4, f"TC_G{k}_", temp))),
                          ("ardupilot", (ardupilot_offset(ap, n, "ACC", temp, ap[f"INS_ACC{n}_CALTEMP"]),
                                         ardupilot_offset(ap, n, "GYR", temp, ap[f"INS_GYR{n}_CALTEMP"])))):
        acc_err = variation(offsets[0] - truth_acc) * MG
        gyro_err = variation(offsets[1] - truth_gyro) * DEG_H
        assert np.all(gyro_err < gyro_tol), (name, gyro_err)
        assert np.all(acc_err < acc_tol), (name, acc_err)


def test_thermal_from_dataflash_matches_the_ulog_of_the_same_samples(
        small_logs: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("pyulog")
    pytest.importorskip("pymavlink")
    import yaml

    sections = []
    for name in ("sweep.ulg", "sweep.bin"):
        out = tmp_path / f"{name}.yaml"
        code, _, err = run_cli(["thermal", small_logs / name, "--instance", 2, "-o", out], capsys)
        assert code == 0, err
        sections.append(yaml.safe_load(out.read_text())["thermal"])
    for triad in ("accel", "gyro"):
        a, b = (np.array(s[triad]["segments"][0]["coeffs"]) for s in sections)
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-12)
    assert sections[0]["reference_temp"] == sections[1]["reference_temp"]
