"""``imu-station calibrate --method turntable A.csv B.csv ... --across-temperature`` end to end: capture
CSVs written from the simulated unit (bias, scale factor and misalignment moving with T) at five soaks,
the parameter file read back, the plot, and ``imu-station apply`` on a capture at a temperature between
soaks against the truth, with and without the thermal section; the clear errors.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import yaml

from mocks.rig import constant, sequence_segments, simulate
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture import read_capture
from station.acquisition.capture_csv import write_csv
from station.engines.shared.correction import apply_calibration
from station.engines.thermal.intrinsics import slope_weights
from station.export.params.file import ParamsFile

SOAKS_DEGC = (-20.0, 0.0, 20.0, 40.0, 60.0)
CHECK_DEGC = 30.0
RATE_HZ = 100.0


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Five soak captures and one at 30 degC of one simulated unit, as CSV files."""
    folder = tmp_path_factory.mktemp("soaks")
    truth = UnitTruth.random(12, thermal_intrinsics=True)
    segments = sequence_segments("twelve-position", True, hold_s=20.0)
    paths = []
    for k, temp in enumerate(SOAKS_DEGC):
        rec = simulate(truth, segments, rate_hz=RATE_HZ, seed=120 + k, temperature=constant(temp))
        paths.append(folder / f"soak{k}_{temp:+.0f}C.csv")
        write_csv(paths[-1], rec.to_capture())
    check = simulate(truth, segments, rate_hz=RATE_HZ, seed=129, temperature=constant(CHECK_DEGC))
    check_path = folder / "check_30C.csv"
    write_csv(check_path, check.to_capture())
    return truth, paths, check, check_path


@pytest.fixture(scope="module")
def calibrated(campaign, tmp_path_factory):
    _, paths, _, _ = campaign
    folder = tmp_path_factory.mktemp("out")
    params = folder / "unit.yaml"
    ParamsFile(noise={"accel": {"N": [1e-3, 1e-3, 1e-3]}}).save(params)  # a section from 'allan'
    code = cli.main(["calibrate", "--method", "turntable", *map(str, paths), "--across-temperature",
                     "-o", str(params), "--plot", str(folder / "drift.png")])
    return code, params, folder / "drift.png"


def test_writes_accel_gyro_and_thermal_sections(campaign, calibrated) -> None:
    truth, paths, _, _ = campaign
    code, params, plot = calibrated
    assert code == 0
    data = yaml.safe_load(params.read_text())
    assert data["noise"] == {"accel": {"N": [1e-3, 1e-3, 1e-3]}}  # other sections kept
    thermal = data["thermal"]
    assert thermal["reference_temp"] == pytest.approx(20.0, abs=0.05)
    for triad in ("accel", "gyro"):
        assert set(thermal["scale"][triad]) >= {"clamp", "powers", "coeffs", "stddev"}
        assert thermal["scale"][triad]["clamp"] == pytest.approx([-20.0, 60.0], abs=0.05)
        assert np.array(thermal["misalignment"][triad]["coeffs"]).shape[0] == 6
        assert data[triad]["method"].startswith("turntable across temperature: 5 soaks")
        # the section's matrix is M(T_ref): against the truth's at 20 degC
        true_m = getattr(truth, triad).matrix_at(np.array([thermal["reference_temp"]]))[0]
        np.testing.assert_allclose(data[triad]["matrix"], true_m, atol=3e-4)
    soaks = thermal["across_temperature"]["soaks"]
    assert [s["capture"] for s in soaks] == [str(p) for p in paths]
    assert all(len(s["sha256"]) == 64 for s in soaks)
    loaded = ParamsFile.load(params)
    assert loaded.thermal is not None and set(loaded.thermal.scale) == {"accel", "gyro"}
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_prints_soaks_and_figures(campaign, tmp_path, capsys) -> None:
    truth, paths, _, _ = campaign
    code = cli.main(["calibrate", *map(str, paths), "--across-temperature", "-o", str(tmp_path / "u.yaml")])
    assert code == 0
    out = capsys.readouterr().out
    assert ("calibration across temperature: 5 soaks, -20.0 to 60.0 degC; T_ref 20 degC, the soak nearest 25"
            in out)
    for path in paths:
        assert path.name in out
    assert "gyro scale-factor temperature coefficient: x" in out
    assert "accel misalignment change over -20..60 degC: xy" in out
    # the plot goes beside the parameter file when --plot is not given, and the report says so
    assert (tmp_path / "u-across-temperature.png").exists()
    assert "u-across-temperature.png: plot of scale, misalignment and bias against temperature" in out


def test_json_figures_against_truth(campaign, capsys) -> None:
    truth, paths, _, _ = campaign
    assert cli.main(["calibrate", *map(str, paths), "--across-temperature", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["outputs"] == {}
    assert set(result["orders"]) == {f"{t}.{q}" for t in ("accel", "gyro") for q in ("bias", "scale",
                                                                                        "misalignment")}
    temps, w = slope_weights(min(SOAKS_DEGC), max(SOAKS_DEGC))
    for triad, tol in (("accel", 3.0), ("gyro", 6.0)):  # some 5 of the fit's own 1-sigma (0.5 and 1.2)
        tc = np.array(result["figures"][triad]["scale_tc_ppm_per_degc"])
        # the truth's slope of K(T) / K(T_ref) over the range, as the figure is defined
        sensor = getattr(truth, triad)
        k_ref = sensor.scale_at(np.array([result["reference_temp"]]))[0]
        np.testing.assert_allclose(tc, w @ (sensor.scale_at(temps) / k_ref) * 1e6, atol=tol)
        assert np.all(np.array(result["figures"][triad]["scale_tc_ppm_per_degc_stddev"]) < tol / 3)


def _step_errors(corrected: np.ndarray, true: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Per labelled step, the mean corrected minus true value (noise averaged out), (steps, 3)."""
    labels = [s for s in dict.fromkeys(step) if str(s).strip()]
    return np.array([(corrected[step == s] - true[step == s]).mean(axis=0) for s in labels])


def test_apply_between_soaks_is_closer_to_truth(campaign, calibrated, tmp_path, capsys) -> None:
    truth, _, check, check_path = campaign
    _, params, _ = calibrated
    out_path = tmp_path / "corrected.csv"
    assert cli.main(["apply", str(params), str(check_path), "-o", str(out_path)]) == 0
    printed = capsys.readouterr().out
    assert ("accel: matrix M(T) at each sample's temperature (thermal.scale and thermal.misalignment"
            in printed)
    corrected = read_capture(out_path)
    step = np.array([str(s) for s in check.step])
    # the same sections without the thermal one: the matrices and biases of 20 degC used at 30 degC
    loaded = ParamsFile.load(params)
    raw = read_capture(check_path)
    flat_acc, flat_gyro = apply_calibration(raw.acc, raw.gyro, raw.temp, None, loaded.accel, loaded.gyro,
                                            None, np.asarray(loaded.gyro.extra["g_sensitivity"]))
    for name, with_thermal, without, true, tol in (
            ("accel", corrected.acc, flat_acc, check.true_specific_force, 2e-3),
            ("gyro", corrected.gyro, flat_gyro, check.true_rate, 2e-4)):
        err = np.sqrt(np.mean(_step_errors(with_thermal, true, step) ** 2))
        err_flat = np.sqrt(np.mean(_step_errors(without, true, step) ** 2))
        assert err < tol, name
        print(f"{name}: per-step mean error RMS {err:.3g} with the thermal section, {err_flat:.3g} without")
        assert err < err_flat / 4, (name, err, err_flat)


def test_clear_errors(campaign, tmp_path, capsys) -> None:
    _, paths, check, _ = campaign
    # a capture without temperature: names the file and the column, says what to do
    no_temp = tmp_path / "no_temp.csv"
    write_csv(no_temp, dataclasses.replace(check.to_capture(), temp=None))
    assert cli.main(["calibrate", str(paths[0]), str(no_temp), "--across-temperature"]) == 4
    err = capsys.readouterr().err
    assert f"{no_temp}, column 'temp': has no temperature" in err
    assert "Traceback" not in err
    # one soak
    assert cli.main(["calibrate", str(paths[0]), "--across-temperature"]) != 0
    assert "needs captures at 2 or more soak temperatures" in capsys.readouterr().err
    # two soaks 0 degC apart (the same file twice is not a temperature range)
    assert cli.main(["calibrate", str(paths[0]), str(paths[0]), "--across-temperature"]) == 4
    assert "span 0.0 degC" in capsys.readouterr().err
    # several captures without --across-temperature, or with another method
    assert cli.main(["calibrate", str(paths[0]), str(paths[1])]) != 0
    assert "give one per soak temperature with --across-temperature" in capsys.readouterr().err
    argv = ["calibrate", str(paths[0]), str(paths[1]), "--across-temperature", "--method", "free"]
    assert cli.main(argv) != 0
    assert "--method free cannot be used with it" in capsys.readouterr().err
