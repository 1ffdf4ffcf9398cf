"""``imu-station allan`` end to end: simulated captures (CSV, HDF5, ROS 1 and ROS 2 bags) to every output."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocks.rig import Static, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from protocols.base import SAMPLE_DTYPE
from station import cli
from station.acquisition.capture_csv import write_csv
from station.engines.allan.deviation import overlapping_adev
from station.engines.shared.sensor_model import SensorCalibration
from station.export.params.file import ParamsFile

GYRO = NoiseSpec(N=[3e-4, 4e-4, 5e-4], K=[2e-5, 2e-5, 2e-5])
ACCEL = NoiseSpec(N=[2e-3, 2e-3, 3e-3], K=[3e-4, 3e-4, 3e-4])
RATE = 100.0
AXES = ["gx", "gy", "gz", "ax", "ay", "az"]


@pytest.fixture(scope="module")
def recording():
    truth = UnitTruth(accel=SensorTruth(noise=ACCEL), gyro=SensorTruth(noise=GYRO), serial="SIM-ALLAN")
    return simulate(truth, [Static("+z", 1200.0)], rate_hz=RATE, seed=21)


@pytest.fixture(scope="module")
def still_csv(recording, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("allan") / "still.csv"
    write_csv(path, recording.to_capture())
    return path


def run_cli(args: list[str], capsys) -> tuple[int, str, str]:
    code = cli.main(["allan", *map(str, args)])
    out, err = capsys.readouterr()
    return code, out, err


def test_every_output_from_a_capture_csv(still_csv, recording, tmp_path, capsys):
    params = tmp_path / "unit.yaml"
    kept = ParamsFile(device={"serial": "SIM-ALLAN"}, gyro=SensorCalibration.identity())
    kept.save(params)
    names = ("curve.csv", "allan.png", "kalibr.yaml", "vins.yaml", "orb.yaml")
    files = {name: tmp_path / name for name in names}
    code, out, err = run_cli([still_csv, "-o", params, "--curve", files["curve.csv"],
                              "--plot", files["allan.png"], "--kalibr", files["kalibr.yaml"],
                              "--vins", files["vins.yaml"],
                              "--orbslam3", files["orb.yaml"], "--rostopic", "/imu/data", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    noise = result["noise"]

    # the parameter file: the noise section beside the section that was there
    back = ParamsFile.load(params)
    assert back.gyro is not None and back.gyro.method == "identity" and back.device["serial"] == "SIM-ALLAN"
    assert back.noise["gyro"]["N"] == noise["gyro"]["N"]
    assert back.noise["units"]["gyro"]["N"] == "rad/s/sqrt(Hz)" and back.noise["units"]["accel"]["K"] == \
        "m/s^3/sqrt(Hz)"
    truth_n = np.concatenate([GYRO.N, ACCEL.N])
    got_n = np.array(noise["gyro"]["N"] + noise["accel"]["N"])
    np.testing.assert_allclose(got_n, truth_n, rtol=0.03)
    assert noise["gyro"]["Q"] is None and "Q" in noise["gyro"]["reasons"]
    deg_per_sqrt_h = noise["gyro"]["datasheet_units"]["N [deg/sqrt(h)]"]
    np.testing.assert_allclose(deg_per_sqrt_h, np.degrees(noise["gyro"]["N"]) * 60.0, rtol=1e-12)
    assert noise["record"]["samples"] == len(recording) and noise["record"]["rate_hz"] == RATE
    assert noise["record"]["timing"]["gaps"] == 0 and noise["record"]["timing_problems"] == []

    # the curve: the engine's numbers on the same samples, re-read from the CSV
    header = files["curve.csv"].read_text().splitlines()[0].split(",")
    assert header[:8] == ["tau", *AXES, "n"]
    assert header[8:14] == [f"edf_{a}" for a in AXES] and header[-1] == "az_hi"
    table = np.loadtxt(files["curve.csv"], delimiter=",", skiprows=1)
    m = np.round(table[:, 0] * RATE).astype(int)
    assert np.array_equal(table[:, 7], len(recording) + 1 - 2 * m)
    raw = np.column_stack([recording.gyro, recording.acc]).astype(np.float32).astype(np.float64)
    np.testing.assert_allclose(table[:, 1:7], overlapping_adev(raw, RATE, m), rtol=1e-6)
    assert np.all(table[:, 14:20] < table[:, 1:7]) and np.all(table[:, 1:7] < table[:, 20:26])

    # Kalibr, VINS-Fusion, ORB-SLAM3: the largest axis of N and K, in their keys
    kal = yaml.safe_load(files["kalibr.yaml"].read_text())
    assert kal["gyroscope_noise_density"] == pytest.approx(max(noise["gyro"]["N"]), rel=1e-6)
    assert kal["accelerometer_random_walk"] == pytest.approx(max(noise["accel"]["K"]), rel=1e-6)
    assert kal["rostopic"] == "/imu/data" and kal["update_rate"] == RATE
    vins = yaml.safe_load(files["vins.yaml"].read_text())
    assert vins["gyr_w"] == kal["gyroscope_random_walk"]
    assert vins["acc_n"] == kal["accelerometer_noise_density"]
    orb = yaml.safe_load(files["orb.yaml"].read_text())
    assert orb["IMU.NoiseGyro"] == kal["gyroscope_noise_density"] and orb["IMU.Frequency"] == RATE
    k_truth = max(GYRO.K)
    assert kal["gyroscope_random_walk"] == pytest.approx(k_truth, rel=0.5)

    png = files["allan.png"].read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    import matplotlib.image

    assert matplotlib.image.imread(files["allan.png"]).shape[2] in (3, 4)


def test_human_summary(still_csv, capsys):
    code, out, _ = run_cli([still_csv], capsys)
    assert code == 0
    assert "120000 samples at 100 Hz" in out and "deg/sqrt(h)" in out and "rad/s^2/sqrt(Hz)" in out


def _write_csv_rows(path: Path, t: np.ndarray, rec, rows: np.ndarray) -> None:
    from station.acquisition.capture import Capture

    write_csv(path, Capture(t=t[rows], acc=rec.acc[rows], gyro=rec.gyro[rows]))


def test_gaps_are_reported_refused_and_accepted_on_request(recording, tmp_path, capsys):
    keep = np.ones(len(recording), bool)
    keep[50_000:50_600] = False  # 6 s missing: 0.5 % of the record
    path = tmp_path / "gap.csv"
    _write_csv_rows(path, recording.t, recording, keep)
    code, _, err = run_cli([path], capsys)
    assert code == 4
    assert "1 gap(s) missing 600 samples" in err and "--max-missing" in err
    code, out, err = run_cli([path, "--max-missing", "0.01", "--json"], capsys)
    assert code == 0, err
    timing = json.loads(out)["noise"]["record"]["timing"]
    assert timing["gaps"] == 1 and timing["missing_samples"] == 600
    assert timing["gap_examples"][0]["length_s"] == pytest.approx(6.01, abs=1e-6)


def test_station_capture_file(recording, tmp_path, capsys):
    from station.acquisition.capture_h5 import H5CaptureWriter

    path = tmp_path / "still.h5"
    samples = recording.samples()
    writer = H5CaptureWriter(path, device={"serial": "SIM-H5", "model": "imu-sim", "firmware": "1.0.0"})
    writer.write(samples)
    writer.close()
    params = tmp_path / "p.yaml"
    code, out, err = run_cli([path, "-o", params, "--json"], capsys)
    assert code == 0, err
    noise = json.loads(out)["noise"]
    np.testing.assert_allclose(noise["gyro"]["N"], GYRO.N, rtol=0.03)
    assert ParamsFile.load(params).device["serial"] == "SIM-H5"


def _imu_messages(rec, stamps_ns: np.ndarray, rows: np.ndarray, typestore):
    imu = typestore.types["sensor_msgs/msg/Imu"]
    header = typestore.types["std_msgs/msg/Header"]
    stamp = typestore.types["builtin_interfaces/msg/Time"]
    vec = typestore.types["geometry_msgs/msg/Vector3"]
    quat = typestore.types["geometry_msgs/msg/Quaternion"]
    cov = np.zeros(9)
    for i, ns in zip(rows, stamps_ns, strict=True):
        when = stamp(sec=int(ns // 10**9), nanosec=int(ns % 10**9))
        yield int(ns), imu(header=header(stamp=when, frame_id="imu"),
                           orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=cov,
                           angular_velocity=vec(x=float(rec.gyro[i, 0]), y=float(rec.gyro[i, 1]),
                                                z=float(rec.gyro[i, 2])),
                           angular_velocity_covariance=cov,
                           linear_acceleration=vec(x=float(rec.acc[i, 0]), y=float(rec.acc[i, 1]),
                                                   z=float(rec.acc[i, 2])),
                           linear_acceleration_covariance=cov)


@pytest.mark.parametrize("version", [2, 1])
def test_ros_bags_with_repeated_and_disordered_stamps(recording, tmp_path, capsys, version):
    pytest.importorskip("rosbags", reason="ROS bags need the optional extra 'ros' (imu-station[ros])")
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    n = 30_000  # 5 min: enough to check the reading, not the noise terms
    rows = np.arange(n)
    stamps = (1_700_000_000 * 10**9 + np.round(recording.t[:n] * 1e9)).astype(np.int64)
    # bag order: sample 100 sent twice, samples 200 and 201 arrive after 202
    order = np.concatenate([rows[:101], [100], rows[101:200], [202, 200, 201], rows[203:]])
    path = tmp_path / ("imu_ros2" if version == 2 else "imu.bag")
    writer = Writer2(path, version=9) if version == 2 else Writer1(path)
    with writer:
        msgtype = "sensor_msgs/msg/Imu"
        conn = writer.add_connection("/imu/data", msgtype, typestore=store)
        other = writer.add_connection("/imu/other", msgtype, typestore=store)
        ser = store.serialize_cdr if version == 2 else store.serialize_ros1
        # received in bag order, one every 10 ms; the header stamps carry the disorder
        for k, (_, msg) in enumerate(_imu_messages(recording, stamps[order], order, store)):
            writer.write(conn, int(stamps[0]) + k * 10**7, ser(msg, msgtype))
        for ns, msg in _imu_messages(recording, stamps[:10], rows[:10], store):
            writer.write(other, ns, ser(msg, msgtype))
    code, _, err = run_cli([path], capsys)
    assert code == 4 and "several IMU topics" in err and "/imu/other" in err
    curve = tmp_path / f"bag{version}.csv"
    # a 5 min record is too short for K: the reading alone is checked (--terms N)
    code, out, err = run_cli([path, "--topic", "/imu/data", "--curve", curve, "--json", "--terms", "N"],
                             capsys)
    assert code == 0, err
    timing = json.loads(out)["noise"]["record"]["timing"]
    assert timing["duplicates"] == 1 and timing["disordered"] == 2 and timing["samples"] == n - 2
    # 200 and 201 came after 202 and were dropped: a gap of two samples, reported
    assert timing["gaps"] == 1 and timing["missing_samples"] == 2
    assert timing["gap_examples"][0]["t"] == pytest.approx((stamps[199] - stamps[0]) * 1e-9, abs=1e-9)
    table = np.loadtxt(curve, delimiter=",", skiprows=1)
    m = np.round(table[:, 0] * RATE).astype(int)
    raw = np.column_stack([recording.gyro, recording.acc])[np.concatenate([rows[:200], [202], rows[203:n]])]
    np.testing.assert_allclose(table[:, 1:7], overlapping_adev(raw, RATE, m), rtol=1e-6)


def test_refusals(still_csv, recording, tmp_path, capsys):
    code, _, err = run_cli([tmp_path / "nope.csv"], capsys)
    assert code == 4 and "does not exist" in err
    short = tmp_path / "short.csv"
    _write_csv_rows(short, recording.t, recording, np.arange(3000))  # 30 s: no random walk to see
    kalibr_file = tmp_path / "imu.yaml"
    code, _, err = run_cli([short, "--kalibr", kalibr_file], capsys)
    assert code == 4 and "random walk" in err.lower() or "K is unknown" in err
    assert not kalibr_file.exists()
    code, _, err = run_cli([still_csv, "--per-decade", "5"], capsys)
    assert code == 4 and "at least 10" in err
    assert SAMPLE_DTYPE.names[0] == "seq"
