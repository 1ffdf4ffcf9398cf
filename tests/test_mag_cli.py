"""``imu-station calibrate --method mag`` end to end: a nine-axis unit captured over a real pty, the
fit into the parameter file (YAML read back and compared with the unit's truth), the summary,
JSON and plot, the World Magnetic Model's field, and the refusals."""

from __future__ import annotations

import datetime
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mag_helpers import angle_deg, errors, polar

from drivers import open_device
from mocks.device import SimDevice
from mocks.mag_sessions import mag_capture, nine_axis_unit, sphere_session
from mocks.magnetometer import EarthField
from mocks.pty_server import PtyServer
from station import cli
from station.acquisition.capture_csv import write_csv
from station.acquisition.recorder import record
from station.engines.magnetometer.calibration import MagCapture, calibrate_mag
from station.engines.magnetometer.geomagnetic import field_at
from station.engines.shared.sensor_model import SensorCalibration
from station.errors import ExitCode
from station.export.params.file import ParamsFile
from station.export.params.sections import mag_calibration


@pytest.fixture(scope="module")
def desk_csv(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    cap, truth = mag_capture("desk", 3)
    path = tmp_path_factory.mktemp("mag") / "desk.csv"
    write_csv(path, cap)
    return path, truth


def _accel_file(path: Path, truth) -> None:
    """A parameter file holding the unit's accelerometer as a prior calibration would have it."""
    ParamsFile(accel=SensorCalibration(truth.accel.matrix, truth.accel.bias, method="prior")).save(path)


def test_pty_capture_then_calibrate_recovers_the_unit(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    truth = nine_axis_unit(11, EarthField(magnitude_ut=48.0, dip_deg=58.0))
    session = sphere_session(n_poses=16, seed=11, hold_s=1.5, move_s=1.5)
    device = SimDevice(truth, seed=11, rate_hz=100, scenario=session)
    capture = tmp_path / "sphere.csv"
    with PtyServer(device, speed=25) as server, open_device(server.port_path) as dev:
        result = record(dev, capture, duration_s=52.0, handle_sigint=False)
    assert result.ended_by == "duration" and result.error is None
    params = tmp_path / "unit.yaml"
    _accel_file(params, truth)
    assert cli.main(["calibrate", str(capture), "--method", "mag", "--field", "48", "-o", str(params)]) == 0
    out = capsys.readouterr().out
    assert "coverage:" in out and "±" in out and "rotation to the accelerometer" in out
    data = yaml.safe_load(params.read_text())
    assert data["accel"]["method"] == "prior"                                  # kept
    section = data["mag"]
    assert set(section) >= {"matrix", "bias", "correction", "frame", "field_norm", "residual_rms", "coverage",
                            "stddev"}
    assert section["frame"] == "accel" and section["field_norm"] == 48.0 and section["coverage"] > 0.8
    err = errors(np.array(section["matrix"]), np.array(section["bias"]), truth)
    assert err["hard_ut"] < 0.05 and err["shape_pct"] < 0.2 and err["align_deg"] < 0.1, err
    assert section["dip_deg"] == pytest.approx(58.0, abs=0.1)
    # read back as the exports read it: the corrected field is the truth's, in accelerometer axes
    mag = mag_calibration(ParamsFile.load(params))
    assert mag is not None
    field = truth.mag.field.world()
    assert np.linalg.norm(mag.correct(truth.mag.measure(field[None, :]))[0] - field) < 0.1


def test_desk_capture_with_the_world_magnetic_model(desk_csv, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    path, truth = desk_csv
    params = tmp_path / "unit.yaml"
    _accel_file(params, truth)
    png = tmp_path / "mag.png"
    code = cli.main(["calibrate", str(path), "--method", "mag", "--latitude", "45.07", "--longitude",
                     "7.68", "--height", "240", "--date", "2026-11-26", "-o", str(params), "--plot", str(png),
                     "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    model = field_at(45.07, 7.68, 240.0, datetime.date(2026, 11, 26))
    assert result["field_norm"] == pytest.approx(model.magnitude_ut)
    assert result["field_source"] == model.describe() and "WMM 2025" in result["field_source"]
    # the simulated field has dip 60 deg, the model's place 61.2: no warning under 3 deg apart
    assert not any("geomagnetic model" in w for w in result["warnings"])
    assert result["coverage"] < 0.5 and any("field along +z" in w for w in result["warnings"])
    err = errors(np.array(result["matrix"]), np.array(result["bias"]), truth)
    assert err["hard_ut"] < 0.4 and err["shape_pct"] < 1.0 and err["align_deg"] < 0.2, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert yaml.safe_load(params.read_text())["mag"]["field_source"] == result["field_source"]


def test_dip_far_from_the_model_is_warned_about(desk_csv, capsys: pytest.CaptureFixture[str]) -> None:
    path, _ = desk_csv
    # Sydney: dip -64 deg, against the simulated +60
    assert cli.main(["calibrate", str(path), "--method", "mag", "--latitude", "-33.87", "--longitude",
                     "151.2", "--date", "2026-06-01"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "differs from the geomagnetic model's" in out


def test_without_accel_section_the_accelerometer_is_estimated(
        desk_csv, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, _ = desk_csv
    assert cli.main(["calibrate", str(path), "--method", "mag", "-o", str(tmp_path / "u.yaml")]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "no accelerometer calibration: its bias, scale and misalignment were estimated" in out
    assert "accelerometer estimated from the still poses" in out and "looks uncalibrated" not in out
    section = yaml.safe_load((tmp_path / "u.yaml").read_text())["mag"]
    assert section["field_source"] == "the data's own" and "field_norm" in section["stddev"]
    assert section["frame"] == "accel" and "accelerometer estimated" in section["method"]


def test_estimated_accelerometer_agrees_with_a_later_accel_calibration(tmp_path: Path) -> None:
    """The mag section written without an accel section and the one written after calibrate --method
    free into the same file are in the same axes (the accelerometer's lower-triangular frame): their
    rotations agree to a few hundredths of a degree; the raw accelerometer taken as it is would put
    the rotation 0.2 deg away."""
    cap, _ = mag_capture("sphere", 1, initial_still_s=10.0, n_poses=40)
    path = tmp_path / "sphere.csv"
    write_csv(path, cap)
    alone, later = tmp_path / "alone.yaml", tmp_path / "later.yaml"
    assert cli.main(["calibrate", str(path), "--method", "mag", "-o", str(alone)]) == 0
    assert cli.main(["calibrate", str(path), "--method", "free", "--initial-still", "10",
                     "-o", str(later)]) == 0
    assert cli.main(["calibrate", str(path), "--method", "mag", "-o", str(later)]) == 0
    a, b = (yaml.safe_load(f.read_text()) for f in (alone, later))
    assert "accelerometer estimated" in a["mag"]["method"] and "accel" not in a
    assert "accelerometer estimated" not in b["mag"]["method"] and b["accel"]["method"].startswith("free")
    rotation = polar(np.array(b["mag"]["matrix"]))[1]
    assert angle_deg(polar(np.array(a["mag"]["matrix"]))[1] @ rotation.T) < 0.06
    np.testing.assert_allclose(a["mag"]["bias"], b["mag"]["bias"], atol=0.01)
    as_is = calibrate_mag(MagCapture(cap.t, cap.mag, cap.acc, cap.gyro))
    assert angle_deg(polar(as_is.matrix)[1] @ rotation.T) > 0.15


def test_capture_without_magnetometer_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cap, _ = mag_capture("desk", 3)
    cap.mag = None
    path = tmp_path / "six.csv"
    write_csv(path, cap)
    assert cli.main(["calibrate", str(path), "--method", "mag"]) == 4
    err = capsys.readouterr().err
    assert "six.csv: has no magnetometer columns (mx, my, mz)" in err and "--method free" in err


@pytest.mark.parametrize(("options", "message"), [
    (["--field", "48", "--longitude", "7"], "either --field or --latitude"),
    (["--latitude", "45"], "needs both --latitude and --longitude"),
    (["--latitude", "45", "--longitude", "7", "--date", "2040-01-01"], "no field for 2040-01-01"),
])
def test_bad_field_options_are_refused_before_reading(options: list[str], message: str, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "not-read.csv"
    assert cli.main(["calibrate", str(missing), "--method", "mag", *options]) == 4
    assert message in capsys.readouterr().err


def test_bad_date_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["calibrate", "x.csv", "--method", "mag", "--date", "26/11/2026"])
    assert exc.value.code == ExitCode.USAGE
    assert "is not a date; give YYYY-MM-DD" in capsys.readouterr().err


def test_mag_section_is_checked_on_read(tmp_path: Path) -> None:
    from station.errors import InputFileError

    good = {"matrix": [[0, 1, 0], [1, 0, 0], [0, 0, -1]], "bias": [1, 2, 3], "frame": "accel"}
    path = tmp_path / "p.yaml"
    ParamsFile(other={"mag": good}).save(path)
    ParamsFile.load(path)       # a permuted mounting is a calibration in the accelerometer's axes
    cases = (({"dip_deg": 120}, "mag.dip_deg"), ({"stddev": {"bias": ["x", 1, 2]}}, "mag.stddev.bias"),
             ({"frame": "sensor"}, "mag.matrix"))
    for bad, where in cases:
        ParamsFile(other={"mag": good | bad}).save(path)
        with pytest.raises(InputFileError, match=where.replace(".", r"\.")):
            ParamsFile.load(path)


def test_world_magnetic_model_matches_its_published_test_values() -> None:
    """WMM2020 technical report (NOAA/NCEI, BGS), test values: 2020.0, height 0 km, 80 N 0 E:
    F 54999.4 nT, I 83.14 deg, D -1.28 deg."""
    model = field_at(80.0, 0.0, 0.0, datetime.date(2020, 1, 1))
    assert model.magnitude_ut == pytest.approx(54.9994, abs=0.01)
    assert model.dip_deg == pytest.approx(83.14, abs=0.01)
    assert model.declination_deg == pytest.approx(-1.28, abs=0.01)
    assert model.model == "WMM 2020, 2020-01-01"
