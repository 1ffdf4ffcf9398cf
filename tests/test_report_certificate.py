"""Calibration certificates (``imu-station report``): the numbers in people's units against independent
conversions, the residuals per pose recovering an injected bias error, a whole certificate (every section,
a plan it fails) valid, self-contained, rendered by Chromium and printed to a PDF that is not blank; a
parameter file without sections, a factory run's certificate beside its record (attached with its
SHA-256), an unknown serial and a record whose files are gone."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from report_helpers import check_page, chromium, cli, not_blank, pdf_pages, screenshot

from protocols.units import STANDARD_GRAVITY
from station.acquisition.capture import Capture
from station.acquisition.capture_csv import write_csv
from station.common.files import sha256_file
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import DtempFilter, ThermalBias, ThermalModel, ThermalSegment
from station.export.params.file import ParamsFile
from station.factory.plan import SCHEMA as PLAN_SCHEMA
from station.factory.records import RecordStore
from station.plots.certificate import pose_residuals, thermal_points
from station.report import parameters

RATE = 100.0
POSES = ("+x", "-x", "+y", "-y", "+z", "-z")
RNG = np.random.default_rng(17)
ACCEL = SensorCalibration.from_parts(
    np.array([1.012, 0.995, 1.003]),
    np.array([[0, 2e-3, -1e-3], [1.5e-3, 0, 3e-3], [-2e-3, 1e-3, 0]]),
    np.array([0.08, -0.05, 0.12]),
    method="turntable: six-position analytic (Ferraris)",
    residual_rms=8e-4,
    stddev={"bias": [2e-3] * 3, "scale": [1e-4] * 3, "misalignment": [[0, 1e-4, 1e-4]] * 3},
)
GYRO = SensorCalibration.from_parts(
    np.array([1.004, 1.001, 0.998]),
    np.zeros((3, 3)),
    np.array([0.01, -0.02, 0.005]),
    method="turntable: rotations",
)
_COEFFS = np.zeros((3, 7))
_COEFFS[:, 2] = [1e-3, -2e-3, 5e-4]  # linear in T - T_ref
_COEFFS[:, 1] = [2e-5, 1e-5, -1e-5]
THERMAL = ThermalModel(
    25.0,
    DtempFilter(),
    accel=ThermalBias([ThermalSegment(-10, 60, _COEFFS)]),
    gyro=ThermalBias([ThermalSegment(-10, 60, _COEFFS * 1e-2)]),
)
MAG_MATRIX = np.diag([1.1, 0.95, 1.02])
MAG_BIAS = np.array([12.0, -7.0, 30.0])
TIGHT_PLAN = f"""\
schema: {PLAN_SCHEMA}
name: tight
sequence: {{name: six-position, rotations: false, hold_s: 1}}
device: {{rate_hz: 100}}
run: {{timeout_s: 120, step_timeout_s: 20}}
limits:
  accel.bias: {{max_abs: 100, unit: mg}}
  accel.scale_error: {{max_abs: 1, unit: "%"}}
"""


def six_pose_capture(accel: SensorCalibration, gyro: SensorCalibration, with_mag: bool = False) -> Capture:
    """Three seconds a pose through the forward model raw = M true + b, with white noise; the
    magnetometer (when asked) sweeps directions through raw = A true + b_m."""
    acc, rates, steps = [], [], []
    n = int(3 * RATE)
    for label in POSES:
        up = np.zeros(3)
        up["xyz".index(label[1])] = 1.0 if label[0] == "+" else -1.0
        acc.append(accel.matrix @ (STANDARD_GRAVITY * up) + accel.bias + 5e-3 * RNG.standard_normal((n, 3)))
        rates.append(gyro.bias + 1e-5 * RNG.standard_normal((n, 3)))
        steps += [label] * n
    total = n * len(POSES)
    mag = None
    if with_mag:
        d = RNG.standard_normal((total, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        mag = (48.0 * d) @ MAG_MATRIX.T + MAG_BIAS
    return Capture(
        np.arange(total) / RATE,
        np.vstack(acc),
        np.vstack(rates),
        step=np.array(steps),
        device={"serial": "CERT-1", "model": "imu-sim-mems", "firmware": "1.0.0"},
        mag=mag,
    )


def still_capture(seconds: float = 300.0) -> Capture:
    """A still unit: white noise of the noise section's N on every axis (the measured Allan curve)."""
    n = int(seconds * RATE)
    acc = np.array([0, 0, STANDARD_GRAVITY]) + 1e-3 * np.sqrt(RATE) * RNG.standard_normal((n, 3))
    gyro = 2e-4 * np.sqrt(RATE) * RNG.standard_normal((n, 3))
    return Capture(np.arange(n) / RATE, acc, gyro)


def thermal_sweep(model: ThermalModel, factor: float = 1.0) -> Capture:
    """Twenty minutes on +z, then on -z, at 10 Hz while the temperature climbs 0 -> 50 degC: the raw
    readings carry the intrinsics and ``factor`` times the model's thermal bias."""
    n = 12000
    temp = np.linspace(0.0, 50.0, 2 * n)
    up = np.repeat([[0, 0, 1.0], [0, 0, -1.0]], n, axis=0)
    assert model.accel is not None and model.gyro is not None
    thermal_a = model.accel.evaluate(temp, np.zeros_like(temp), model.reference_temp)
    thermal_g = model.gyro.evaluate(temp, np.zeros_like(temp), model.reference_temp)
    acc = STANDARD_GRAVITY * up @ ACCEL.matrix.T + ACCEL.bias + factor * thermal_a
    gyro = GYRO.bias + factor * thermal_g + 1e-5 * RNG.standard_normal((2 * n, 3))
    return Capture(
        np.arange(2 * n) / 10.0,
        acc + 2e-3 * RNG.standard_normal((2 * n, 3)),
        gyro,
        temp=temp,
        step=np.array(["+z"] * n + ["-z"] * n),
    )


def test_thermal_points_follow_the_model_they_were_made_with() -> None:
    params = ParamsFile(accel=ACCEL, gyro=GYRO, thermal=THERMAL)
    points = thermal_points(thermal_sweep(THERMAL), params)
    for name in ("accel", "gyro"):
        temp, bias = points[name]
        model = getattr(THERMAL, name).evaluate(temp, np.zeros_like(temp), THERMAL.reference_temp)
        span = np.ptp(model, axis=0).max()
        assert len(temp) == 80 and temp.min() < 1.0 and temp.max() > 49.0
        assert np.abs(bias - model).max() < 0.02 * span, name  # within 2 % of the model's own range
        # a sweep with twice the thermal bias does not follow the model: the plot would show it
        doubled = thermal_points(thermal_sweep(THERMAL, 2.0), params)[name][1]
        assert np.abs(doubled - model).max() > 0.15 * span, name  # each pose spans half the sweep


def full_params(tmp: Path, capture_path: Path, still_path: Path, sweep_path: Path) -> Path:
    """A parameter file with every section the certificate draws (accel, gyro, noise, thermal, mag,
    characterisation), its accel and mag sections naming the six-pose capture by SHA-256, its noise
    section the still one, its thermal section the sweep."""
    params = ParamsFile(device={"serial": "CERT-1", "model": "imu-sim-mems", "firmware": "1.0.0"})
    source = {"capture": str(capture_path), "sha256": sha256_file(capture_path), "serial": "CERT-1"}
    params.set_section("accel", ACCEL, source)
    params.set_section("gyro", GYRO, source)
    terms = {
        "N": [2e-4, 2.1e-4, 1.9e-4],
        "K": [3e-6, 2e-6, 4e-6],
        "B": [1e-5, 1.2e-5, 9e-6],
        "Q": None,
        "R": None,
    }
    params.set_section(
        "noise",
        {
            "method": "overlapping Allan deviation",
            "gyro": {
                **terms,
                "stddev": {"N": [1e-5] * 3, "K": [5e-7] * 3, "B": [1e-6] * 3, "Q": None, "R": None},
            },
            "accel": {
                "N": [1e-3] * 3,
                "K": [2e-5] * 3,
                "B": [5e-5] * 3,
                "Q": None,
                "R": None,
                "stddev": {"N": [5e-5] * 3, "K": None, "B": None, "Q": None, "R": None},
            },
            "record": {"tau_range_s": [0.01, 2000.0]},
        },
        {"capture": str(still_path), "sha256": sha256_file(still_path)},
    )
    params.set_section("thermal", THERMAL, {"capture": str(sweep_path), "sha256": sha256_file(sweep_path)})
    params.set_section(
        "mag",
        {
            "matrix": MAG_MATRIX.tolist(),
            "bias": MAG_BIAS.tolist(),
            "correction": np.linalg.inv(MAG_MATRIX).tolist(),
            "frame": "sensor",
            "field_norm": 48.0,
            "residual_rms": 0.3,
            "coverage": 0.93,
            "stddev": {"bias": [0.1, 0.1, 0.12]},
        },
        source,
    )
    params.set_section(
        "characterisation",
        {
            "turn_ons": 10,
            "accel_bias_repeatability": [1e-3, 2e-3, 1.5e-3],
            "gyro_bias_repeatability": [1e-4, 2e-4, None],
        },
    )
    path = tmp / "unit.yaml"
    params.save(path)
    return path


def test_parameters_in_people_units_against_independent_conversions() -> None:
    section = ParamsFile(accel=ACCEL).to_dict()["accel"]
    rows = {(r.quantity, r.axis): r for r in parameters.sensor_rows("accel", section)}
    for i, axis in enumerate("xyz"):
        assert rows["bias", axis].value == pytest.approx(ACCEL.bias[i] / STANDARD_GRAVITY * 1000.0)
        assert rows["bias", axis].unit == "mg"
        assert rows["bias", axis].sigma == pytest.approx(2e-3 / STANDARD_GRAVITY * 1000.0)
        assert rows["scale error", axis].value == pytest.approx((ACCEL.scale[i] - 1.0) * 1e6)
    assert rows["misalignment", "xy"].value == pytest.approx(math.degrees(ACCEL.misalignment[0, 1]))
    assert rows["misalignment", "xy"].unit == "deg"
    assert rows["residual RMS", ""].value == pytest.approx(8e-4 / STANDARD_GRAVITY * 1000.0)
    gyro = {
        (r.quantity, r.axis): r
        for r in parameters.sensor_rows("gyro", ParamsFile(gyro=GYRO).to_dict()["gyro"])
    }
    assert (
        gyro["bias", "y"].value == pytest.approx(math.degrees(-0.02) * 3600.0)
        and gyro["bias", "y"].sigma is None
    )
    noise = {
        (r.quantity, r.axis): r
        for r in parameters.noise_rows({"gyro": {"N": [2e-4, 0, 0], "B": [1e-5, 0, 0]}})
    }
    assert noise["gyroscope N", "x"].value == pytest.approx(math.degrees(2e-4) * 60.0)  # deg/sqrt(h)
    assert noise["gyroscope B", "x"].value == pytest.approx(math.degrees(1e-5) * 3600.0)  # deg/h


def test_residuals_per_pose_recover_an_injected_bias_error() -> None:
    capture = six_pose_capture(ACCEL, GYRO)
    exact = pose_residuals(capture, ParamsFile(accel=ACCEL, gyro=GYRO))
    assert [r["pose"] for r in exact] == list(POSES)
    for r in exact:  # the true calibration leaves noise alone: 5 mm/s^2 / sqrt(300) ~ 0.03 mg
        assert np.abs(r["accel_mg"]).max() < 0.2
        assert np.abs(r["gyro_dph"]).max() < 1.0
    # an independent computation: solve M a = mean(raw) - b per pose, minus g u
    part = capture.segments()[4][1]
    a = np.linalg.solve(ACCEL.matrix, capture.acc[part].mean(axis=0) - ACCEL.bias)
    g = np.median(
        [
            np.linalg.norm(np.linalg.solve(ACCEL.matrix, capture.acc[p].mean(axis=0) - ACCEL.bias))
            for _, p in capture.segments()
        ]
    )
    assert exact[4]["accel_mg"] == pytest.approx(
        (a - g * np.array([0, 0, 1.0])) / STANDARD_GRAVITY * 1e3, abs=1e-9
    )
    # a bias 2 mg off on x shows as -2 mg (through the correction) in every pose
    wrong = SensorCalibration(ACCEL.matrix, ACCEL.bias + np.array([2e-3 * STANDARD_GRAVITY, 0, 0]))
    shifted = pose_residuals(capture, ParamsFile(accel=wrong))
    off = np.mean([r["accel_mg"] for r in shifted], axis=0) - np.mean([r["accel_mg"] for r in exact], axis=0)
    assert off == pytest.approx(-(np.linalg.inv(ACCEL.matrix) @ [2.0, 0, 0]), abs=0.05)
    assert shifted[0]["gyro_dph"] is None  # no gyro section: no gyro residuals


def test_a_whole_certificate_with_every_section_and_a_failed_limit(tmp_path: Path) -> None:
    chromium()  # --pdf needs it: skipped, saying so, where it is not installed
    capture_path = tmp_path / "six-pose.csv"
    write_csv(capture_path, six_pose_capture(ACCEL, GYRO, with_mag=True))
    still_path = tmp_path / "still.csv"
    write_csv(still_path, still_capture())
    sweep_path = tmp_path / "sweep.csv"
    write_csv(sweep_path, thermal_sweep(THERMAL))
    params = full_params(tmp_path, capture_path, still_path, sweep_path)
    (tmp_path / "plan.yaml").write_text(TIGHT_PLAN)
    done = cli(
        "report",
        str(params),
        "--capture",
        str(capture_path),
        "--capture",
        str(still_path),
        "--capture",
        str(sweep_path),
        "--plan",
        "plan.yaml",
        "--operator",
        "J. Smith",
        "--station",
        "bench-2",
        "-o",
        "unit.html",
        "--pdf",
        "unit.pdf",
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    text = check_page(tmp_path / "unit.html")
    for needed in (
        "CERT-1",
        "imu-sim-mems",
        "J. Smith",
        "bench-2",
        "six-position",
        sha256_file(capture_path),
        sha256_file(params),
        "turntable: six-position analytic (Ferraris)",
        "deg/h",
        "ppm",
        "mg",
    ):
        assert needed in text, needed
    # scale error 1.2 % against 1 %: FAIL; biases within 100 mg: PASS; the verdict is FAIL
    fail_row = next(p for p in text.split("<tr") if "accel.scale_error.x" in p)
    assert ">FAIL<" in fail_row
    assert ">PASS<" in next(p for p in text.split("<tr") if "accel.bias.x" in p)
    assert 'class="verdict FAIL"' in text
    for title in (
        "Residuals per pose",
        "Allan deviation",
        "Bias against temperature",
        "Magnetometer coverage and corrected sphere",
    ):
        assert title in text
    assert text.count("<svg") == 4
    assert "measured curve with its 68 % interval from " + str(still_path) in text
    assert "Datasheet figures" in text and "angle random walk" in text
    assert "30 s block means of " + str(sweep_path) in text
    assert "has no section" not in text  # every section is there
    assert "hard iron" in text and "bias repeatability" in text
    not_blank(screenshot(tmp_path / "unit.html", tmp_path))
    pages = pdf_pages(tmp_path / "unit.pdf", tmp_path)
    assert len(pages) >= 2
    for page in pages[:2]:
        not_blank(page)


def test_a_parameter_file_without_sections_says_what_it_lacks(tmp_path: Path) -> None:
    ParamsFile(device={"serial": "BARE-1"}, accel=ACCEL).save(tmp_path / "bare.yaml")
    done = cli("report", "bare.yaml", "-o", "bare.html", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    text = check_page(tmp_path / "bare.html")
    assert "the parameter file has no section gyro, thermal, noise, mag, characterisation" in text
    assert "residuals per pose: give the calibration&#39;s labelled capture" in text
    assert "NOT JUDGED" in text and "<svg" not in text
    assert "no section" in done.stderr  # and the terminal says so too
    done = cli("report", "missing.yaml", "-o", "x.html", cwd=tmp_path)
    assert done.returncode == 4 and "missing.yaml" in done.stderr and not (tmp_path / "x.html").exists()
    done = cli("report", "-o", "x.html", cwd=tmp_path)
    assert done.returncode == 4 and "--serial" in done.stderr


def test_factory_run_certificate_and_records_whose_files_are_gone(tmp_path: Path) -> None:
    (tmp_path / "plan.yaml").write_text(TIGHT_PLAN)
    done = cli(
        "run",
        "--plan",
        "plan.yaml",
        "--simulate",
        "--seed",
        "4",
        "--serial",
        "SIM-4",
        "--speed",
        "5",
        "--db",
        "line.sqlite",
        cwd=tmp_path,
        env={"IMU_STATION_ID": "line-c-1"},
    )
    assert done.returncode in (0, 1), done.stderr
    with RecordStore.open(tmp_path / "line.sqlite") as store:
        (record,) = store.query(serial="SIM-4")
    cert = next(a for a in record.attachments() if a.name == "calibration certificate")
    path = Path(record.files_dir) / cert.path
    assert (
        path.name == "certificate.html" and cert.sha256 == sha256_file(path) and cert.mimetype == "text/html"
    )
    assert record.verify() == []
    text = check_page(path)
    assert f'class="verdict {record.outcome}"' in text and "line-c-1" in text and record.run_id in text
    assert "Residuals per pose" in text  # the run's own capture, in memory
    assert (
        yaml.safe_load((Path(record.files_dir) / "record.json").read_text())["phases"][-1]["attachments"][-1][
            "sha256"
        ]
        == cert.sha256
    )
    # from the database, the same record
    done = cli("report", "--db", "line.sqlite", "--serial", "SIM-4", "-o", "again.html", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Residuals per pose" in check_page(tmp_path / "again.html")
    done = cli("report", "--db", "line.sqlite", "--serial", "NOPE-9", "-o", "x.html", cwd=tmp_path)
    assert done.returncode == 4 and "--serial NOPE-9: no record of this unit" in done.stderr
    done = cli(
        "report", "--db", "line.sqlite", "--serial", "SIM-4", "--run", "zz", "-o", "x.html", cwd=tmp_path
    )
    assert done.returncode == 4 and "--run zz" in done.stderr
    # the files are gone: the certificate says so and shows the record's measurements
    (Path(record.files_dir) / "params.yaml").unlink()
    shutil.copy(Path(record.files_dir) / "capture.csv", tmp_path / "kept.csv")
    (Path(record.files_dir) / "capture.csv").unlink()
    done = cli("report", "--db", "line.sqlite", "--serial", "SIM-4", "-o", "gone.html", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    text = check_page(tmp_path / "gone.html")
    assert "params.yaml: missing" in text and "capture.csv: missing" in text
    assert "accel.bias.x" in text and "No parameter file is at hand." in text
    assert "missing" in done.stderr
