"""Export of a parameter file the engines produce: a simulated unit calibrated on a simulated
turntable (`imu-station calibrate`), its thermal model fitted on a simulated chamber sweep (the
thermal engine), then the exported C run over the sweep as a firmware loop would (its own dT
filter, then imu_calib_apply) against `imu-station apply` on the same capture.

Tolerance: 2e-6 relative to the sample's magnitude, as in test_export_c (float32 in C, the
capture CSV's 9 significant digits on the apply side)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_export_c import build, relative_error, run

from mocks.chamber import ChamberSweep, chamber_sweep
from mocks.rig import sequence_segments, simulate
from mocks.truth import UnitTruth
from station.acquisition.capture import read_capture
from station.acquisition.capture_csv import write_csv
from station.cli import main
from station.engines.thermal.fit import ThermalSettings, ThermalSweep, fit_thermal
from station.export.params.file import ParamsFile

SWEEP = ChamberSweep(low_degc=0.0, high_degc=40.0, start_degc=20.0, ramp_degc_per_min=4.0, soak_s=120.0)


@pytest.fixture(scope="module")
def engine_unit(tmp_path_factory: pytest.TempPathFactory) -> dict:
    work = tmp_path_factory.mktemp("engines")
    truth = UnitTruth.random(21)
    turntable = simulate(truth, sequence_segments("six-position", rotations=True, hold_s=2.0), rate_hz=100.0,
                         seed=1)
    write_csv(work / "turntable.csv", turntable.to_capture())
    params_path = work / "unit.yaml"
    argv = ["calibrate", str(work / "turntable.csv"), "--method", "turntable", "-o", str(params_path)]
    assert main(argv) == 0
    sweep = chamber_sweep(truth, SWEEP, rate_hz=5.0, seed=2).recording
    params = ParamsFile.load(params_path)
    data = ThermalSweep(sweep.t, sweep.temp, sweep.acc, sweep.gyro, sweep.step, accel_cal=params.accel,
                        gyro_cal=params.gyro)
    fit = fit_thermal(data, ThermalSettings(segments=2, tau_s=10.0))
    params.thermal = fit.model
    params.save(params_path)
    write_csv(work / "sweep.csv", sweep.to_capture())
    return {"dir": work, "params": params_path, "truth": truth}


def test_exported_c_agrees_with_imu_station_apply(engine_unit: dict, capsys) -> None:
    work, params = engine_unit["dir"], engine_unit["params"]
    assert main(["apply", str(params), str(work / "sweep.csv"), "-o", str(work / "corrected.csv")]) == 0
    assert "thermal: applied with dT estimated" in capsys.readouterr().out
    assert main(["export", str(params), "-f", "c", "-o", str(work / "fw"), "--station-id", "e2e"]) == 0
    exe = build(work / "fw", "c")
    raw = read_capture(work / "sweep.csv")
    rows = np.zeros((len(raw.t), 8), dtype=np.float32)
    rows[1:, 0] = np.diff(raw.t)
    rows[:, 1] = raw.temp
    rows[:, 2:5] = raw.acc
    rows[:, 5:8] = raw.gyro
    rows.astype("<f4").tofile(work / "stream.f32")
    blob = work / "fw" / "imu_calib.bin"
    run([str(exe), "stream", str(blob), str(work / "stream.f32"), str(work / "c.f32")], work)
    got = np.fromfile(work / "c.f32", dtype="<f4").reshape(-1, 6).astype(np.float64)
    corrected = read_capture(work / "corrected.csv")
    ref = np.hstack([corrected.acc, corrected.gyro])
    assert relative_error(got, ref, rows) < 2e-6
    # The file really carries what the engines found: a two-segment thermal model with dT terms.
    p = ParamsFile.load(params)
    assert len(p.thermal.accel.segments) == 2 and p.accel.method


def test_autopilot_exports_of_an_engine_file_report_small_losses(engine_unit: dict, capsys) -> None:
    work, params = engine_unit["dir"], engine_unit["params"]
    truth = engine_unit["truth"]
    for fmt in ("px4", "ardupilot"):
        out = work / f"unit.{fmt}"
        argv = ["export", str(params), "-f", fmt, "-o", str(out), "--device-id", "1310988", "--json"]
        assert main(argv) == 0
        report = json.loads(capsys.readouterr().out)
        sizes = {(lim["triad"], lim["what"]): lim["size"] for lim in report["limitations"]}
        # Misalignment of the simulated MEMS unit (~5 mrad) leaves about g * 5e-3 at the poses.
        s = np.abs(truth.accel.misalignment).max()
        assert 0.2 * 9.8 * s < sizes[("accel", "misalignment")] < 3 * 9.8 * s
        # A cubic truth fitted with two continuous segments: one cubic holds it to a few percent.
        p = ParamsFile.load(params)
        temp = np.linspace(0.0, 40.0, 81)
        bias = p.thermal.accel.evaluate(temp, np.zeros_like(temp), p.thermal.reference_temp)
        variation = np.linalg.norm(bias.max(axis=0) - bias.min(axis=0))
        assert sizes[("accel", "thermal model as one cubic")] < 0.1 * variation
