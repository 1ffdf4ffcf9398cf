"""The engines' input objects and settings: arrays checked once, with messages that say what is wrong
and where; settings validated on construction; the stage interface gives what the engines gave."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mocks.rig import sequence_segments, simulate
from mocks.truth import UnitTruth
from protocols.units import STANDARD_GRAVITY
from station.engines.calibration.free import FreeCapture, FreeSettings
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.engines.thermal.fit import ThermalSettings, ThermalSweep
from station.errors import EngineInputError

N = 300


@pytest.fixture()
def arrays() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return np.arange(N) / 100.0, rng.normal(0, 0.01, (N, 3)) + [0, 0, 9.8], rng.normal(0, 0.01, (N, 3))


@pytest.mark.parametrize("make", [
    lambda t, a, g: FreeCapture(t, a, g),
    lambda t, a, g: TurntableCapture(t, a, g, np.full(len(t), "+z", dtype=object)),
    lambda t, a, g: ThermalSweep(t, np.full(len(t), 25.0), a, g),
], ids=["free", "turntable", "thermal"])
def test_every_input_object_refuses_bad_arrays_naming_them(arrays, make) -> None:
    t, acc, gyro = arrays
    with pytest.raises(EngineInputError, match=r"^acc has shape \(300, 2\); the engines take \(300, 3\)"):
        make(t, acc[:, :2], gyro)
    with pytest.raises(EngineInputError, match=r"^gyro has shape \(299, 3\)"):
        make(t, acc, gyro[:-1])
    with pytest.raises(EngineInputError, match=r"^the time column has shape \(300, 1\)"):
        make(t[:, None], acc, gyro)
    bad = acc.copy()
    bad[[17, 40], 1] = [np.nan, np.inf]
    expected = r"^acc is NaN or infinite in 2 of 300 samples \(the first is sample 17\)"
    with pytest.raises(EngineInputError, match=expected):
        make(t, bad, gyro)
    late = t.copy()
    late[5] = np.nan
    expected = r"^t is NaN or infinite in 1 of 300 samples \(the first is sample 5\)"
    with pytest.raises(EngineInputError, match=expected):
        make(late, acc, gyro)


def test_the_input_objects_hold_float_arrays_and_cannot_be_changed(arrays) -> None:
    t, acc, gyro = arrays
    data = FreeCapture(t.tolist(), acc.astype(np.float32), gyro)
    assert data.t.dtype == data.acc.dtype == np.float64 and data.acc.shape == (N, 3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        data.acc = acc  # type: ignore[misc]


def test_turntable_capture_checks_labels_and_rate(arrays) -> None:
    t, acc, gyro = arrays
    with pytest.raises(EngineInputError, match="the step column has 299 labels for 300 samples"):
        TurntableCapture(t, acc, gyro, np.full(N - 1, "+z", dtype=object))
    with pytest.raises(EngineInputError, match="no step labels"):
        TurntableCapture(t, acc, gyro, None)
    with pytest.raises(EngineInputError, match="stated sample rate 50 Hz disagrees"):
        TurntableCapture(t, acc, gyro, np.full(N, "+z", dtype=object), rate_hz=50.0)
    step = np.array(["+z"] * 100 + [""] * 20 + ["rot+z"] * 100 + ["wobble"] * 80, dtype=object)
    data = TurntableCapture(t, acc, gyro, step, rate_hz=100.0)
    assert [label for label, _ in data.statics] == ["+z"]
    assert [label for label, _ in data.rotations] == ["rot+z"]
    assert data.ignored == ["wobble"]


def test_free_capture_checks_the_stated_rate_and_length(arrays) -> None:
    t, acc, gyro = arrays
    with pytest.raises(EngineInputError, match="stated sample rate 200 Hz disagrees"):
        FreeCapture(t, acc, gyro, rate_hz=200.0)
    with pytest.raises(EngineInputError, match="only 99 samples"):
        FreeCapture(t[:99], acc[:99], gyro[:99])


def test_settings_are_validated_on_construction() -> None:
    with pytest.raises(ValueError, match="convention must be 'lower' or 'upper'"):
        FreeSettings(convention="diagonal")
    with pytest.raises(ValueError, match="gyro_bias must be 'still' or 'intervals'"):
        FreeSettings(gyro_bias="median")
    with pytest.raises(EngineInputError, match="unknown terms"):
        ThermalSettings(terms=["t4"])
    with pytest.raises(EngineInputError, match="must be positive"):
        ThermalSettings(tau_s=0.0)
    with pytest.raises(EngineInputError, match="at least one segment"):
        ThermalSettings(segments=0)
    assert ThermalSettings(segments=[30.0, 10.0]).segments == (30.0, 10.0)
    imu_tk = FreeSettings.imu_tk(gravity=9.81744, convention="upper")
    assert (imu_tk.window_samples, imu_tk.gyro_bias) == (101, "still")
    assert (imu_tk.gravity, imu_tk.convention) == (9.81744, "upper")
    for settings in (TurntableSettings(), FreeSettings(), ThermalSettings()):
        assert settings.gravity == STANDARD_GRAVITY


def test_the_stages_compose_to_the_report() -> None:
    """calibrate_turntable is its stages in turn: the accelerometer stage's M and b are the report's."""
    from station.engines.calibration.turntable import accel_calibration, fit_accelerometer

    truth = UnitTruth.random(5)
    rec = simulate(truth, sequence_segments("six-position", True, hold_s=8.0), rate_hz=100.0, seed=5)
    data = TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step, rate_hz=100.0)
    settings = TurntableSettings(gravity=truth.gravity)
    report = calibrate_turntable(data, settings)
    stage = fit_accelerometer(data, settings.gravity)
    accel, poses = accel_calibration(stage, data, settings.gravity)
    np.testing.assert_array_equal(report.accel.matrix, accel.matrix)
    np.testing.assert_array_equal(report.accel.bias, accel.bias)
    assert stage.six and poses == report.poses[:6]
    np.testing.assert_allclose(report.accel.matrix, truth.accel.matrix, atol=2e-3)
