"""PX4 and ArduPilot hold a bias over temperature and nothing else: a parameter file with thermal
scale-factor and misalignment polynomials (``thermal.scale``, ``thermal.misalignment``) is exported
with what is lost stated in ppm of K at T_ref and in microradians at the clamp's ends, per triad and
axis, in the export's result (``thermal_intrinsics_lost``, the limitations) and in what
``imu-station export -f px4|ardupilot`` prints.

References: the closed form of the polynomials written here by hand (k(t) = c1 t + c2 t^2 at
t = T_end - T_ref, over K), exact to rounding (1e-9 relative); and the pose errors of the target's
own formula, which for a file the target otherwise holds exactly (``cubic_params``) are the scale
change itself: |g k_i / K_i| for the accelerometer, |k_i| x 1 rad/s for the gyro, within 1e-6 m/s^2
or rad/s (the target's parameters are float32: g x 2^-24 is 6e-7 m/s^2).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from export_params import cubic_params

from protocols.units import STANDARD_GRAVITY
from station.cli import main
from station.engines.thermal.intrinsics import TempPolynomial
from station.export.autopilot import GYRO_POSE_RATE, build_ardupilot, build_px4, thermal_intrinsics_loss
from station.export.params.file import ParamsFile

CLAMP = (-5.0, 55.0)  # cubic_params' thermal range; T_ref 25 degC, so t = -30 and +30 at the ends
GYRO_SCALE = np.array([[2e-4, 1e-6], [-1e-4, 0.0], [5e-5, -2e-6]])  # powers 1, 2; gyro K = 1
ACCEL_SCALE = np.array([[1e-4], [-5e-5], [3e-5]])  # power 1
GYRO_MISALIGNMENT = np.array([[2e-6], [-1e-6], [0.0], [3e-6], [5e-7], [-4e-6]])  # rad per degC

BUILD = {"px4": build_px4, "ardupilot": build_ardupilot}


def with_polynomials(misalignment: bool = True) -> ParamsFile:
    params = cubic_params(seed=4)
    params.thermal.scale["gyro"] = TempPolynomial(*CLAMP, (1, 2), GYRO_SCALE)
    params.thermal.scale["accel"] = TempPolynomial(*CLAMP, (1,), ACCEL_SCALE)
    if misalignment:
        params.thermal.misalignment["gyro"] = TempPolynomial(*CLAMP, (1,), GYRO_MISALIGNMENT)
    return params


def test_loss_is_the_closed_form() -> None:
    params = with_polynomials()
    lost = thermal_intrinsics_loss(params)
    assert set(lost) == {"accel", "gyro"} and "misalignment" not in lost["accel"]
    gyro = lost["gyro"]["scale"]
    assert gyro["unit"] == "ppm" and gyro["temps"] == list(CLAMP) and gyro["components"] == ["x", "y", "z"]
    # Gyro K = 1: k(+-30) = +-30 c1 + 900 c2, in ppm. Written out: x -5100 / +6900, y +3000 / -3000,
    # z -3300 / -300.
    expected = np.array([[-5100.0, 6900.0], [3000.0, -3000.0], [-3300.0, -300.0]])
    assert np.allclose(gyro["change"], expected, rtol=1e-9)
    assert gyro["largest"] == pytest.approx(6900.0, rel=1e-9)
    accel = lost["accel"]["scale"]
    k0 = params.accel.scale
    assert np.allclose(accel["change"], ACCEL_SCALE * np.array([-30.0, 30.0]) / k0[:, None] * 1e6, rtol=1e-9)
    mis = lost["gyro"]["misalignment"]
    assert mis["unit"] == "urad" and mis["components"] == ["xy", "xz", "yx", "yz", "zx", "zy"]
    assert np.allclose(mis["change"], GYRO_MISALIGNMENT * np.array([-30.0, 30.0]) * 1e6, rtol=1e-9)
    assert mis["largest"] == pytest.approx(120.0, rel=1e-9)  # 4e-6 rad/degC x 30 degC
    assert thermal_intrinsics_loss(cubic_params(seed=4)) == {}


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_pose_errors_carry_the_scale_change(target: str) -> None:
    """What the target leaves at the six poses over temperature is exactly the dropped scale change."""
    params = with_polynomials(misalignment=False)
    result = BUILD[target](params)
    lost = result.thermal_intrinsics_lost
    accel_worst = STANDARD_GRAVITY * lost["accel"]["scale"]["largest"] * 1e-6
    gyro_worst = GYRO_POSE_RATE * lost["gyro"]["scale"]["largest"] * 1e-6
    assert result.pose_errors["accel"]["over_temperature"] == pytest.approx(accel_worst, abs=1e-6)
    assert result.pose_errors["gyro"]["over_temperature"] == pytest.approx(gyro_worst, abs=1e-6)
    assert accel_worst > 0.02 and gyro_worst > 5e-3  # far above the tolerance
    # At T_ref nothing of it is lost: the target holds the file there.
    assert max(result.pose_errors["accel"]["at_reference"]) < 1e-6
    whats = {(lim.triad, lim.what): lim for lim in result.limitations}
    lim = whats[("gyro", "scale factor over temperature")]
    assert (lim.unit, lim.size) == ("ppm", pytest.approx(6900.0, rel=1e-9))
    assert "x -5100/+6900" in lim.detail and "-5/55 degC" in lim.detail


@pytest.mark.parametrize(("target", "holds"), [("px4", "TC_*"), ("ardupilot", "INS_TCAL*")])
def test_export_command_prints_and_reports_the_loss(target: str, holds: str, tmp_path: Path, capsys) -> None:
    unit = tmp_path / "unit.yaml"
    with_polynomials().save(unit)
    out = tmp_path / f"unit.{target}"
    assert main(["export", str(unit), "-f", target, "-o", str(out), "--station-id", "s"]) == 0
    text = capsys.readouterr().out
    lost_lines = [line for line in text.splitlines() if "over temperature" in line and "bias only" in line]
    assert len(lost_lines) == 3, text  # accel scale, gyro scale, gyro misalignment
    gyro_scale = next(line for line in text.splitlines() if "gyro  scale factor over temperature" in line)
    assert "6.9e+03 ppm" in gyro_scale and holds in gyro_scale and "x -5100/+6900" in gyro_scale
    gyro_mis = next(line for line in text.splitlines() if "gyro  misalignment over temperature" in line)
    assert "120 urad" in gyro_mis and "zy +120/-120" in gyro_mis
    assert main(["export", str(unit), "-f", target, "-o", str(out), "--station-id", "s", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    lost = report["thermal_intrinsics_lost"]
    assert lost["gyro"]["scale"]["change"][0] == pytest.approx([-5100.0, 6900.0], rel=1e-9)
    assert lost["gyro"]["misalignment"]["largest"] == pytest.approx(120.0, rel=1e-9)
    assert {(lim["triad"], lim["what"]) for lim in report["limitations"]} >= {
        ("accel", "scale factor over temperature"), ("gyro", "scale factor over temperature"),
        ("gyro", "misalignment over temperature")}
