"""``imu-station calibrate`` end to end: capture CSV in, parameter file (YAML read back) and report out."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from mocks.rig import handheld_session, sequence_segments, simulate
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.export.params.file import ParamsFile


@pytest.fixture(scope="module")
def twelve_csv(tmp_path_factory):
    truth = UnitTruth.random(31)
    rec = simulate(truth, sequence_segments("twelve-position", True, hold_s=6.0), rate_hz=100.0, seed=31)
    path = tmp_path_factory.mktemp("cal") / "twelve.csv"
    write_csv(path, rec.to_capture())
    return truth, path


def test_turntable_json_and_merged_parameter_file(twelve_csv, tmp_path, capsys) -> None:
    truth, csv_path = twelve_csv
    params_path = tmp_path / "unit.yaml"
    ParamsFile(noise={"accel": {"N": [1e-3, 1e-3, 1e-3]}}).save(params_path)  # a section from 'allan'
    code = cli.main(["calibrate", str(csv_path), "--method", "turntable", "-o", str(params_path), "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["method"] == "turntable"
    assert result["gravity"] == pytest.approx(9.80665)
    assert len(result["poses"]) == 18
    data = yaml.safe_load(params_path.read_text())
    assert data["schema"] == "imu-station/params/1"
    assert data["noise"] == {"accel": {"N": [1e-3, 1e-3, 1e-3]}}  # kept
    for name, tr in (("accel", truth.accel), ("gyro", truth.gyro)):
        section = data[name]
        required = {"matrix", "bias", "scale", "misalignment", "correction", "method", "residual_rms"}
        assert set(section) >= required | {"stddev"}
        np.testing.assert_allclose(section["matrix"], tr.matrix, atol=2e-3)
        np.testing.assert_allclose(np.array(section["correction"]) @ np.array(section["matrix"]), np.eye(3),
                                   atol=1e-12)
        g_sensitivity = {"g_sensitivity"} if name == "gyro" else set()  # twelve poses determine it
        assert set(section["stddev"]) == {"matrix", "bias", "scale", "misalignment"} | g_sensitivity
        assert section == result[name] | {k: v for k, v in section.items() if k not in result[name]}
    # the file loads back as the station's own type
    loaded = ParamsFile.load(params_path)
    np.testing.assert_allclose(loaded.gyro.bias, data["gyro"]["bias"])


def test_readable_report_with_latitude_gravity(twelve_csv, capsys) -> None:
    _, csv_path = twelve_csv
    assert cli.main(["calibrate", str(csv_path), "--latitude", "45", "--height", "100"]) == 0
    out = capsys.readouterr().out
    # WGS-84 normal gravity at 45 deg (9.8061978) less the free-air 3.086e-6 s^-2 per metre over 100 m
    assert "turntable calibration, g = 9.805889" in out
    assert "±" in out and "per-pose residuals" in out and "rot-z" in out


def test_free_method_with_upper_convention_and_plot(tmp_path, capsys) -> None:
    truth = UnitTruth.random(32)
    segments = handheld_session(n_poses=20, seed=32, hold_s=4.0, initial_still_s=15.0)
    rec = simulate(truth, segments, rate_hz=100.0, seed=32)
    capture = rec.to_capture()
    capture.step = None
    path = tmp_path / "hand.csv"
    write_csv(path, capture)
    png = tmp_path / "cal.png"
    code = cli.main(["calibrate", str(path), "--initial-still", "14", "--convention", "upper",
                     "--plot", str(png), "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["method"] == "free"
    assert result["accel"]["convention"] == "upper"
    matrix = np.array(result["accel"]["matrix"])
    assert np.allclose(np.tril(matrix, -1), 0, atol=1e-12)   # upper-triangular body frame
    assert [t["multiplier"] for t in result["details"]["trials"]] == [2, 3, 4, 5, 6, 7, 8, 9, 10]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_errors_are_one_line_without_traceback(twelve_csv, tmp_path, capsys) -> None:
    _, csv_path = twelve_csv
    assert cli.main(["calibrate", str(csv_path), "--gravity", "9.81", "--latitude", "45"]) == 4
    assert "either --gravity or --latitude" in capsys.readouterr().err
    assert cli.main(["calibrate", str(csv_path), "--rate", "250"]) == 4
    err = capsys.readouterr().err
    assert "stated sample rate 250 Hz disagrees" in err and "Traceback" not in err
    assert cli.main(["calibrate", str(tmp_path / "missing.csv")]) == 4
    assert "missing.csv: does not exist" in capsys.readouterr().err


def test_demo_ends_with_a_calibration_of_the_simulated_unit(tmp_path) -> None:
    import io

    from station.commands import demo

    # The demo's sequence over the pty (poses of 4 s, x20), its calibration and the comparison with
    # the truth; the whole demo runs in tests/test_demo.py.
    out = io.StringIO()
    ctx = demo.DemoContext(out_dir=tmp_path / "demo", seed=3, hold_s=4.0, speed=20.0, out=out,
                           err=io.StringIO())
    mine = (demo.start_simulated_unit, demo.run_sequence, demo.calibrate_unit, demo.compare_with_truth)
    steps = [(title, step) for title, step in demo.STEPS if step in mine]
    assert [step for _, step in steps] == list(mine)
    demo.run_demo(ctx, steps)
    errors = ctx.results["calibration"]
    assert errors["accel scale"] < 2e-4 and errors["gyro scale"] < 3e-4
    assert errors["accel misalignment"] < 3e-4 and errors["gyro misalignment"] < 3e-4
    assert errors["accel bias"] < 3e-3 and errors["gyro bias"] < 2e-4
    assert max(ctx.results["sigma_ratios"]) < 5.0  # every error within 5 reported sigmas
    text = out.getvalue()
    assert "recovered" in text and "true" in text and "1-sigma" in text and "bias z" in text
    params = ParamsFile.load(tmp_path / "demo" / "params.yaml")
    assert params.device["serial"] == "SIM-000003"
    assert params.accel is not None and params.gyro is not None
    np.testing.assert_allclose(params.gyro.matrix, ctx.report.gyro.matrix, rtol=1e-12)
