"""PX4 and ArduPilot exports read back from the written files, their firmware formulas applied in
numpy (written here from the autopilots' sources, independently of station.export), compared
with our own correction at the six calibration poses.

PX4 (sensor_calibration/Accelerometer.hpp, TemperatureCompensation.cpp):
    acc = (raw - TC(T) - OFF) * SCALE,  gyro = raw - TC(T) - OFF,
    TC(T) = X0 + X1 d + X2 d^2 + X3 d^3,  d = min(max(T, TMIN), TMAX) - TREF.
ArduPilot (AP_InertialSensor_Backend.cpp, AP_InertialSensor_tempcal.cpp):
    v = raw - P(T) + P(T_cal) with T, T_cal clamped to [TMIN, TMAX],
    P(T) = (c1 + (c2 + c3 x) x) x * 1e-6, x = T - 35;  acc = (v - OFFS) * SCAL, gyro = v - OFFS.
Tolerances: where the target can hold the model, 2e-6 relative to the pose magnitude (float32
parameters); elsewhere the error must equal the one the export reports (1e-9 relative).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from autopilot_params import read_ardupilot, read_px4
from export_params import BREAKS, cubic_params, make_params

from station.engines.shared.correction import apply_calibration
from station.export.autopilot.ardupilot import build_ardupilot, render_ardupilot
from station.export.autopilot.px4 import build_px4, render_px4
from station.export.params.file import ParamsFile

G = 9.80665
POSES = np.repeat(np.eye(3), 2, axis=0) * np.tile([1.0, -1.0], 3)[:, None]


def px4_firmware(p: dict[str, tuple[float, int]], raw_acc, raw_gyro, temp, i: int = 0):
    v = {k: val for k, (val, _) in p.items()}

    def tc(prefix: str, enable: str) -> np.ndarray:
        if v.get(enable) != 1:
            return np.zeros((len(temp), 3))
        d = np.minimum(np.maximum(temp, v[prefix + "TMIN"]), v[prefix + "TMAX"]) - v[prefix + "TREF"]
        return np.stack([sum(v[f"{prefix}X{k}_{a}"] * d**k for k in range(4)) for a in range(3)], axis=1)

    off = np.array([v[f"CAL_ACC{i}_{a}OFF"] for a in "XYZ"])
    scale = np.array([v[f"CAL_ACC{i}_{a}SCALE"] for a in "XYZ"])
    goff = np.array([v[f"CAL_GYRO{i}_{a}OFF"] for a in "XYZ"])
    return ((raw_acc - tc(f"TC_A{i}_", "TC_A_ENABLE") - off) * scale,
            raw_gyro - tc(f"TC_G{i}_", "TC_G_ENABLE") - goff)


def ardupilot_firmware(v: dict[str, float], raw_acc, raw_gyro, temp):
    def tcal(sensor: str, caltemp: str) -> np.ndarray:
        if v["INS_TCAL1_ENABLE"] != 1:
            return np.zeros((len(temp), 3))
        lo, hi = v["INS_TCAL1_TMIN"], v["INS_TCAL1_TMAX"]
        c = [np.array([v[f"INS_TCAL1_{sensor}{k}_{a}"] for a in "XYZ"]) for k in (1, 2, 3)]

        def poly(x: np.ndarray) -> np.ndarray:
            x = np.asarray(x, float).reshape(-1, 1)
            return (c[0] + (c[1] + c[2] * x) * x) * x * 1e-6

        t_cal = np.full(len(temp), np.clip(v[caltemp], lo, hi))
        return poly(np.clip(temp, lo, hi) - 35.0) - poly(t_cal - 35.0)

    off = np.array([v[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
    scal = np.array([v[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
    goff = np.array([v[f"INS_GYROFFS_{a}"] for a in "XYZ"])
    return ((raw_acc - tcal("ACC", "INS_ACC1_CALTEMP") - off) * scal,
            raw_gyro - tcal("GYR", "INS_GYR1_CALTEMP") - goff)


# Each target: its builder and renderer, a reader of the file it writes, and its firmware's formula.
TARGETS = {
    "px4": (build_px4, render_px4, read_px4, px4_firmware),
    "ardupilot": (build_ardupilot, render_ardupilot, read_ardupilot, ardupilot_firmware),
}


def pose_inputs(params: ParamsFile, temps: np.ndarray, rate: float = 1.0):
    """Raw readings of the six poses (gravity; +-rate rad/s) at each temperature, dT = 0, from the
    forward model raw = M true + b + B(T, 0)."""
    temp = np.repeat(temps, 6)
    true_acc = np.tile(POSES * G, (len(temps), 1))
    true_gyro = np.tile(POSES * rate, (len(temps), 1))
    raw_acc = params.accel.forward(true_acc)
    raw_gyro = params.gyro.forward(true_gyro)
    if params.thermal is not None:
        th = params.thermal
        raw_acc = raw_acc + th.accel.evaluate(temp, np.zeros_like(temp), th.reference_temp)
        raw_gyro = raw_gyro + th.gyro.evaluate(temp, np.zeros_like(temp), th.reference_temp)
    return raw_acc, raw_gyro, temp


def ours(params: ParamsFile, raw_acc, raw_gyro, temp):
    return apply_calibration(raw_acc, raw_gyro, temp, np.zeros_like(temp), params.accel, params.gyro,
                             params.thermal)


TEMPS = np.array([-15.0, -5.0, 3.0, 25.0, 33.3, 47.0, 55.0, 70.0])  # inside and outside -5..55


def test_px4_holds_a_cubic_diagonal_model_exactly(tmp_path: Path) -> None:
    params = cubic_params(seed=8)
    result = build_px4(params, device_id=1310988, gyro_device_id=2359308)
    path = tmp_path / "unit.params"
    path.write_text(render_px4(result, params, "st", "2026-11-22T10:00:00Z"))
    p = read_px4(path)
    expected = {"CAL_ACC0_ID", "CAL_GYRO0_ID", "TC_A_ENABLE", "TC_G_ENABLE", "TC_A0_ID", "TC_G0_ID"}
    expected |= {f"CAL_ACC0_{a}{w}" for a in "XYZ" for w in ("OFF", "SCALE")}
    expected |= {f"CAL_GYRO0_{a}OFF" for a in "XYZ"}
    for s in "AG":
        expected |= {f"TC_{s}0_{w}" for w in ("TREF", "TMIN", "TMAX")}
        expected |= {f"TC_{s}0_X{k}_{a}" for k in range(4) for a in range(3)}
    assert set(p) == expected
    assert p["CAL_ACC0_ID"] == (1310988, 6) and p["CAL_GYRO0_ID"] == (2359308, 6)
    assert p["TC_A0_ID"][0] == 1310988 and p["TC_G0_ID"][0] == 2359308
    assert p["TC_A_ENABLE"] == (1, 6) and p["CAL_ACC0_XOFF"][1] == 9
    assert (p["TC_A0_TREF"][0], p["TC_A0_TMIN"][0], p["TC_A0_TMAX"][0]) == (25.0, -5.0, 55.0)
    raw_acc, raw_gyro, temp = pose_inputs(params, TEMPS)
    acc, gyro = px4_firmware(p, raw_acc, raw_gyro, temp)
    ref_acc, ref_gyro = ours(params, raw_acc, raw_gyro, temp)
    assert np.max(np.abs(acc - ref_acc)) < 2e-6 * G
    assert np.max(np.abs(gyro - ref_gyro)) < 2e-6
    assert np.allclose(ref_acc, np.tile(POSES * G, (len(TEMPS), 1)), atol=1e-9)
    assert max(result.pose_errors["accel"]["at_reference"]) < 2e-6 * G
    assert result.pose_errors["gyro"]["over_temperature"] < 2e-6


def test_ardupilot_holds_a_cubic_diagonal_model_exactly(tmp_path: Path) -> None:
    params = cubic_params(seed=9)
    result = build_ardupilot(params, device_id=2753036)
    path = tmp_path / "unit.param"
    path.write_text(render_ardupilot(result, params, "st", "2026-11-22T10:00:00Z"))
    v = read_ardupilot(path)
    expected = {"INS_ACC_ID", "INS_GYR_ID", "INS_TCAL1_ENABLE", "INS_TCAL1_TMIN", "INS_TCAL1_TMAX",
                "INS_ACC1_CALTEMP", "INS_GYR1_CALTEMP"}
    expected |= {f"INS_{w}_{a}" for w in ("ACCOFFS", "ACCSCAL", "GYROFFS") for a in "XYZ"}
    expected |= {f"INS_TCAL1_{s}{k}_{a}" for s in ("ACC", "GYR") for k in (1, 2, 3) for a in "XYZ"}
    assert set(v) == expected
    assert v["INS_TCAL1_ENABLE"] == 1 and (v["INS_TCAL1_TMIN"], v["INS_TCAL1_TMAX"]) == (-5.0, 55.0)
    assert v["INS_ACC1_CALTEMP"] == 25.0
    raw_acc, raw_gyro, temp = pose_inputs(params, TEMPS)
    acc, gyro = ardupilot_firmware(v, raw_acc, raw_gyro, temp)
    ref_acc, ref_gyro = ours(params, raw_acc, raw_gyro, temp)
    assert np.max(np.abs(acc - ref_acc)) < 2e-6 * G
    assert np.max(np.abs(gyro - ref_gyro)) < 2e-6
    assert result.pose_errors["accel"]["over_temperature"] < 2e-6 * G


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_misalignment_and_gyro_scale_reported_with_their_size(target: str, tmp_path: Path) -> None:
    params = make_params(seed=4, thermal=False)
    build, render, read, firmware = TARGETS[target]
    result = build(params)
    path = tmp_path / "unit.txt"
    path.write_text(render(result, params, "st", "2026-11-22T10:00:00Z"))
    raw_acc, raw_gyro, temp = pose_inputs(params, np.array([25.0]))
    acc, gyro = firmware(read(path), raw_acc, raw_gyro, temp)
    err_acc = np.linalg.norm(acc - POSES * G, axis=1)
    err_gyro = np.linalg.norm(gyro - POSES, axis=1)
    # Per-axis scale 1/K leaves exactly the misalignment: g |S e_i| at the +-i poses (to float32).
    s = params.accel.misalignment
    assert np.allclose(err_acc, np.repeat(G * np.linalg.norm(s, axis=0), 2), rtol=1e-5)
    # No gyro scale on either target: M e_i - e_i remains.
    gyro_left = np.linalg.norm(params.gyro.matrix - np.eye(3), axis=0)
    assert np.allclose(err_gyro, np.repeat(gyro_left, 2), rtol=1e-5)
    assert np.allclose(result.pose_errors["accel"]["at_reference"], err_acc, rtol=1e-9, atol=1e-12)
    assert np.allclose(result.pose_errors["gyro"]["at_reference"], err_gyro, rtol=1e-9, atol=1e-12)
    whats = {(lim.triad, lim.what): lim.size for lim in result.limitations}
    assert whats[("accel", "misalignment")] == pytest.approx(err_acc.max(), rel=1e-9)
    assert whats[("gyro", "scale and misalignment")] == pytest.approx(err_gyro.max(), rel=1e-9)
    assert err_acc.max() > 1e-3  # the fixture's misalignment is really there
    if target == "ardupilot":
        assert read(path)["INS_TCAL1_ENABLE"] == 0
    else:
        assert not any(name.startswith("TC_") for name in read(path))


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_thermal_segments_and_dtemp_terms_reported(target: str, tmp_path: Path) -> None:
    params = make_params(seed=6)
    build, render, read, firmware = TARGETS[target]
    result = build(params)
    path = tmp_path / "unit.txt"
    path.write_text(render(result, params, "st", "2026-11-22T10:00:00Z"))
    temps = np.union1d(np.linspace(-15.0, 65.0, 161), BREAKS)
    raw_acc, raw_gyro, temp = pose_inputs(params, temps)
    acc, gyro = firmware(read(path), raw_acc, raw_gyro, temp)
    worst_acc = np.linalg.norm(acc - np.tile(POSES * G, (len(temps), 1)), axis=1).max()
    worst_gyro = np.linalg.norm(gyro - np.tile(POSES, (len(temps), 1)), axis=1).max()
    # The report samples the range more finely than this grid and at both sides of every segment
    # edge: it finds our worst case (to the grid's resolution) and is not wildly above it.
    for name, worst in (("accel", worst_acc), ("gyro", worst_gyro)):
        reported = result.pose_errors[name]["over_temperature"]
        assert worst <= reported * 1.01 and reported < 1.2 * worst
    th = params.thermal
    tt, dd = np.meshgrid(np.linspace(-10, 60, 71), [th.accel.dt_min, 0.0, th.accel.dt_max])
    tt, dd = tt.ravel(), dd.ravel()
    dtemp_size = np.linalg.norm(th.accel.evaluate(tt, dd, th.reference_temp)
                                - th.accel.evaluate(tt, np.zeros_like(tt), th.reference_temp), axis=1).max()
    whats = {(lim.triad, lim.what): lim for lim in result.limitations}
    assert whats[("accel", "dT terms")].size == pytest.approx(dtemp_size, rel=0.05)
    assert whats[("accel", "thermal model as one cubic")].size > 1e-4
    assert "3 segment(s)" in whats[("gyro", "thermal model as one cubic")].detail


def test_instances_and_ids() -> None:
    params = make_params(seed=1)
    px4 = {p.name for p in build_px4(params, instance=2, device_id=7).params}
    assert {"CAL_ACC2_XOFF", "CAL_GYRO2_ZOFF", "TC_A2_X3_2", "TC_G2_TREF", "CAL_ACC2_ID", "TC_A2_ID"} <= px4
    assert not any(name.startswith(("CAL_ACC0", "CAL_GYRO0", "TC_A0", "TC_G0")) for name in px4)
    ardu = {p.name for p in build_ardupilot(params, instance=1, device_id=7, gyro_device_id=8).params}
    assert {"INS_ACC2OFFS_X", "INS_ACC2SCAL_Z", "INS_GYR2OFFS_Y", "INS_TCAL2_ACC3_Z", "INS_ACC2_CALTEMP",
            "INS_GYR2_CALTEMP", "INS_ACC2_ID", "INS_GYR2_ID"} <= ardu
    with pytest.raises(ValueError):
        build_px4(params, instance=4)
    with pytest.raises(ValueError):
        build_ardupilot(params, instance=3)


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_hostile_unit_strings_stay_in_comments(target: str, tmp_path: Path) -> None:
    device = {"serial": "x\n1\t1\tCAL_ACC0_XOFF\t100\t9\nINS_ACCOFFS_X,100", "model": "\r\n#",
              "firmware": "é\t"}
    params = make_params(seed=2, device=device)
    build, render, read, _ = TARGETS[target]
    result = build(params)
    text = render(result, params, "st\nINS_GYROFFS_X,5", "2026-11-22T10:00:00Z")
    path = tmp_path / "unit.txt"
    path.write_text(text)
    values = read(path)
    assert set(values) == {p.name for p in result.params}
    written = {name: v[0] if isinstance(v, tuple) else v for name, v in values.items()}
    assert written == result.values()
    assert text.isascii()


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_six_pose_errors_at_the_reference_temperature_with_a_grid_point_beside_it(target: str) -> None:
    # The chamber scenario's range with T_ref mid-way: a point of the report's temperature grid lies
    # 1.4e-4 degC from T_ref; the errors "at the reference" were taken there too (12, not 6).
    params = make_params(seed=3, breaks=(-20.0021, 60.0018))
    params.thermal.reference_temp = 20.0
    result = TARGETS[target][0](params)
    for name in ("accel", "gyro"):
        errors = result.pose_errors[name]
        assert len(errors["at_reference"]) == len(errors["poses"]) == 6
