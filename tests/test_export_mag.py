"""The magnetometer and the gyro g-sensitivity in the PX4 and ArduPilot exports, and every export
on a parameter file holding any subset of sections.

The autopilots' formulas are written here from their sources, independently of station.export:
PX4 (sensor_calibration/Magnetometer.hpp, Correct; parameters in gauss):
    mag = W (raw - CAL_MAGn_{X,Y,Z}OFF),  W = [[XSCALE, XODIAG, YODIAG], [XODIAG, YSCALE, ZODIAG],
                                              [YODIAG, ZODIAG, ZSCALE]]
ArduPilot (AP_Compass_Backend::correct_field; milligauss, offsets added, COMPASS_SCALE 0 = none):
    mag = W (raw + COMPASS_OFS),  W = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]]
Tolerances: where the target holds the model (frame sensor: a symmetric correction), 2e-6 of the
field; with the accelerometer frame, the error is the rotation the export reports (1e-5 relative).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from autopilot_params import read_ardupilot, read_px4
from export_params import FIELD_UT, make_params
from test_export_autopilot import pose_inputs

from station.cli import main
from station.engines.shared.correction import apply_calibration
from station.export.autopilot.ardupilot import build_ardupilot, render_ardupilot
from station.export.autopilot.px4 import build_px4, render_px4
from station.export.firmware.blob import FLAG_MAG, parse_blob
from station.export.params.file import ParamsFile

G = 9.80665
FIELDS = np.vstack([np.eye(3), -np.eye(3), np.random.default_rng(5).normal(0.0, 1.0, (200, 3))])
FIELDS = FIELD_UT * FIELDS / np.linalg.norm(FIELDS, axis=1, keepdims=True)


def px4_mag(path: Path, raw_ut: np.ndarray, i: int = 0) -> np.ndarray:
    v = {name: value for name, (value, _) in read_px4(path).items()}
    p = f"CAL_MAG{i}_"
    w = np.array([[v[p + "XSCALE"], v[p + "XODIAG"], v[p + "YODIAG"]],
                  [v[p + "XODIAG"], v[p + "YSCALE"], v[p + "ZODIAG"]],
                  [v[p + "YODIAG"], v[p + "ZODIAG"], v[p + "ZSCALE"]]])
    off = np.array([v[p + a + "OFF"] for a in "XYZ"])
    return (raw_ut / 100.0 - off) @ w.T * 100.0


def ardupilot_mag(path: Path, raw_ut: np.ndarray, n: str = "") -> np.ndarray:
    v = read_ardupilot(path)
    w = np.array([[v[f"COMPASS_DIA{n}_X"], v[f"COMPASS_ODI{n}_X"], v[f"COMPASS_ODI{n}_Y"]],
                  [v[f"COMPASS_ODI{n}_X"], v[f"COMPASS_DIA{n}_Y"], v[f"COMPASS_ODI{n}_Z"]],
                  [v[f"COMPASS_ODI{n}_Y"], v[f"COMPASS_ODI{n}_Z"], v[f"COMPASS_DIA{n}_Z"]]])
    assert v[f"COMPASS_SCALE{n}"] == 0.0  # no scaling: W holds ours
    return (raw_ut * 10.0 + np.array([v[f"COMPASS_OFS{n}_{a}"] for a in "XYZ"])) @ w.T / 10.0


TARGETS = {"px4": (build_px4, render_px4, px4_mag),
           "ardupilot": (build_ardupilot, render_ardupilot, ardupilot_mag)}


def written(target: str, params: ParamsFile, tmp_path: Path, **kw):
    build, render, firmware = TARGETS[target]
    result = build(params, **kw)
    path = tmp_path / f"unit.{target}"
    path.write_text(render(result, params, "st", "2026-11-22T10:00:00Z"))
    return result, path, firmware


def raw_field(params: ParamsFile, true: np.ndarray) -> np.ndarray:
    mag = params.other["mag"]
    return true @ np.asarray(mag["matrix"]).T + np.asarray(mag["bias"])


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_symmetric_soft_iron_is_held_exactly(target: str, tmp_path: Path) -> None:
    params = make_params(seed=11, mag="sensor")
    result, path, firmware = written(target, params, tmp_path)
    got = firmware(path, raw_field(params, FIELDS))
    assert np.max(np.abs(got - FIELDS)) < 2e-6 * FIELD_UT
    lim = {(x.triad, x.what): x for x in result.limitations}[("mag", "rotation (polar part of C)")]
    assert lim.size < 1e-9 * FIELD_UT and lim.unit == "uT"
    assert max(result.pose_errors["mag"]["at_reference"]) < 2e-6 * FIELD_UT


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_rotation_to_the_accel_frame_is_reported_with_its_size(target: str, tmp_path: Path) -> None:
    params = make_params(seed=12, mag="accel")
    result, path, firmware = written(target, params, tmp_path)
    got = firmware(path, raw_field(params, FIELDS))
    # The magnitude survives; the direction turns by the rotation the target cannot hold.
    assert np.allclose(np.linalg.norm(got, axis=1), FIELD_UT, rtol=2e-6)
    correction = np.asarray(params.other["mag"]["correction"])
    w, _, vt = np.linalg.svd(correction)
    angle = np.arccos((np.trace(w @ vt) - 1) / 2)
    assert np.radians(0.5) < angle < np.radians(10)  # the fixture's rotation is really there
    err = np.linalg.norm(got - FIELDS, axis=1)
    assert np.max(err) <= 2 * np.sin(angle / 2) * FIELD_UT * (1 + 1e-5)
    lim = {(x.triad, x.what): x for x in result.limitations}[("mag", "rotation (polar part of C)")]
    assert lim.size == pytest.approx(2 * np.sin(angle / 2) * FIELD_UT, rel=1e-9)
    assert f"{np.degrees(angle):.3g} deg" in lim.detail and "frame accel" in lim.detail
    assert np.allclose(result.pose_errors["mag"]["at_reference"], err[:6][[0, 3, 1, 4, 2, 5]], rtol=1e-5)


def test_units_and_signs_of_the_offsets(tmp_path: Path) -> None:
    params = make_params(seed=13, accel=False, gyro=False, thermal=False, mag="accel")
    bias = np.asarray(params.other["mag"]["bias"])
    _, px4_path, _ = written("px4", params, tmp_path)
    p = read_px4(px4_path)
    assert set(p) == {f"CAL_MAG0_{a}{w}" for a in "XYZ" for w in ("OFF", "SCALE", "ODIAG")}
    # gauss, subtracted
    assert np.allclose([p[f"CAL_MAG0_{a}OFF"][0] for a in "XYZ"], bias / 100.0, rtol=1e-6)
    assert all(kind == 9 for _, kind in p.values())
    _, ardu_path, _ = written("ardupilot", params, tmp_path, instance=1)
    v = read_ardupilot(ardu_path)
    assert set(v) == {f"COMPASS_{w}2_{a}" for w in ("OFS", "DIA", "ODI") for a in "XYZ"} | {"COMPASS_SCALE2"}
    assert np.allclose([v[f"COMPASS_OFS2_{a}"] for a in "XYZ"], -bias * 10.0, rtol=1e-6)  # mGauss, added
    got = ardupilot_mag(ardu_path, raw_field(params, FIELDS), n="2")
    assert np.allclose(np.linalg.norm(got, axis=1), FIELD_UT, rtol=2e-6)


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_gyro_g_sensitivity_is_reported_as_dropped(target: str) -> None:
    params = make_params(seed=14, thermal=False, g_sensitivity=True)
    result = TARGETS[target][0](params)
    g_matrix = np.asarray(params.gyro.extra["g_sensitivity"])
    poses = np.repeat(np.eye(3), 2, axis=0) * np.tile([G, -G], 3)[:, None]
    left = np.linalg.norm(poses @ g_matrix.T @ np.linalg.inv(params.gyro.matrix).T, axis=1)
    lim = {(x.triad, x.what): x for x in result.limitations}[("gyro", "g-sensitivity")]
    assert lim.size == pytest.approx(left.max(), rel=1e-9) and lim.unit == "rad/s"
    assert 1e-4 < lim.size < 1e-2  # ~0.1 deg/s per g: really there
    # The gyro pose errors count it: the autopilot's gyro against ours with the bias G f in the input.
    raw_acc, raw_gyro, temp = pose_inputs(params, np.array([25.0]))
    raw_gyro = raw_gyro + (poses @ g_matrix.T)
    _, ours = apply_calibration(raw_acc, raw_gyro, temp, None, params.accel, params.gyro, None, g_matrix)
    theirs = raw_gyro - params.gyro.bias
    assert np.allclose(result.pose_errors["gyro"]["at_reference"], np.linalg.norm(theirs - ours, axis=1),
                       rtol=1e-5)


SUBSETS = {
    "mag only": {"accel": False, "gyro": False, "thermal": False, "mag": "accel"},
    "accel only": {"gyro": False, "thermal": False},
    "gyro only": {"accel": False, "thermal": False},
    "noise only": {"accel": False, "gyro": False, "thermal": False, "noise": True},
    "thermal and noise": {"noise": True},
}
CARRYING = ("c", "bin", "px4", "ardupilot")


@pytest.mark.parametrize("subset", list(SUBSETS))
@pytest.mark.parametrize("fmt", ["c", "bin", "json", "yaml", "px4", "ardupilot"])
def test_every_format_on_every_subset(subset: str, fmt: str, tmp_path: Path, capsys) -> None:
    params = make_params(seed=15, **SUBSETS[subset])
    source = tmp_path / "unit.yaml"
    params.save(source)
    out = tmp_path / ("fw" if fmt == "c" else f"out.{fmt}")
    code = main(["export", str(source), "-f", fmt, "-o", str(out), "--station-id", "st", "--json"])
    captured = capsys.readouterr()
    if subset == "noise only" and fmt in CARRYING:
        assert code == 4
        assert "holds only noise" in captured.err and f"--format {fmt}" in captured.err
        assert not out.exists()
        return
    assert code == 0, captured.err
    report = json.loads(captured.out)
    notes = " ".join(report.get("notes", []))
    if "noise" in SUBSETS[subset] and fmt in CARRYING:
        assert f"{fmt} does not carry the file's noise section: not written" in notes
    else:
        assert "does not carry" not in notes
    if fmt in ("json", "yaml"):
        text = out.read_text()
        back = ParamsFile.from_dict(json.loads(text) if fmt == "json" else yaml.safe_load(text), out)
        assert back.other.get("mag") == params.other.get("mag")
        assert back.noise == params.noise and (back.accel is None) == (params.accel is None)
    elif fmt in ("c", "bin"):
        blob = parse_blob((out / "imu_calib.bin" if fmt == "c" else out).read_bytes())
        assert (blob.mag is not None) == ("mag" in SUBSETS[subset])
        assert (blob.flags & FLAG_MAG != 0) == ("mag" in SUBSETS[subset])
    else:
        names = set(report["parameters"])
        assert names == {p.split(",")[0] if fmt == "ardupilot" else p.split("\t")[2]
                         for p in out.read_text().splitlines() if not p.startswith("#")}
        has_compass = any(n.startswith(("CAL_MAG", "COMPASS_")) for n in names)
        assert has_compass == (subset == "mag only")
        if subset == "mag only":
            # Nothing of the IMU: above all not INS_TCAL1_ENABLE = 0, which would switch off the
            # vehicle's own temperature calibration.
            assert all(n.startswith(("CAL_MAG", "COMPASS_")) for n in names)
            assert set(report["pose_errors"]) == {"mag"}


def test_text_report_of_a_mag_only_file(tmp_path: Path, capsys) -> None:
    source = tmp_path / "unit.yaml"
    make_params(seed=16, accel=False, gyro=False, thermal=False, mag="accel").save(source)
    png = tmp_path / "loss.png"
    argv = ["export", str(source), "-f", "ardupilot", "-o", str(tmp_path / "u.param"), "--plot", str(png)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "what ardupilot cannot hold" in text and "rotation (polar part of C)" in text
    assert f"mag error at the six field directions, |B| {FIELD_UT:g} uT (uT): +x" in text
    assert "not written, the file has no accel or gyro offsets to draw" in text and not png.exists()


def test_large_hard_iron_warns_against_ardupilots_arming_limit() -> None:
    params = make_params(seed=17, accel=False, gyro=False, thermal=False, mag="sensor")
    params.other["mag"]["bias"] = [200.0, 0.0, -10.0]  # 2000 mGauss on x
    notes = " ".join(build_ardupilot(params).notes)
    assert "exceed COMPASS_OFFS_MAX's default 1800" in notes
    params.other["mag"]["bias"] = [150.0, 0.0, -10.0]
    assert "COMPASS_OFFS_MAX" not in " ".join(build_ardupilot(params).notes)


def test_simulated_nine_axis_unit_through_apply_the_c_and_the_autopilots(tmp_path: Path, capsys) -> None:
    """A simulated desk session (mocks.mag_sessions) with the unit's true magnetometer as the mag
    section: 'imu-station apply' and the exported C give the truth's own inverse of the field, and
    the autopilots report the unit's rotation against the accelerometer."""
    from test_export_c import build, c_apply, relative_error

    from mocks.mag_sessions import mag_capture
    from station.acquisition.capture_csv import read_csv, write_csv
    from station.engines.shared.sensor_model import SensorCalibration
    from station.export.firmware.c_source import write_c_export

    capture, truth = mag_capture("desk", seed=3)
    mag = truth.mag
    params = ParamsFile(device={"serial": truth.serial},
                        accel=SensorCalibration(truth.accel.matrix, truth.accel.bias, method="truth"))
    matrix = mag.soft_iron @ mag.rotation
    params.other["mag"] = {"matrix": matrix.tolist(), "bias": mag.hard_iron.tolist(),
                           "correction": np.linalg.inv(matrix).tolist(), "frame": "accel",
                           "field_norm": mag.field.magnitude_ut}
    source, raw_csv, out = tmp_path / "unit.yaml", tmp_path / "raw.csv", tmp_path / "corrected.csv"
    params.save(source)
    write_csv(raw_csv, capture)
    assert main(["apply", str(source), str(raw_csv), "-o", str(out)]) == 0
    raw, corrected = read_csv(raw_csv), read_csv(out)
    np.testing.assert_allclose(corrected.mag, mag.correct(raw.mag), atol=1e-5)
    # The field's magnitude comes back to the Earth field within the unit's noise and resolution.
    assert np.abs(np.linalg.norm(corrected.mag, axis=1) - 50.0).max() < 1.0
    # The C on the same raw samples.
    write_c_export(ParamsFile.load(source), tmp_path / "fw", "st", 0)
    rows = np.zeros((len(raw.t), 11), dtype=np.float32)
    rows[:, 0] = np.nan
    rows[:, 2:5], rows[:, 5:8], rows[:, 8:11] = raw.acc, raw.gyro, raw.mag
    got, _ = c_apply(build(tmp_path / "fw", "c"), tmp_path / "fw" / "imu_calib.bin", rows, tmp_path)
    reference = np.hstack([corrected.acc, corrected.gyro, corrected.mag])
    assert relative_error(got, reference, rows) < 2e-6
    # What PX4 drops is the unit's own rotation against the accelerometer.
    capsys.readouterr()
    assert main(["export", str(source), "-f", "px4", "-o", str(tmp_path / "u.params"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    lim = next(x for x in report["limitations"] if x["triad"] == "mag")
    true_angle = np.degrees(np.arccos((np.trace(mag.rotation) - 1) / 2))
    assert 1.0 <= true_angle <= 2.0 and f"{true_angle:.3g} deg" in lim["detail"]
