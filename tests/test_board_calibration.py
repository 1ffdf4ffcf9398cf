"""Several IMUs on one board (issue 28), end to end through ``cli.main``: simulated boards of three mounted
IMUs (mocks/board.py) calibrated on a turntable from per-instance CSVs and hand-held from a multi-IMU ULog;
each IMU's rotation relative to the first recovered against the injected truth within its 1-sigma and a
stated tolerance, against scipy's align_vectors on the calibrated still poses, the parameter file read back,
and the refusals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from autopilot_params import px4_values, read_ardupilot
from scipy.spatial.transform import Rotation

from mocks.board import mounted, rotation_xyz, simulate_board, true_relative_rotation, write_board_ulog
from mocks.rig import Static, handheld_session, sequence_segments
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.engines.calibration.imu_alignment import rotation_vector
from station.export.params.file import ParamsFile
from station.export.params.imus import board_entries

MOUNTS_DEG = ([0.3, -0.2, 0.5], [1.5, -2.0, 3.0], [-2.5, 1.0, -4.0])
DEVICE_IDS = (2490378, 2228234, 3473418)
# accuracy stated in the docs: every error within 4 sigma plus 0.002 deg (the truth's float32 rounding)
K_SIGMA, FLOOR_DEG = 4.0, 0.002


def run(args: list, capsys) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def board(seed: int) -> list[UnitTruth]:
    return [mounted(UnitTruth.random(seed * 10 + k), rotation_xyz(m)) for k, m in enumerate(MOUNTS_DEG)]


def write_instances(folder: Path, name: str, recordings, serial: str = "SIM-BOARD") -> list[Path]:
    paths = []
    for k, rec in enumerate(recordings):
        capture = rec.to_capture()
        capture.device = {"serial": serial, "model": "sim-board", "rate_hz": rec.rate_hz, "instance": k}
        path = folder / (f"{name}.csv" if k == 0 else f"{name}.imu{k}.csv")
        write_csv(path, capture)
        if "# instance:" not in path.read_text()[:400]:  # a writer without the instance line: add it
            path.write_text(f"# instance: {k}\n" + path.read_text())
        paths.append(path)
    return paths


def errors_against_truth(params_path: Path, truths: list[UnitTruth]) -> list[tuple[float, float]]:
    """(error, 1-sigma) in deg of each IMU's rotation to the first, largest axis of the ratio."""
    params = ParamsFile.load(params_path)
    entries = board_entries(params)
    out = []
    for entry in entries[1:]:
        truth = true_relative_rotation(truths[0], truths[entry.instance])  # v_k = R v_0
        error = rotation_vector(entry.rotation_to_first @ truth)  # identity when exact
        assert entry.rotation_sigma is not None
        k = int(np.argmax(np.abs(error) / entry.rotation_sigma))
        out.append((float(np.degrees(abs(error[k]))), float(np.degrees(entry.rotation_sigma[k]))))
    return out


@pytest.fixture(scope="module")
def turntable_board(tmp_path_factory):
    folder = tmp_path_factory.mktemp("turntable")
    truths = board(1)
    segments = sequence_segments("twelve-position", rotations=True, hold_s=5.0)
    recordings = simulate_board(truths, segments, rates_hz=[200.0, 200.0, 200.0], seed=1)
    return folder, truths, write_instances(folder, "board", recordings)


def test_turntable_board_rotations_recovered(turntable_board, capsys) -> None:
    folder, truths, paths = turntable_board
    out_yaml = folder / "board.yaml"
    code, out, err = run(["calibrate", *paths, "--method", "turntable", "-o", out_yaml, "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert [imu["instance"] for imu in result["imus"]] == [0, 1, 2]
    assert [r["instance"] for r in result["rotations"]] == [1, 2]
    for err_deg, sigma_deg in errors_against_truth(out_yaml, truths):
        assert err_deg < K_SIGMA * sigma_deg + FLOOR_DEG, (err_deg, sigma_deg)
        assert sigma_deg < 0.01  # twelve poses and six turns: better than 0.01 deg
    # the true rotations are a few degrees: the mounting, not noise
    angles = [r["angle_deg"] for r in result["rotations"]]
    assert 3.0 < angles[0] < 5.0 and 4.0 < angles[1] < 6.0
    document = yaml.safe_load(out_yaml.read_text())
    assert document["imus"][0] == {"instance": 0}
    assert set(document["imus"][1]) >= {"instance", "accel", "gyro", "rotation_to_first", "rotation_sigma"}
    # the top-level sections are the first IMU's, as a one-IMU calibration of its capture writes them
    code, out, err = run(["calibrate", paths[0], "--method", "turntable", "--json"], capsys)
    assert code == 0, err
    np.testing.assert_allclose(document["accel"]["matrix"], json.loads(out)["accel"]["matrix"], atol=1e-12)


def test_turntable_board_rotation_is_scipys_on_the_calibrated_poses(turntable_board, capsys) -> None:
    """The estimator's poses-only answer against scipy's align_vectors on the same calibrated pose means."""
    from station.acquisition.capture import read_capture
    from station.engines.calibration.common import triangular_correction
    from station.engines.calibration.turntable import TurntableCapture, calibrate_turntable

    _, _, paths = turntable_board
    means = []
    for path in paths[:2]:
        capture = read_capture(path)
        report = calibrate_turntable(TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step))
        assert report.accel is not None
        _, own = triangular_correction(report.accel.correction, "lower")
        poses = [p for p in report.poses if p.get("kind") == "static"]
        means.append(np.array([(capture.acc[(capture.t >= p["t0"]) & (capture.t <= p["t1"])].mean(axis=0)
                                - report.accel.bias) @ own.T for p in poses]))
    theirs, _ = Rotation.align_vectors(means[1], means[0])
    from station.engines.calibration.imu_alignment import AlignmentVectors, relative_rotation

    ours = relative_rotation(AlignmentVectors(means[0], np.ones(len(means[0]))),
                             AlignmentVectors(means[1], np.ones(len(means[1]))))
    assert np.degrees(np.linalg.norm(rotation_vector(ours.matrix.T @ theirs.as_matrix()))) < 1e-9


@pytest.fixture(scope="module")
def handheld_board(tmp_path_factory):
    folder = tmp_path_factory.mktemp("handheld")
    truths = board(2)
    segments = handheld_session(n_poses=24, seed=5, hold_s=4.0, initial_still_s=15.0)
    # the second IMU at another rate: the first's still stretches are read on the log's time base
    recordings = simulate_board(truths, segments, rates_hz=[200.0, 250.0, 200.0], seed=2)
    log = write_board_ulog(folder / "handheld.ulg", recordings, DEVICE_IDS)
    return folder, truths, log


def test_handheld_board_from_a_ulog(handheld_board, capsys) -> None:
    folder, truths, log = handheld_board
    out_yaml = folder / "board.yaml"
    code, out, err = run(["calibrate", log, "-o", out_yaml], capsys)
    assert code == 0, err
    assert "=== IMU 2" in out and "rotation of each IMU relative to IMU 0" in out
    for err_deg, sigma_deg in errors_against_truth(out_yaml, truths):
        assert err_deg < K_SIGMA * sigma_deg + FLOOR_DEG, (err_deg, sigma_deg)
        assert sigma_deg < 0.05
    entries = board_entries(ParamsFile.load(out_yaml))
    assert [(e.instance, e.device_id) for e in entries] == list(enumerate(DEVICE_IDS))
    # --instance keeps today's single-IMU calibration
    code, out, err = run(["calibrate", log, "--instance", "1", "--json"], capsys)
    assert code == 0, err
    assert "rotations" not in json.loads(out)


def test_board_refusals(turntable_board, tmp_path, capsys) -> None:
    folder, truths, paths = turntable_board
    code, _, err = run(["calibrate", paths[0], paths[0], "--method", "turntable"], capsys)
    assert code != 0 and "both IMU instance 0" in err and "Traceback" not in err
    other = tmp_path / "other.imu1.csv"
    other.write_text(paths[1].read_text().replace("SIM-BOARD", "SIM-OTHER"))
    code, _, err = run(["calibrate", paths[0], other, "--method", "turntable"], capsys)
    assert code != 0 and "different units" in err
    code, _, err = run(["calibrate", *paths[:2], "--instance", "1"], capsys)
    assert code != 0 and "leave --instance out" in err
    # gravity in one direction only: the rotation about it is free
    still = simulate_board(truths[:2], [Static("+z", 20.0)], seed=3)
    flat = write_instances(tmp_path, "flat", still)
    code, _, err = run(["calibrate", *flat, "--method", "turntable"], capsys)
    assert code == 4 and "Traceback" not in err


def test_board_exports_every_imu_to_px4_and_ardupilot(handheld_board, tmp_path, capsys) -> None:
    from station.engines.thermal.model import DtempFilter, ThermalBias, ThermalModel, ThermalSegment

    folder, _, log = handheld_board
    params_path = tmp_path / "board.yaml"
    code, _, err = run(["calibrate", log, "-o", params_path], capsys)
    assert code == 0, err
    entries = board_entries(ParamsFile.load(params_path))
    code, out, err = run(["export", params_path, "-f", "px4", "-o", tmp_path / "board.params", "--json"],
                         capsys)
    assert code == 0, err
    # The board's IMUs are what the export writes: no note that it leaves the imus section out.
    assert not [n for n in json.loads(out)["notes"] if "does not carry" in n and "imus" in n]
    values = px4_values(tmp_path / "board.params")
    for entry in entries:
        k = entry.instance
        assert entry.accel is not None and entry.gyro is not None
        assert values[f"CAL_ACC{k}_ID"] == DEVICE_IDS[k] and values[f"CAL_GYRO{k}_ID"] == DEVICE_IDS[k]
        for i, axis in enumerate("XYZ"):
            assert values[f"CAL_ACC{k}_{axis}OFF"] == pytest.approx(entry.accel.bias[i], rel=1e-6)
            assert values[f"CAL_ACC{k}_{axis}SCALE"] == pytest.approx(1 / entry.accel.scale[i], rel=1e-6)
            assert values[f"CAL_GYRO{k}_{axis}OFF"] == pytest.approx(entry.gyro.bias[i], rel=1e-6, abs=1e-9)
    report = json.loads(out)
    rotations = [lim for lim in report["limitations"] if lim["what"] == "rotation to the first IMU"]
    assert [lim["triad"] for lim in rotations] == ["imu1", "imu2"]
    assert rotations[0]["unit"] == "deg"
    assert rotations[0]["size"] == pytest.approx(entries[1].rotation_angle_deg)
    assert "accel (IMU 2)" in report["pose_errors"]
    # one IMU of the board alone, with its device id given
    code, _, err = run(["export", params_path, "-f", "px4", "--instance", "2", "--device-id", "7",
                        "-o", tmp_path / "imu2.params"], capsys)
    assert code == 0, err
    alone = px4_values(tmp_path / "imu2.params")
    assert alone["CAL_ACC2_ID"] == 7 and not any(name.startswith("CAL_ACC0") for name in alone)
    # ArduPilot, with a thermal model on the second IMU: INS_ACC2OFFS_*, INS_TCAL2_*
    document = yaml.safe_load(params_path.read_text())
    coeffs = np.zeros((3, 7))
    coeffs[:, 2] = [1e-3, -2e-3, 5e-4]
    thermal = ThermalModel(25.0, DtempFilter(), accel=ThermalBias([ThermalSegment(-10, 60, coeffs)]),
                           gyro=ThermalBias([ThermalSegment(-10, 60, coeffs * 1e-2)]))
    document["imus"][1]["thermal"] = thermal.to_dict()
    params_path.write_text(yaml.safe_dump(document, sort_keys=False))
    code, out, err = run(["export", params_path, "-f", "ardupilot", "-o", tmp_path / "board.param"], capsys)
    assert code == 0, err
    values = read_ardupilot(tmp_path / "board.param")
    assert values["INS_TCAL2_ENABLE"] == 1
    assert values["INS_TCAL1_ENABLE"] == 0 and values["INS_TCAL3_ENABLE"] == 0
    assert values["INS_ACC2_ID"] == DEVICE_IDS[1] and values["INS_GYR3_ID"] == DEVICE_IDS[2]
    assert values["INS_TCAL2_ACC1_X"] == pytest.approx(1e-3 * 1e6, rel=1e-5)
    assert entries[2].accel is not None
    assert values["INS_ACC3SCAL_Y"] == pytest.approx(1 / entries[2].accel.scale[1], rel=1e-6)
    assert "rotation to the first IMU" in out


def test_board_file_refusals(handheld_board, tmp_path, capsys) -> None:
    folder, _, log = handheld_board
    params_path = tmp_path / "board.yaml"
    code, _, err = run(["calibrate", log, "-o", params_path], capsys)
    assert code == 0, err
    good = params_path.read_text()
    document = yaml.safe_load(good)
    mirror = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]
    for change, field in ((lambda d: d["imus"][1].__setitem__("rotation_to_first", mirror),
                           "imus[1].rotation_to_first"),
                          (lambda d: d["imus"][2].__setitem__("instance", 1), "imus[2].instance"),
                          (lambda d: d["imus"][1].__setitem__("rotation_sigma", [0.1, -0.1, 0.0]),
                           "imus[1].rotation_sigma"),
                          (lambda d: d["imus"][0].__setitem__("accel", d["accel"]), "imus[0].accel"),
                          (lambda d: d["imus"][1]["accel"].pop("bias"), "imus[1].accel"),
                          (lambda d: d["imus"][1].__setitem__("thermal", {"reference_temp": 900,
                                                                           "dtemp_filter": {"kind": "ema",
                                                                                            "tau_s": 2}}),
                           "imus[1].thermal.reference_temp"),
                          (lambda d: d["imus"][2].pop("rotation_to_first"), "imus[2]")):
        broken = yaml.safe_load(good)
        change(broken)
        params_path.write_text(yaml.safe_dump(broken, sort_keys=False))
        code, _, err = run(["export", params_path, "-f", "px4", "-o", tmp_path / "x.params"], capsys)
        assert code == 4 and field in err and str(params_path) in err and "Traceback" not in err, err
    assert document["imus"][1]["instance"] == 1


def test_board_certificate_lists_every_imu_and_its_rotation(handheld_board, tmp_path, capsys) -> None:
    from report_helpers import check_page, not_blank, screenshot

    folder, _, log = handheld_board
    params_path = tmp_path / "board.yaml"
    code, _, err = run(["calibrate", log, "-o", params_path], capsys)
    assert code == 0, err
    code, _, err = run(["report", params_path, "-o", tmp_path / "board.html"], capsys)
    assert code == 0, err
    text = check_page(tmp_path / "board.html")
    entries = board_entries(ParamsFile.load(params_path))
    for entry in entries[1:]:
        assert f"IMU {entry.instance} relative to IMU 0" in text
        assert f"accelerometer (accel), IMU {entry.instance}" in text
        assert f"{entry.rotation_angle_deg:.4g}"[:4] in text
    assert "rotation about IMU 0&#39;s axes" in text or "rotation about IMU 0's axes" in text
    not_blank(screenshot(tmp_path / "board.html", tmp_path))


def test_turntable_board_from_hdf5_capture_files(tmp_path, capsys) -> None:
    """Capture files (.h5) name their instance in the device attribute; the same rotations as the CSVs."""
    from station.acquisition.capture_h5 import H5CaptureWriter

    truths = board(4)
    recordings = simulate_board(truths, sequence_segments("six-position", rotations=True, hold_s=4.0), seed=4)
    paths = []
    for k, rec in enumerate(recordings):
        path = tmp_path / ("board.h5" if k == 0 else f"board.imu{k}.h5")
        writer = H5CaptureWriter(path, device={"serial": "SIM-H5", "rate_hz": rec.rate_hz, "instance": k},
                                 with_step=True)
        writer.write(rec.samples(), [str(s) for s in rec.step])
        writer.close()
        paths.append(path)
    code, out, err = run(["calibrate", *paths, "--method", "turntable", "-o", tmp_path / "b.yaml", "--json"],
                         capsys)
    assert code == 0, err
    assert [r["instance"] for r in json.loads(out)["rotations"]] == [1, 2]
    for err_deg, sigma_deg in errors_against_truth(tmp_path / "b.yaml", truths):
        assert err_deg < K_SIGMA * sigma_deg + FLOOR_DEG, (err_deg, sigma_deg)
