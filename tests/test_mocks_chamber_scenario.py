"""The simulated unit's ``chamber`` scenario: a still unit, flat, in a chamber sweeping temperature.

Served as ``sim://?scenario=chamber`` and by ``imu-station simulate --scenario chamber``; captured
and fitted by ``imu-station capture`` and ``imu-station thermal`` as a real sweep would be.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import serial

import mocks
from mocks.chamber import parse_chamber_spec, scenario_sweep
from mocks.device import SimDevice
from mocks.protocol_sim import parse_sim_url
from mocks.truth import STANDARD_GRAVITY, ThermalTruth, UnitTruth
from station import cli
from station.acquisition.capture import read_capture
from station.engines.thermal.model import estimate_dtemp
from station.export.params.file import ParamsFile

mocks.register_sim_url()

MG = 1e3 / STANDARD_GRAVITY
DEG_H = 180.0 / np.pi * 3600.0


def test_default_programme_is_minus_20_to_60_and_back_at_1_degc_per_min() -> None:
    sweep = scenario_sweep()
    assert sweep.chamber_points() == [(0.0, -20.0), (4800.0, 60.0), (5400.0, 60.0), (10200.0, -20.0),
                                      (10800.0, -20.0)]
    assert sweep.poses == ("+z",) and sweep.self_heating_degc == 0.0
    assert parse_sim_url("sim://?scenario=chamber&speed=400").chamber == sweep
    custom = parse_sim_url("sim://?scenario=chamber&t_min=0&t_max=40&rate_c_per_min=4&soak_s=60").chamber
    assert custom is not None and custom.duration_s == 2 * 600.0 + 2 * 60.0
    assert parse_chamber_spec("t_max=40, soak_s=0") == scenario_sweep(t_max=40.0, soak_s=0.0)


@pytest.mark.parametrize(("url", "message"), [
    ("sim://?scenario=chamber&t_min=70", "t_min 70 must be below t_max 60"),
    ("sim://?scenario=chamber&rate_c_per_min=0", "rate_c_per_min 0 must be positive"),
    ("sim://?scenario=chamber&soak_s=-1", "soak_s -1 must not be negative"),
    ("sim://?scenario=chamber&t_max=hot", "t_max='hot': not a number"),
    ("sim://?scenario=chamber&t_max=nan", "t_max='nan': not a finite number"),
    ("sim://?t_min=0&rate_c_per_min=2", "t_min, rate_c_per_min apply to scenario=chamber only"),
])
def test_bad_programme_options_are_refused_by_name(url: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_sim_url(url)
    with pytest.raises(serial.SerialException, match=message):
        serial.serial_for_url(url)


def test_samples_carry_the_truths_thermal_bias_at_the_programmes_temperature() -> None:
    """An ideal unit with a thermal truth: every sample is gravity plus b_T(T, dT) of the programme."""
    c = np.zeros((3, 7))
    c[:, 1] = [1e-5, -2e-5, 3e-5]   # t^2
    c[:, 2] = [1e-3, -2e-3, 3e-3]   # t
    c[:, 4] = [0.1, 0.0, -0.2]      # dT
    unit = UnitTruth.ideal()
    unit = replace(unit, accel=replace(unit.accel, thermal=ThermalTruth(c, 25.0)),
                   gyro=replace(unit.gyro, thermal=ThermalTruth(-c / 100.0, 25.0)))
    sweep = scenario_sweep(t_min=0.0, t_max=40.0, rate_c_per_min=4.0, soak_s=60.0)
    device = SimDevice(unit, rate_hz=10, scenario="chamber", chamber=sweep, temp_noise_degc=0.0)
    s = device.produce(sweep.duration_s + 100.0)
    t = s["t_us"] / 1e6
    profile = sweep.profile()
    temp, dtemp = profile(t), profile.rate(t)
    assert len(s) == (sweep.duration_s + 100.0) * 10 + 1
    np.testing.assert_allclose(s["temp"], temp, atol=1e-4)
    assert s["temp"].min() == pytest.approx(0.0, abs=1e-4)
    assert s["temp"].max() == pytest.approx(40.0, abs=1e-4)
    assert np.all(s["temp"][t > sweep.duration_s] == pytest.approx(0.0, abs=1e-4))  # held at t_min after
    gravity = np.array([0.0, 0.0, STANDARD_GRAVITY])
    np.testing.assert_allclose(s["acc"], gravity + ThermalTruth(c, 25.0).bias(temp, dtemp), rtol=1e-6,
                               atol=1e-6)
    np.testing.assert_allclose(s["gyro"], ThermalTruth(-c / 100.0, 25.0).bias(temp, dtemp), rtol=1e-6,
                               atol=1e-8)
    with pytest.raises(ValueError, match="needs the chamber scenario"):
        SimDevice(unit, scenario="still", chamber=sweep)


def _ten_second_errors(fitted: np.ndarray, truth: np.ndarray,
                       rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """RMS and worst of the 10 s means of fitted - truth, per axis, the constant removed (the fit
    measures absolute biases, whose constant also holds the unit's static bias and scale error)."""
    err = fitted - truth
    err -= err.mean(axis=0)
    n = int(round(10 * rate_hz))
    means = err[: len(err) // n * n].reshape(-1, n, 3).mean(axis=1)
    return np.sqrt(np.mean(means**2, axis=0)), np.abs(means).max(axis=0)


def test_capture_then_thermal_recovers_the_truths_bias_curve(tmp_path: Path, capsys) -> None:
    """The documented run on a short programme (0 -> 40 -> 0 degC at 4 degC/min, 22 min): the fitted
    curve follows the truth's thermal bias within 1.5 % of its variation (RMS of 10 s means) and
    3 % (worst 10 s mean) per axis; in absolute terms within 0.1 mg and 10 deg/h RMS, the unit's
    white noise and bias instability over 10 s."""
    seed, options = 2, {"t_min": "0", "t_max": "40", "rate_c_per_min": "4", "soak_s": "60"}
    url = f"sim://?scenario=chamber&seed={seed}&speed=400&rate=100&" + "&".join(f"{k}={v}" for k, v in
                                                                            options.items())
    sweep_h5, params = tmp_path / "sweep.h5", tmp_path / "unit.yaml"
    sweep = scenario_sweep(0.0, 40.0, 4.0, 60.0)
    plot = tmp_path / "thermal.png"
    duration = f"{sweep.duration_s:g}"
    assert cli.main(["capture", "--port", url, "--duration", duration, "-o", str(sweep_h5)]) == 0
    assert cli.main(["thermal", str(sweep_h5), "-o", str(params), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "0.0 .. 40.0 degC" in out and "poses +z" in out
    assert plot.stat().st_size > 10_000

    cap = read_capture(sweep_h5)
    profile = sweep.profile()
    assert cap.temp is not None and cap.t[-1] >= sweep.duration_s - 0.02
    assert np.std(cap.temp - profile(cap.t)) < 0.02  # the sensor's 0.01 degC noise
    model = ParamsFile.load(params).thermal
    assert model is not None
    truth = UnitTruth.random(seed)
    dtemp = estimate_dtemp(cap.t, cap.temp, model.dtemp_filter)
    true_temp, true_dtemp = profile(cap.t), profile.rate(cap.t)
    for triad, sensor, unit, floor in (("accel", truth.accel, MG, 0.1), ("gyro", truth.gyro, DEG_H, 10.0)):
        expected = sensor.thermal.bias(true_temp, true_dtemp)
        fitted = getattr(model, triad).evaluate(cap.temp, dtemp, model.reference_temp)
        rms, worst = _ten_second_errors(fitted, expected, cap.rate_hz)
        variation = np.ptp(expected, axis=0)
        assert np.all(rms < 0.015 * variation), (triad, rms / variation)
        assert np.all(worst < 0.03 * variation), (triad, worst / variation)
        assert np.all(rms * unit < floor), (triad, rms * unit)


def test_simulate_serves_the_chamber_and_refuses_a_bad_programme(capsys) -> None:
    args = ["simulate", "--scenario", "chamber", "--chamber", "t_min=-10,t_max=50", "--duration", "0.5",
            "--speed", "100"]
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    assert "scenario chamber" in out
    assert "chamber: -10 -> 50 -> -10 degC at 1 degC/min, soaks of 600 s, 8400 s of device clock" in out
    assert cli.main(["simulate", "--scenario", "chamber", "--chamber", "t_min=90"]) == 4
    assert "--chamber 't_min=90': t_min 90 must be below t_max 60" in capsys.readouterr().err
    assert cli.main(["simulate", "--chamber", "t_min=0"]) == 4
    assert "--chamber applies to --scenario chamber only" in capsys.readouterr().err
