"""``imu-station demo`` end to end, as a user runs it: the whole main job on the simulated unit.

The simulated unit is served on a real pty (device clock x20), read by the serial driver, walked
through the twelve-position + rotation sequence by the runner and a simulated operator, recorded,
calibrated, written as a parameter file and exported for firmware (compiled with gcc when it is
there). The test reads the files back and checks the recovered intrinsics against the
simulator's truth model, UnitTruth.random(seed), built here independently of the demo.

Tolerances (seed 1, poses of 10 s at 200 Hz, turns at 90 deg/s; observed errors are 2-5 times
smaller): scale 1e-4 (accel) and 3e-4 (gyro); misalignment 1.5e-4 rad (accel) and 3e-4 rad
(gyro); bias 1.5e-3 m/s^2 (150 ug) and 2e-4 rad/s (41 deg/h). Every error must also be within
5 of the 1-sigma the calibration wrote into the parameter file.
"""

from __future__ import annotations

import contextlib
import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocks.truth import UnitTruth
from station.acquisition.capture import read_capture
from station.acquisition.sequences import builtin
from station.cli import main
from station.export.firmware.blob import parse_blob
from station.export.params.file import ParamsFile

pytestmark = pytest.mark.timeout(120)

TOLERANCE = {
    ("accel", "scale"): 1e-4, ("accel", "misalignment"): 1.5e-4, ("accel", "bias"): 1.5e-3,
    ("gyro", "scale"): 3e-4, ("gyro", "misalignment"): 3e-4, ("gyro", "bias"): 2e-4,
}


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("demo") / "out"
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["demo", "--out", str(out)])
    assert code == 0, stderr.getvalue()
    return out, stdout.getvalue()


def test_demo_prints_every_step_and_the_comparison(demo_run) -> None:
    _, text = demo_run
    titles = re.findall(r"^\[(\d)/9\] (.*)$", text, flags=re.M)
    assert [int(n) for n, _ in titles] == list(range(1, 10))
    assert "all 1000 samples equal, bit for bit" in text
    assert "all 18 steps accepted" in text
    for row in ("scale x", "S yx", "S xz", "bias z"):
        assert len(re.findall(rf"^\s+(?:accel|gyro|)\s+{row}\s", text, flags=re.M)) == 2, row
    assert re.search(r"\d+ of 24 errors within 3 sigma", text)
    # The sequence ran on the device clock far faster than the wall clock (x20 asked).
    device_s, wall_s = (float(x) for x in re.search(
        r"([0-9.]+) s of device clock in ([0-9.]+) s of wall clock", text).groups())
    assert device_s > 150 and device_s / wall_s > 5


def test_parameter_file_read_back_recovers_the_true_unit(demo_run) -> None:
    out, _ = demo_run
    raw = yaml.safe_load((out / "params.yaml").read_text())
    assert raw["schema"] == "imu-station/params/1"
    assert raw["device"] == {"serial": "SIM-000001", "model": "imu-sim-mems", "firmware": "1.0.0"}
    params = ParamsFile.load(out / "params.yaml")
    truth = UnitTruth.random(1)
    for triad in ("accel", "gyro"):
        cal, tr, sd = getattr(params, triad), getattr(truth, triad), raw[triad]["stddev"]
        np.testing.assert_allclose(cal.matrix, np.asarray(raw[triad]["matrix"]), rtol=0, atol=0)
        off = ~np.eye(3, dtype=bool)
        for name, got, true, sigma in (
                ("scale", cal.scale, tr.scale, np.asarray(sd["scale"])),
                ("misalignment", cal.misalignment[off], tr.misalignment[off],
                 np.asarray(sd["misalignment"])[off]),
                ("bias", cal.bias, tr.bias, np.asarray(sd["bias"]))):
            error = np.abs(got - true)
            assert error.max() < TOLERANCE[triad, name], (triad, name, error)
            assert np.all(error < 5 * sigma), (triad, name, error / sigma)


def test_sequence_capture_is_labelled_at_the_units_rate(demo_run) -> None:
    out, _ = demo_run
    capture = read_capture(out / "sequence.h5")
    expected = builtin("twelve-position").labels
    assert [label for label, _ in capture.segments()] == expected
    assert capture.device["serial"] == "SIM-000001" and capture.device["rate_hz"] == 200
    assert np.all(np.round(np.diff(capture.t) * 1e6) == 5000)  # no sample lost, 200 Hz on the device clock
    assert capture.link["lost"] == 0 and capture.link["errors"] == 0
    for label, sl in capture.segments():
        if not label.startswith("rot"):
            assert capture.t[sl][-1] - capture.t[sl][0] >= 10.0 - 0.01, label


def test_firmware_export_holds_the_parameters(demo_run) -> None:
    out, text = demo_run
    params = ParamsFile.load(out / "params.yaml")
    blob = parse_blob((out / "firmware" / "imu_calib.bin").read_bytes())
    assert blob.serial == "SIM-000001" and blob.station_id == "demo-station"
    # The blob holds the correction (the inverse) in float32: an entry near zero carries the
    # absolute error of the inversion (~1e-13 here), not a relative one.
    np.testing.assert_allclose(blob.accel.matrix, params.accel.matrix, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(blob.gyro.bias, params.gyro.bias, rtol=1e-6)
    assert '"SIM-000001"' in (out / "firmware" / "imu_calib.h").read_text()
    if shutil.which("gcc") is None:
        assert "gcc not found" in text
        return
    assert "imu_calib_load: 0 ok" in text
    acc = [float(x) for x in re.search(r"acc\s+\(([^)]*)\) m/s\^2", text).group(1).split(",")]
    # Corrected with the recovered parameters: true gravity within the calibration's error.
    np.testing.assert_allclose(acc, [0.0, 0.0, 9.80665], atol=2e-3)


def test_demo_refuses_bad_options(capsys) -> None:
    with pytest.raises(SystemExit) as usage:  # --speed is checked where it is parsed, as in simulate and tui
        main(["demo", "--speed", "0"])
    assert usage.value.code == 4
    assert "argument --speed: 0 is outside the allowed range, above 0 up to 100" in capsys.readouterr().err
    assert main(["demo", "--hold", "-1"]) == 4
    assert "--hold -1" in capsys.readouterr().err
    assert main(["demo", "--rate", "0"]) == 4
    assert "--rate 0" in capsys.readouterr().err
