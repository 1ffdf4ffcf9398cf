"""The estimators' noise files (PX4 EKF2, ArduPilot EKF3, OpenVINS beside Kalibr, VINS-Fusion, ORB-SLAM3):
the conversions against closed forms from the Allan terms and against a simulated IMU, the files read back
in each estimator's own syntax and units, the inflation factor on every value and printed every time, and
the refusals (a factor below 1, a parameter file without a noise section, a term the record does not show).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from autopilot_params import read_ardupilot, read_px4

from mocks.rig import Static, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.errors import EngineInputError
from station.export.estimators import inflation
from station.export.estimators.noise_export import build_noise_export
from station.export.params.file import ParamsFile
from station.export.writers import NOISE_FORMATS

# OpenVINS' config/euroc_mav/kalibr_imu_chain.yaml (the EuRoC ADIS16448, Kalibr's own imu_adis16448.yaml
# values): a published example of the four numbers in their file.
EUROC = {"gyroscope_noise_density": 1.6968e-04, "gyroscope_random_walk": 1.9393e-05,
         "accelerometer_noise_density": 2.0000e-3, "accelerometer_random_walk": 3.0000e-3}
NAMES = {"ekf2": {("gyro", "N"): "EKF2_GYR_NOISE", ("accel", "N"): "EKF2_ACC_NOISE",
                  ("gyro", "K"): "EKF2_GYR_B_NOISE", ("accel", "K"): "EKF2_ACC_B_NOISE"},
         "ekf3": {("gyro", "N"): "EK3_GYRO_P_NSE", ("accel", "N"): "EK3_ACC_P_NSE",
                  ("gyro", "K"): "EK3_GBIAS_P_NSE", ("accel", "K"): "EK3_ABIAS_P_NSE"}}
UNITS = {("gyro", "N"): "rad/s", ("accel", "N"): "m/s^2", ("gyro", "K"): "rad/s^2", ("accel", "K"): "m/s^3"}
STEP_S = {"ekf2": 0.010, "ekf3": 0.012}  # PX4's EKF2_PREDICT_US default, ArduPilot's EKF_TARGET_DT
CONTINUOUS = {"kalibr": {("gyro", "N"): "gyroscope_noise_density", ("gyro", "K"): "gyroscope_random_walk",
                         ("accel", "N"): "accelerometer_noise_density",
                         ("accel", "K"): "accelerometer_random_walk"},
              "vins": {("gyro", "N"): "gyr_n", ("gyro", "K"): "gyr_w", ("accel", "N"): "acc_n",
                       ("accel", "K"): "acc_w"},
              "orbslam3": {("gyro", "N"): "IMU.NoiseGyro", ("gyro", "K"): "IMU.GyroWalk",
                           ("accel", "N"): "IMU.NoiseAcc", ("accel", "K"): "IMU.AccWalk"}}
CONTINUOUS["openvins"] = CONTINUOUS["kalibr"]


def noise_section(gyro_n: list[float | None] | None = None, gyro_k: list[float | None] | None = None,
                  rate_hz: float = 200.0) -> dict:
    """A noise section as 'allan' writes it (the terms filters take), largest axes the EuRoC values."""
    return {"record": {"source": "still.csv", "samples": 1_440_000, "rate_hz": rate_hz, "duration_s": 7200.0,
                       "tau_range_s": [0.005, 700.0]},
            "gyro": {"N": gyro_n or [1.6968e-4, 1.2e-4, 1.5e-4], "K": gyro_k or [1.0e-5, 1.9393e-5, 1.2e-5],
                     "B": [None, None, None], "Q": None, "R": None},
            "accel": {"N": [1.5e-3, 2.0e-3, 1.9e-3], "K": [3.0e-3, 2.0e-3, 1.0e-3], "B": None, "Q": None,
                      "R": None}}


def largest(noise: dict) -> dict[tuple[str, str], float]:
    return {(s, t): max(noise[s][t]) for s in ("gyro", "accel") for t in ("N", "K")}


def save_params(path: Path, noise: dict | None) -> Path:
    params = ParamsFile(device={"serial": "SN-7", "model": "IMU-9", "firmware": "2.0"},
                        created="2026-11-28T10:00:00Z")
    params.noise = noise
    params.save(path)
    return path


def read_values(fmt: str, path: Path) -> dict[str, float]:
    """Every noise value of a written file, by the estimator's key."""
    if fmt == "ekf2":
        return {name: value for name, (value, _) in read_px4(path).items()}
    if fmt == "ekf3":
        return read_ardupilot(path)
    text = path.read_text()
    if fmt == "openvins":
        first, _, rest = text.partition("\n")
        assert first == "%YAML:1.0"  # cv::FileStorage's header, which PyYAML does not read
        return {k: v for k, v in yaml.safe_load(rest)["imu0"].items() if k in EUROC}
    doc = yaml.safe_load(text)
    return {name: doc[name] for name in CONTINUOUS[fmt].values()}


def export(args: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = cli.main(["export", *map(str, args)])
    except SystemExit as usage:  # argparse's refusal of an option's value
        code = int(usage.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("fmt", ["ekf2", "ekf3"])
@pytest.mark.parametrize(("rate", "factor"), [(None, 1.0), (250.0, 1.0), (None, 15.0)])
def test_the_autopilots_values_are_the_densities_over_the_root_of_the_step(fmt, rate, factor, tmp_path,
                                                                           capsys):
    noise = noise_section()
    source = save_params(tmp_path / "unit.yaml", noise)
    out = tmp_path / f"noise.{fmt}"
    args = [source, "-f", fmt, "-o", out, "--inflate", factor, "--json"]
    code, stdout, err = export([*args, *(["--ekf-rate", rate] if rate else [])], capsys)
    assert code == 0, err
    report = json.loads(stdout)
    step = 1.0 / rate if rate else STEP_S[fmt]
    back = read_values(fmt, out)
    assert set(back) == set(NAMES[fmt].values())
    units = {v["name"]: v["unit"] for v in report["values"]}
    for key, value in largest(noise).items():
        name = NAMES[fmt][key]
        # (dt sigma)^2 = N^2 dt (delta-angle variance), (dt sigma_b)^2 = K^2 dt (bias variance per step)
        assert back[name] == pytest.approx(factor * value / math.sqrt(step), rel=1e-6)  # float32 in the file
        assert units[name] == UNITS[key]
    if fmt == "ekf2":
        assert {kind for _, kind in read_px4(out).values()} == {9}  # MAV_PARAM_TYPE_REAL32
    assert report["filter_step_s"] == pytest.approx(step)
    assert report["inflation"]["factor"] == factor


def test_the_ekf_values_match_a_simulated_imu_at_the_filters_step() -> None:
    # White noise of density N sampled at 1 kHz (sigma N sqrt(fs)) summed into 10 ms delta angles, and a
    # bias walking with density K: the spread the EKF2 parameters describe, measured.
    n_density, k_density, fs, step = 2e-4, 3e-5, 1000.0, 0.010
    rng = np.random.default_rng(7)
    rate = rng.normal(0.0, n_density * math.sqrt(fs), (4000, int(fs * step)))
    delta_angle = rate.sum(axis=1) / fs
    bias = np.cumsum(rng.normal(0.0, k_density / math.sqrt(fs), 400_000))
    per_step = np.diff(bias[:: int(fs * step)])
    noise = noise_section(gyro_n=[n_density] * 3, gyro_k=[k_density] * 3)
    values = {v["name"]: v["value"] for v in build_noise_export("ekf2", noise).values}
    assert np.std(delta_angle) / step == pytest.approx(values["EKF2_GYR_NOISE"], rel=0.03)
    assert np.std(per_step) / step == pytest.approx(values["EKF2_GYR_B_NOISE"], rel=0.03)


def test_openvins_writes_the_published_example_back_and_the_ekfs_read_it_at_their_step(tmp_path, capsys):
    noise = noise_section()
    source = save_params(tmp_path / "unit.yaml", noise)
    out = tmp_path / "kalibr_imu_chain.yaml"
    code, stdout, err = export([source, "-f", "openvins", "-o", out, "--rostopic", "/imu/data"], capsys)
    assert code == 0, err
    assert read_values("openvins", out) == pytest.approx(EUROC, rel=1e-6)
    imu0 = yaml.safe_load(out.read_text().partition("\n")[2])["imu0"]
    assert imu0["rostopic"] == "/imu/data" and imu0["update_rate"] == 200.0 and imu0["model"] == "kalibr"
    assert np.array_equal(imu0["Tw"], np.eye(3)) and np.array_equal(imu0["Tg"], np.zeros((3, 3)))
    assert np.array_equal(imu0["T_i_b"], np.eye(4))
    # Kalibr's wiki: sigma_gd = sigma_g / sqrt(dt); PX4's gyro noise is that at its 10 ms step, and the
    # ADIS16448's bench value x10 lands on PX4's default (0.015 rad/s) within 15 %
    ekf2 = {v["name"]: v["value"] for v in build_noise_export("ekf2", noise, factor=10.0).values}
    assert ekf2["EKF2_GYR_NOISE"] == pytest.approx(10 * 1.6968e-4 / math.sqrt(0.01), rel=1e-6)
    assert ekf2["EKF2_GYR_NOISE"] == pytest.approx(0.015, rel=0.15)


@pytest.mark.parametrize("fmt", NOISE_FORMATS)
def test_inflate_multiplies_every_value_and_is_printed(fmt, tmp_path, capsys):
    noise = noise_section()
    source = save_params(tmp_path / "unit.yaml", noise)
    plain, inflated = tmp_path / f"plain.{fmt}", tmp_path / f"inflated.{fmt}"
    code, stdout, err = export([source, "-f", fmt, "-o", plain], capsys)
    assert code == 0, err
    assert "inflation: noise values as measured, not inflated (--inflate 1)" in stdout
    assert "Kalibr's wiki" in stdout and "OpenVINS' docs" in stdout
    code, stdout, err = export([source, "-f", fmt, "-o", inflated, "--inflate", "12.5"], capsys)
    assert code == 0, err
    assert "inflation: noise values inflated by a factor of 12.5 (--inflate 12.5, variances x156.25)" \
        in stdout
    before, after = read_values(fmt, plain), read_values(fmt, inflated)
    assert set(before) == set(after) and len(after) == 4
    for name, value in before.items():
        assert after[name] == pytest.approx(12.5 * value, rel=1e-6), name
    # the file says so too
    assert "x 12.5 (--inflate 12.5)" in inflated.read_text()
    assert "not inflated (--inflate 1)" in plain.read_text()
    if fmt in CONTINUOUS:
        for key, name in CONTINUOUS[fmt].items():
            assert before[name] == pytest.approx(largest(noise)[key], rel=1e-6)


@pytest.mark.parametrize("value", ["0.5", "0", "-3", "1001", "nan"])
def test_an_inflation_below_one_is_refused(value, tmp_path, capsys):
    source = save_params(tmp_path / "unit.yaml", noise_section())
    code, out, err = export([source, "-f", "ekf2", "-o", tmp_path / "x.params", "--inflate", value], capsys)
    assert code == 4 and "Traceback" not in err
    assert "--inflate" in err and "1..1000" in err
    assert not (tmp_path / "x.params").exists()
    with pytest.raises(EngineInputError, match="below 1 a filter would trust the IMU more"):
        build_noise_export("kalibr", noise_section(), factor=0.5)


@pytest.mark.parametrize("fmt", ["ekf2", "ekf3", "openvins", "kalibr"])
def test_a_parameter_file_without_a_noise_section_is_refused(fmt, tmp_path, capsys):
    source = save_params(tmp_path / "unit.yaml", None)
    code, out, err = export([source, "-f", fmt, "-o", tmp_path / "x"], capsys)
    assert code == 4 and "Traceback" not in err
    assert "has no noise section" in err and "imu-station allan" in err
    assert not (tmp_path / "x").exists()


def test_a_term_the_record_does_not_show_is_refused(tmp_path, capsys):
    noise = noise_section(gyro_k=[None, None, None])
    source = save_params(tmp_path / "unit.yaml", noise)
    code, out, err = export([source, "-f", "ekf3", "-o", tmp_path / "x.param"], capsys)
    assert code == 4 and "gyro K is unknown" in err and "Traceback" not in err


@pytest.mark.parametrize("topic", ["/imu0\nupdate_rate: 1", "imu: x", ""])
def test_a_topic_that_is_not_a_ros_name_is_refused(topic, tmp_path, capsys):
    source = save_params(tmp_path / "unit.yaml", noise_section())
    args = [source, "-f", "openvins", "-o", tmp_path / "x.yaml", "--rostopic", topic]
    code, out, err = export(args, capsys)
    assert code == 4 and "is not a ROS topic name" in err and "Traceback" not in err
    assert not (tmp_path / "x.yaml").exists()


def test_values_outside_the_documented_range_are_written_and_named(tmp_path, capsys):
    source = save_params(tmp_path / "unit.yaml", noise_section())
    code, out, err = export([source, "-f", "ekf3", "-o", tmp_path / "x.param", "--inflate", "10"], capsys)
    assert code == 0, err
    assert "EK3_ABIAS_P_NSE 0.2739 m/s^3 is above the range ArduPilot EKF3 documents (1e-05..0.02)" in out
    assert read_ardupilot(tmp_path / "x.param")["EK3_ABIAS_P_NSE"] == pytest.approx(
        10 * 3e-3 / math.sqrt(0.012), rel=1e-6)


def test_the_options_help_shows_are_the_writers() -> None:
    from station.console import options

    assert options.NOISE_EXPORT_FORMATS == NOISE_FORMATS


def test_the_reason_names_the_factor_and_the_sources() -> None:
    assert inflation.reason(1.0).startswith("noise values as measured, not inflated (--inflate 1)")
    assert "a factor of 20" in inflation.reason(20.0) and "10-20x" in inflation.reason(20.0)
    assert inflation.check_factor(1.0) == 1.0


# allan writes the same files straight from a record
GYRO = NoiseSpec(N=np.array([3e-4, 4e-4, 5e-4]), K=np.array([2e-5, 2e-5, 2e-5]))
ACCEL = NoiseSpec(N=np.array([2e-3, 2e-3, 3e-3]), K=np.array([3e-4, 3e-4, 3e-4]))


@pytest.fixture(scope="module")
def still_csv(tmp_path_factory) -> Path:
    truth = UnitTruth(accel=SensorTruth(noise=ACCEL), gyro=SensorTruth(noise=GYRO), serial="SIM-NOISE")
    recording = simulate(truth, [Static("+z", 1200.0)], rate_hz=100.0, seed=21)
    path = tmp_path_factory.mktemp("noise") / "still.csv"
    write_csv(path, recording.to_capture())
    return path


def test_allan_writes_the_estimator_files_with_the_factor(still_csv, tmp_path, capsys):
    files = {fmt: tmp_path / f"{fmt}.out" for fmt in ("kalibr", "openvins", "ekf2", "ekf3")}
    args = ["allan", str(still_csv), "--force", "--inflate", "10", "--ekf-rate", "200",
            *[a for fmt, path in files.items() for a in (f"--{fmt}", str(path))]]
    assert cli.main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    values = largest(result["noise"] if "filter_equivalent" not in result["noise"]["gyro"] else
                     {s: result["noise"][s]["filter_equivalent"] for s in ("gyro", "accel")})
    for key, value in values.items():
        assert read_values("kalibr", files["kalibr"])[CONTINUOUS["kalibr"][key]] == pytest.approx(10 * value,
                                                                                                  rel=1e-6)
        assert read_values("openvins", files["openvins"])[CONTINUOUS["openvins"][key]] == pytest.approx(
            10 * value, rel=1e-6)
        for fmt in ("ekf2", "ekf3"):
            got = read_values(fmt, files[fmt])[NAMES[fmt][key]]
            assert got == pytest.approx(10 * value / math.sqrt(1 / 200.0), rel=1e-6)
    for path in files.values():
        assert result["estimators"][str(path)]["inflation"]["factor"] == 10.0
    # the text output prints every file's values and the factor with its reason
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert "EKF2_GYR_NOISE" in out and "EK3_ABIAS_P_NSE" in out and "gyroscope_noise_density" in out
    assert out.count("inflation: noise values inflated by a factor of 10 (--inflate 10") == 1
