"""``imu-station thermal`` end to end: CSV in, parameter file out (read back), applied by ``apply``."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocks.chamber import ChamberSweep, chamber_sweep, cubic_rate_unit
from station import cli
from station.acquisition.capture_csv import read_csv, write_csv
from station.acquisition.capture_h5 import H5CaptureWriter
from station.engines.shared.sensor_model import SensorCalibration
from station.export.params.file import ParamsFile

SWEEP = ChamberSweep(low_degc=0.0, high_degc=45.0, start_degc=20.0, ramp_degc_per_min=4.0, soak_s=240.0)


@pytest.fixture(scope="module")
def unit():
    return cubic_rate_unit(31)


@pytest.fixture(scope="module")
def sweep_run(unit):
    return chamber_sweep(unit, SWEEP, rate_hz=5.0, seed=1)


@pytest.fixture(scope="module")
def sweep_csv(sweep_run, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("thermal") / "sweep.csv"
    write_csv(path, sweep_run.to_capture())
    return path


@pytest.fixture(scope="module")
def sweep_h5(sweep_run, tmp_path_factory) -> Path:
    """The same sweep as the station's capture file, with the unit's info and step labels."""
    path = tmp_path_factory.mktemp("thermal") / "sweep.h5"
    r = sweep_run.recording
    writer = H5CaptureWriter(path, device=r.truth.device_info(r.rate_hz), with_step=True)
    writer.write(r.samples(), step=r.step)
    writer.close()
    return path


def calibrated_params(unit, path: Path) -> dict:
    """A parameter file as 'calibrate' and 'allan' leave it: accel, gyro and noise sections."""
    params = ParamsFile(device={"serial": unit.serial})
    params.accel = SensorCalibration(unit.accel.matrix, unit.accel.bias, method="six-position")
    params.gyro = SensorCalibration(unit.gyro.matrix, unit.gyro.bias, method="six-position")
    params.noise = {"accel": {"N": [1e-3, 1e-3, 1e-3]}}
    params.save(path)
    return yaml.safe_load(path.read_text())


def test_fit_write_read_back_and_apply_to_another_sweep(unit, sweep_h5, tmp_path, capsys) -> None:
    params_path = tmp_path / "unit.yaml"
    before = calibrated_params(unit, params_path)
    plot = tmp_path / "plots" / "thermal.png"
    assert cli.main(["thermal", str(sweep_h5), "-o", str(params_path), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "relative to the calibration in PARAMS" in out and "held-out RMS" in out
    assert f"wrote the thermal section to {params_path}" in out

    data = yaml.safe_load(params_path.read_text())
    # the sensitivity printed with the 1-sigma the file keeps, in the printed unit (deg/h for the gyro)
    sd_gyro = data["thermal"]["gyro"]["temp_sensitivity_sd"]
    assert f"+/- {sd_gyro[0] * 180 / np.pi * 3600:.2g}" in out and "deg/h/degC (1-sigma)" in out
    for kept in ("accel", "gyro", "noise"):
        assert data[kept] == before[kept]
    assert data["device"]["serial"] == unit.serial and data["device"]["model"] == unit.model
    section = data["thermal"]
    assert set(section) >= {"reference_temp", "dtemp_filter", "accel", "gyro"}
    assert section["accel"]["terms"] == ["t3", "t2", "t", "dt2", "dt", "tdt", "1"]
    assert section["dtemp_filter"]["kind"] == "ema"
    assert ParamsFile.load(params_path).thermal is not None
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    import matplotlib.image

    assert matplotlib.image.imread(plot).shape[0] > 400

    # The same unit swept at another speed, corrected by 'apply' with the file just written.
    other = chamber_sweep(unit, replace(SWEEP, ramp_degc_per_min=2.5), rate_hz=5.0, seed=9)
    raw_h5, fixed_csv = tmp_path / "other.h5", tmp_path / "fixed.csv"
    writer = H5CaptureWriter(raw_h5)
    writer.write(other.recording.samples())
    writer.close()
    assert cli.main(["apply", str(params_path), str(raw_h5), "-o", str(fixed_csv)]) == 0
    fixed = read_csv(fixed_csv)
    r = other.recording
    for got, true, thermal, matrix in (
            (fixed.acc, r.true_specific_force, other.thermal_accel, unit.accel.matrix),
            (fixed.gyro, r.true_rate, other.thermal_gyro, unit.gyro.matrix)):
        err = (got - true) @ matrix.T  # back in raw units, where the thermal bias lives
        err -= err.mean(axis=0)  # a single pose: the constant reads as tilt
        means = err[: len(err) // 50 * 50].reshape(-1, 50, 3).mean(axis=1)
        share = np.sqrt(np.mean(means**2, axis=0)) / np.ptp(thermal, axis=0)
        assert np.all(share < 0.03), share


def test_json_report_new_file_and_segments(sweep_csv, sweep_h5, tmp_path, capsys) -> None:
    params_path = tmp_path / "new.yaml"
    argv = ["thermal", str(sweep_csv), "-o", str(params_path), "--json", "--segments", "2", "--tau", "5"]
    assert cli.main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["calibrated"] == {"accel": False, "gyro": False}
    assert report["dtemp_filter"] == {"kind": "ema", "tau_s": 5.0}
    assert len(report["accel_segments"]) == 2 and len(report["gyro_segments"]) == 2
    for triad in ("accel", "gyro"):
        assert [a["axis"] for a in report[triad]] == ["x", "y", "z"]
        for a in report[triad]:
            assert a["cv_rms_after"] < a["cv_rms_before"]
            assert len(a["cv_rms_after_by_segment"]) == 2
    data = yaml.safe_load(params_path.read_text())
    assert data["schema"] == "imu-station/params/1" and "accel" not in data
    assert len(data["thermal"]["accel"]["segments"]) == 2

    assert cli.main(["thermal", str(sweep_h5), "-o", str(params_path), "--json", "--joins", "25",
                     "--terms", "t3,t2,t,dt", "--tau", "5"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["accel_segments"][0][1] == 25.0
    assert all(a["terms"] == ["t3", "t2", "t", "dt", "1"] for a in report["accel"])


def test_warnings_go_to_stderr(unit, tmp_path, capsys) -> None:
    narrow = tmp_path / "narrow.h5"
    sweep = ChamberSweep(low_degc=22.0, high_degc=28.0, start_degc=25.0, ramp_degc_per_min=1.0, soak_s=60.0)
    r = chamber_sweep(unit, sweep, rate_hz=2.0, seed=2).recording
    writer = H5CaptureWriter(narrow)
    writer.write(r.samples())
    writer.close()
    assert cli.main(["thermal", str(narrow), "-o", str(tmp_path / "p.yaml"), "--tau", "5"]) == 0
    captured = capsys.readouterr()
    assert "warning: temperature span" in captured.err and "warning:" not in captured.out


def test_refusals_name_the_problem(sweep_csv, sweep_h5, tmp_path, capsys) -> None:
    no_temp = tmp_path / "no_temp.csv"
    lines = [line for line in sweep_csv.read_text().splitlines() if not line.startswith("#")]  # metadata
    header = lines[0].split(",")
    keep = [i for i, h in enumerate(header) if h != "temp"]
    no_temp.write_text("\n".join(",".join(row.split(",")[i] for i in keep) for row in lines[:400]) + "\n")
    assert cli.main(["thermal", str(no_temp), "-o", str(tmp_path / "p.yaml")]) == 4
    err = capsys.readouterr().err
    assert str(no_temp) in err and "'temp'" in err and "Traceback" not in err
    assert not (tmp_path / "p.yaml").exists()

    assert cli.main(["thermal", str(sweep_h5), "-o", str(tmp_path / "p.yaml"), "--joins", "90"]) == 4
    assert "inside the fitted range" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli.main(["thermal", str(sweep_csv), "-o", str(tmp_path / "p.yaml"), "--segments", "many"])
    assert exc.value.code == 4
    with pytest.raises(SystemExit):
        cli.main(["thermal", str(sweep_csv), "-o", str(tmp_path / "p.yaml"), "--terms", "t4"])
    assert "unknown terms" in capsys.readouterr().err


def test_a_new_bias_fit_keeps_the_calibration_across_temperature(unit, sweep_csv, tmp_path, capsys) -> None:
    from station.engines.thermal.intrinsics import TempPolynomial
    from station.engines.thermal.model import DtempFilter, ThermalModel

    params_path = tmp_path / "unit.yaml"
    calibrated_params(unit, params_path)
    params = ParamsFile.load(params_path)
    scale = TempPolynomial(-20.0, 60.0, (1,), [[2e-4], [1e-4], [-1e-4]], [[1e-6], [1e-6], [1e-6]])
    misalignment = TempPolynomial(-20.0, 60.0, (1, 2), np.full((6, 2), 1e-7))
    params.thermal = ThermalModel(21.5, DtempFilter(), scale={"gyro": scale},
                                  misalignment={"accel": misalignment})
    params.save(params_path)
    before = yaml.safe_load(params_path.read_text())["thermal"]

    assert cli.main(["thermal", str(sweep_csv), "-o", str(params_path), "--reference-temp", "30"]) == 4
    err = capsys.readouterr().err
    assert f"{params_path}, column 'thermal.reference_temp': holds a calibration across temperature about " \
           "21.5 degC" in err
    assert yaml.safe_load(params_path.read_text())["thermal"] == before  # nothing written

    assert cli.main(["thermal", str(sweep_csv), "-o", str(params_path)]) == 0
    after = yaml.safe_load(params_path.read_text())["thermal"]
    assert after["reference_temp"] == 21.5  # the bias is fitted about the polynomials' own T_ref
    assert after["scale"] == before["scale"] and after["misalignment"] == before["misalignment"]
    assert after["gyro"] is not None and after["accel"] is not None  # the new bias model beside them
