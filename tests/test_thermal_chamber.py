"""The chamber-sweep scenario of the simulated unit (mocks/chamber.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocks.chamber import ChamberSweep, UnitTemperature, chamber_sweep, cubic_rate_unit
from mocks.rig import ramp
from mocks.truth import ThermalTruth, UnitTruth

G = 9.80665


def test_programme_corners_follow_speed_and_soaks() -> None:
    sweep = ChamberSweep(low_degc=0.0, high_degc=40.0, start_degc=20.0, ramp_degc_per_min=2.0, soak_s=60.0)
    assert sweep.chamber_points() == [(0.0, 20.0), (600.0, 40.0), (660.0, 40.0), (1860.0, 0.0), (1920.0, 0.0),
                                      (2520.0, 20.0)]
    two = replace(sweep, cycles=2, ramp_degc_per_min=[2.0, 4.0])
    points = two.chamber_points()
    assert points[:6] == sweep.chamber_points()
    assert points[6] == (2520.0 + 300.0, 40.0)  # the second cycle at twice the speed
    assert two.duration_s == pytest.approx(2520.0 + 300.0 + 60.0 + 600.0 + 60.0 + 300.0)
    with pytest.raises(ValueError, match="one per cycle"):
        replace(sweep, cycles=3, ramp_degc_per_min=[1.0, 2.0])
    with pytest.raises(ValueError, match="within"):
        ChamberSweep(low_degc=0.0, high_degc=10.0, start_degc=20.0)


def test_self_heating_rate_is_the_derivative_of_the_temperature() -> None:
    profile = UnitTemperature(ramp([(0.0, 20.0), (100.0, 30.0), (300.0, 30.0)]), rise_degc=6.0, tau_s=50.0)
    t = np.array([10.0, 55.5, 150.0, 290.0, 400.0])
    h = 1e-4
    numeric = (profile(t + h) - profile(t - h)) / (2 * h)
    np.testing.assert_allclose(profile.rate(t), numeric, rtol=1e-6, atol=1e-9)
    assert profile(np.array([0.0]))[0] == 20.0
    assert profile(np.array([1e4]))[0] == pytest.approx(36.0)


def test_raw_is_the_model_of_eq_2_for_an_ideal_unit() -> None:
    c = np.zeros((3, 7))
    c[:, 2] = [1e-3, -2e-3, 3e-3]
    c[:, 4] = [0.1, 0.0, -0.2]
    truth = UnitTruth.ideal()
    truth = replace(truth, accel=replace(truth.accel, thermal=ThermalTruth(c, 25.0)),
                    gyro=replace(truth.gyro, thermal=ThermalTruth(-c, 25.0)))
    sweep = ChamberSweep(low_degc=10.0, high_degc=40.0, start_degc=25.0, ramp_degc_per_min=6.0, soak_s=60.0,
                         self_heating_degc=3.0, self_heating_tau_s=120.0)
    scale = [100e-6, 0.0, -50e-6]
    hyst = [0.0, 0.0, 0.01]

    def extra(temp: np.ndarray, dtemp: np.ndarray) -> np.ndarray:
        return np.column_stack([np.sin(temp / 10.0), dtemp, np.zeros_like(temp)]) * 1e-3

    run = chamber_sweep(truth, sweep, rate_hz=2.0, seed=0, accel_bias=extra, accel_scale_per_degc=scale,
                        accel_hysteresis=hyst, temp_noise_degc=0.0)
    r = run.recording
    np.testing.assert_allclose(r.temp_true, sweep.profile()(r.t))
    np.testing.assert_allclose(r.dtemp_true, sweep.profile().rate(r.t))
    assert set(r.step) == {"+z"}
    memory = np.sign(r.dtemp_true)  # self-heating keeps dT non-zero: memory is the sign of dT
    expected = (ThermalTruth(c, 25.0).bias(r.temp_true, r.dtemp_true) + extra(r.temp_true, r.dtemp_true)
                + memory[:, None] * np.array(hyst))
    np.testing.assert_allclose(run.thermal_accel, expected, atol=1e-15)
    force = np.array([0.0, 0.0, G])
    drift = (r.temp_true - 25.0)[:, None] * np.array(scale) * force
    np.testing.assert_allclose(run.scale_accel, drift, atol=1e-15)
    np.testing.assert_allclose(r.acc, force + expected + drift, atol=1e-12)
    np.testing.assert_allclose(r.gyro, -ThermalTruth(c, 25.0).bias(r.temp_true, r.dtemp_true), atol=1e-15)
    np.testing.assert_allclose(r.temp, r.temp_true)


def test_hysteresis_remembers_the_last_ramp_through_soaks() -> None:
    sweep = ChamberSweep(low_degc=0.0, high_degc=30.0, start_degc=10.0, ramp_degc_per_min=10.0, soak_s=100.0)
    run = chamber_sweep(UnitTruth.ideal(), sweep, rate_hz=1.0, seed=0, gyro_hysteresis=[1.0, 0.0, 0.0],
                        temp_noise_degc=0.0)
    r = run.recording
    memory = run.thermal_gyro[:, 0]
    soak_high = (r.temp_true == 30.0) & (r.dtemp_true == 0.0)
    soak_low = (r.temp_true == 0.0) & (r.dtemp_true == 0.0)
    assert soak_high.sum() > 90 and soak_low.sum() > 90
    assert np.all(memory[soak_high] == 1.0) and np.all(memory[soak_low] == -1.0)
    assert memory[0] == 1.0  # the programme heats from its first sample


def test_poses_quantization_sensor_resolution_and_determinism() -> None:
    truth = cubic_rate_unit(2)
    sweep = ChamberSweep(low_degc=15.0, high_degc=35.0, start_degc=25.0, ramp_degc_per_min=5.0, soak_s=30.0,
                         poses=("+x", "-y", "+z"), pose_hold_s=20.0, move_s=2.0)
    run = chamber_sweep(truth, sweep, rate_hz=20.0, seed=3, temp_resolution_degc=1 / 16)
    r = run.recording
    labels = set(r.step)
    assert labels == {"+x", "-y", "+z", ""}
    hold = r.step == "-y"
    np.testing.assert_allclose(r.true_specific_force[hold], [[0.0, -G, 0.0]] * hold.sum(), atol=1e-9)
    res_a, res_g = truth.accel.resolution, truth.gyro.resolution
    assert np.allclose(r.acc / res_a, np.round(r.acc / res_a), atol=1e-6)
    assert np.allclose(r.gyro / res_g, np.round(r.gyro / res_g), atol=1e-6)
    assert np.allclose(r.temp * 16, np.round(r.temp * 16))
    assert r.t[-1] >= sweep.duration_s - 1.0
    again = chamber_sweep(truth, sweep, rate_hz=20.0, seed=3, temp_resolution_degc=1 / 16)
    np.testing.assert_array_equal(again.recording.acc, r.acc)
    np.testing.assert_array_equal(again.recording.temp, r.temp)
    other = chamber_sweep(truth, sweep, rate_hz=20.0, seed=4, temp_resolution_degc=1 / 16)
    assert not np.array_equal(other.recording.acc, r.acc)
    capture = run.to_capture()
    assert capture.temp is not None and len(capture) == len(r.t)
