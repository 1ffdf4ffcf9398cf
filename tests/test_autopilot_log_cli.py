"""Every command that reads a capture takes a PX4 (.ulg) or ArduPilot (.bin) log with --instance, end to end
through ``cli.main``: the same results as from the same samples in a capture CSV, the notes on stderr,
and one clear line when the instance is missing or the log cannot serve the method."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mocks.chamber import ChamberSweep, chamber_sweep, cubic_rate_unit
from mocks.rig import Static, handheld_session, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from station import cli
from station.acquisition.capture_csv import read_csv, write_csv
from station.acquisition.capture_data import Capture
from tests.autopilot_log_files import dataflash_from_captures, ulog_from_captures

DATA = Path(__file__).parent / "data" / "px4-pyulog"


def _plain(capture: Capture) -> Capture:
    """What a log holds of a capture: t (whole microseconds), acc, gyro and temp, no labels or unit."""
    return Capture(t=np.rint(capture.t * 1e6) * 1e-6, acc=capture.acc, gyro=capture.gyro, temp=capture.temp)


def run(args: list, capsys) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    """Two still IMUs of different noise in one ULog and one DataFlash log, and instance 1 as a CSV."""
    folder = tmp_path_factory.mktemp("still")
    caps = {}
    for i, n in enumerate((2e-3, 4e-3)):
        truth = UnitTruth(accel=SensorTruth(noise=NoiseSpec(N=[n] * 3, K=[3e-4] * 3)),
                          gyro=SensorTruth(noise=NoiseSpec(N=[n / 5] * 3, K=[2e-5] * 3)), serial=f"SIM-{i}")
        caps[i] = _plain(simulate(truth, [Static("+z", 600.0)], rate_hz=100.0, seed=40 + i).to_capture())
    csv = folder / "imu1.csv"
    write_csv(csv, caps[1])
    ulog = ulog_from_captures(folder / "still.ulg", caps)
    return ulog, dataflash_from_captures(folder / "still.bin", caps), csv


def test_allan_on_a_log_instance_is_the_allan_of_its_samples(still, capsys) -> None:
    ulog, dataflash, csv = still
    code, out, err = run(["allan", csv, "--terms", "N", "--json"], capsys)
    assert code == 0, err
    reference = json.loads(out)["noise"]
    for log in (ulog, dataflash):
        code, out, err = run(["allan", log, "--instance", "1", "--terms", "N", "--json"], capsys)
        assert code == 0, err
        noise = json.loads(out)["noise"]
        for sensor in ("gyro", "accel"):
            assert noise[sensor]["N"] == pytest.approx(reference[sensor]["N"], rel=1e-9)
        device = " (device 1310996)" if log == ulog else ""  # DataFlash's: its INS_ACC2_ID, not logged here
        assert f"{log}: instance 1{device}: 100 Hz, 60000 samples (rate from the timestamps)" in err
    code, _, err = run(["allan", ulog, "--terms", "N"], capsys)
    assert code == 4
    assert err.count("\n") == 1 and "has 2 IMUs: instance 0 (device 1310988): 100 Hz, 60000 samples; " \
        "instance 1 (device 1310996): 100 Hz, 60000 samples; choose one with --instance N" in err


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    sweep = ChamberSweep(low_degc=0.0, high_degc=45.0, start_degc=20.0, ramp_degc_per_min=4.0, soak_s=240.0)
    capture = _plain(chamber_sweep(cubic_rate_unit(31), sweep, rate_hz=5.0, seed=1).to_capture())
    csv = folder / "sweep.csv"
    write_csv(csv, capture)
    return ulog_from_captures(folder / "sweep.ulg", {0: capture, 2: capture}), csv


def test_thermal_from_a_ulog_instance_fits_what_the_csv_fits(sweep, tmp_path, capsys) -> None:
    ulog, csv = sweep
    code, out, err = run(["thermal", csv, "-o", tmp_path / "csv.yaml", "--json", "--segments", "1"], capsys)
    assert code == 0, err
    reference = json.loads(out)
    code, out, err = run(["thermal", ulog, "--instance", "2", "-o", tmp_path / "log.yaml", "--json",
                          "--segments", "1"], capsys)
    assert code == 0, err
    fitted = json.loads(out)
    assert fitted["input"] == str(ulog)
    for key in ("reference_temp", "temp_range", "accel", "gyro", "accel_segments", "gyro_segments"):
        _same(fitted[key], reference[key], key)
    assert "raw driver output" in err and "instance 2 (device 1311004): 5 Hz" in err


def _same(a, b, where: str) -> None:
    """Equal structure and text, numbers within 1e-5 relative: the log's times are whole microseconds times
    1e-6, the CSV's parsed decimals, a last bit apart, which the dT filter and the 1-sigma carry on."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-5, abs=1e-15), where
    else:
        assert a == b, where


def test_thermal_needs_the_temperature_a_log_does_not_carry(tmp_path, capsys) -> None:
    sitl = DATA / "sample_logging_tagged_and_default_params.ulg"  # SITL writes 0 for the temperature
    code, _, err = run(["thermal", sitl, "--instance", "0", "-o", tmp_path / "p.yaml"], capsys)
    assert code == 4
    assert "carries no temperature" in err and "has no temperature; a thermal fit needs" in err


def test_calibrate_hand_held_from_a_log_and_mag_refused(tmp_path, capsys) -> None:
    truth = UnitTruth.random(32)
    segments = handheld_session(n_poses=20, seed=32, hold_s=4.0, initial_still_s=15.0)
    capture = _plain(simulate(truth, segments, rate_hz=100.0, seed=32).to_capture())
    csv = tmp_path / "hand.csv"
    write_csv(csv, capture)
    log = dataflash_from_captures(tmp_path / "hand.bin", {0: capture, 1: capture})
    code, out, err = run(["calibrate", csv, "--initial-still", "14", "--json"], capsys)
    assert code == 0, err
    reference = json.loads(out)
    code, out, err = run(["calibrate", log, "--instance", "0", "--initial-still", "14", "--json",
                          "-o", tmp_path / "unit.yaml"], capsys)
    assert code == 0, err
    result = json.loads(out)
    assert result["method"] == "free"
    # the same samples; the CSV's times are printed to the microsecond, the log's are integers of them: the
    # fits agree to the optimiser's tolerance
    np.testing.assert_allclose(result["accel"]["matrix"], reference["accel"]["matrix"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(result["gyro"]["bias"], reference["gyro"]["bias"], rtol=0, atol=1e-9)
    assert "nothing taken out" in err and "low-pass filtered" in err
    code, _, err = run(["calibrate", log, "--instance", "1", "--method", "mag"], capsys)  # no MAG messages
    assert code == 4 and "has no magnetometer columns (mx, my, mz)" in err and "Traceback" not in err
    # Without --instance the board: every IMU calibrated, with its rotation relative to the first.
    code, out, err = run(["calibrate", log, "--initial-still", "14", "--json"], capsys)
    assert code == 0, err
    assert [imu["instance"] for imu in json.loads(out)["imus"]] == [0, 1]


def test_calibrate_mag_from_a_ulog_is_the_csvs_calibration(tmp_path, capsys) -> None:
    from mocks.mag_sessions import mag_capture

    cap, _ = mag_capture("sphere", 1, initial_still_s=10.0, n_poses=40)
    cap = Capture(t=np.rint(cap.t * 1e6) * 1e-6, acc=cap.acc, gyro=cap.gyro, temp=cap.temp,
                  mag=np.float32(np.float32(cap.mag / 100.0) * np.float32(100.0)).astype(float))
    csv = tmp_path / "sphere.csv"
    write_csv(csv, cap)
    log = ulog_from_captures(tmp_path / "sphere.ulg", {0: cap})
    code, out, err = run(["calibrate", csv, "--method", "mag", "--json"], capsys)
    assert code == 0, err
    reference = json.loads(out)
    code, out, err = run(["calibrate", log, "--method", "mag", "--json"], capsys)
    assert code == 0, err
    result = json.loads(out)
    # the log holds gauss in float32: microtesla a few 1e-6 apart from the CSV's
    np.testing.assert_allclose(result["bias"], reference["bias"], rtol=0, atol=1e-3)
    np.testing.assert_allclose(result["matrix"], reference["matrix"], rtol=0, atol=1e-5)
    assert "magnetometer: sensor_mag 0 (device 396825), raw" in err


def test_apply_and_report_read_a_vendored_ulog(tmp_path, capsys) -> None:
    from tests.export_params import make_params

    params = tmp_path / "unit.yaml"
    make_params(seed=3, thermal=False).save(params)
    sample = DATA / "sample_log_small.ulg"
    out_csv = tmp_path / "corrected.csv"
    code, out, err = run(["apply", params, sample, "--instance", "1", "-o", out_csv], capsys)
    assert code == 0, err
    assert f"{out_csv}: 6 samples written" in out
    assert "instance 1 (device 3670050): 0.999949 Hz, 6 samples" in err
    assert "SENS_BOARD_ROT 4" in err
    assert len(read_csv(out_csv)) == 6
    code, _, err = run(["apply", params, sample, "-o", out_csv], capsys)
    assert code == 4 and "has 3 IMUs" in err
    html = tmp_path / "unit.html"
    code, out, err = run(["report", params, "--capture", sample, "--instance", "2", "-o", html], capsys)
    assert code == 0, err
    assert html.read_text().startswith("<!DOCTYPE html>") and "instance 2 (device 2621474)" in err
