"""``imu-station apply``: every section of a parameter file applied to every sample, checked against
the simulated unit's true specific force and rate, and against the model written out by hand."""

from __future__ import annotations

import numpy as np
import pytest
from export_params import make_params
from scipy.spatial.transform import Rotation as Rot

from mocks.rig import Move, Rotation, Static, ramp, simulate
from mocks.truth import SensorTruth, ThermalTruth, UnitTruth
from protocols.units import STANDARD_GRAVITY
from station import cli
from station.acquisition.capture import Capture
from station.acquisition.capture_csv import read_csv, write_csv
from station.commands.apply import apply_params
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import (
    TERMS,
    DtempFilter,
    ThermalBias,
    ThermalModel,
    ThermalSegment,
    estimate_dtemp,
)
from station.export.params.file import ParamsFile


def _truth() -> UnitTruth:
    rng = np.random.default_rng(21)

    def triad(scale: float, bias: float, thermal: float) -> SensorTruth:
        mis = rng.normal(0, 0.004, (3, 3))
        np.fill_diagonal(mis, 0.0)
        coeffs = np.zeros((3, 7))
        coeffs[:, 2] = rng.normal(0, thermal, 3)          # t
        coeffs[:, 1] = rng.normal(0, thermal * 1e-2, 3)   # t^2
        coeffs[:, 4] = rng.normal(0, thermal * 5, 3)      # dT
        return SensorTruth(scale=1 + rng.normal(0, scale, 3), misalignment=mis, bias=rng.normal(0, bias, 3),
                           thermal=ThermalTruth(coeffs=coeffs, t_ref=25.0))

    return UnitTruth(accel=triad(0.01, 0.1, 3e-3), gyro=triad(0.01, 0.01, 2e-4))


@pytest.fixture(scope="module")
def recording():
    truth = _truth()
    segments = [Static("+z", 5.0), Move(2.0), Static("-x", 5.0), Rotation("+y", 180.0), Static("+x+y", 5.0)]
    rec = simulate(truth, segments, rate_hz=100.0, seed=3, temperature=ramp([(0, 20.0), (30, 32.0)]),
                   temp_noise_degc=0.0)
    return truth, rec


def _params(truth: UnitTruth) -> ParamsFile:
    def thermal(triad: SensorTruth) -> ThermalBias:
        assert list(TERMS) == ["t3", "t2", "t", "dt2", "dt", "tdt", "1"]  # same order as the truth's terms
        return ThermalBias([ThermalSegment(-40.0, 85.0, triad.thermal.coeffs)], dt_min=-5.0, dt_max=5.0)

    return ParamsFile(
        device={"serial": truth.serial},
        accel=SensorCalibration(truth.accel.matrix, truth.accel.bias, method="truth"),
        gyro=SensorCalibration(truth.gyro.matrix, truth.gyro.bias, method="truth"),
        thermal=ThermalModel(25.0, DtempFilter("ema", 2.0), thermal(truth.accel), thermal(truth.gyro)),
    )


def test_apply_with_the_true_parameters_gives_the_true_motion(recording, tmp_path, capsys) -> None:
    truth, rec = recording
    params_path = tmp_path / "unit.yaml"
    _params(truth).save(params_path)
    raw = tmp_path / "raw.csv"
    write_csv(raw, rec.to_capture(true_dtemp=True))
    out = tmp_path / "corrected.csv"
    assert cli.main(["apply", str(params_path), str(raw), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "thermal: applied with the input's dtemp column" in text
    corrected = read_csv(out)
    assert list(corrected.step) == [str(s) for s in rec.step]
    # float32 on the wire: 1e-6 relative; otherwise exact
    np.testing.assert_allclose(corrected.acc, rec.true_specific_force, atol=5e-5)
    np.testing.assert_allclose(corrected.gyro, rec.true_rate, atol=5e-6)
    # without the thermal section the temperature ramp leaves a visible error
    plain = ParamsFile.load(params_path)
    plain.thermal = None
    uncompensated, how = apply_params(plain, rec.to_capture(true_dtemp=True))
    assert how["thermal"] == "absent"
    assert np.abs(uncompensated.acc - rec.true_specific_force).max() > 1e-2


def test_apply_estimates_dtemp_with_the_files_filter(recording, tmp_path, capsys) -> None:
    truth, rec = recording
    params = _params(truth)
    params_path = tmp_path / "unit.yaml"
    params.save(params_path)
    raw = tmp_path / "raw.csv"
    capture = rec.to_capture(true_dtemp=False)
    write_csv(raw, capture)
    out = tmp_path / "corrected.csv"
    assert cli.main(["apply", str(params_path), str(raw), "-o", str(out)]) == 0
    assert "dT estimated by the file's filter (ema, tau 2 s)" in capsys.readouterr().out
    corrected = read_csv(out)
    # the model by hand: M^-1 (raw - b - B(T, dT)), dT from the stored filter
    written = read_csv(raw)
    dtemp = estimate_dtemp(written.t, written.temp, DtempFilter("ema", 2.0))
    for raw_values, cal, triad, got in ((written.acc, params.accel, params.thermal.accel, corrected.acc),
                                        (written.gyro, params.gyro, params.thermal.gyro, corrected.gyro)):
        t_rel = written.temp - 25.0
        terms = np.stack([t_rel**3, t_rel**2, t_rel, dtemp**2, dtemp, t_rel * dtemp, np.ones_like(t_rel)], 1)
        thermal_bias = terms @ triad.segments[0].coeffs.T
        expected = np.linalg.solve(cal.matrix, (raw_values - cal.bias - thermal_bias).T).T
        np.testing.assert_allclose(got, expected, rtol=1e-7, atol=1e-9)
    assert "dtemp" not in out.read_text().splitlines()[0]


def test_apply_refuses_a_missing_or_foreign_parameter_file(recording, tmp_path, capsys) -> None:
    truth, rec = recording
    raw = tmp_path / "raw.csv"
    write_csv(raw, rec.to_capture())
    assert cli.main(["apply", str(tmp_path / "none.yaml"), str(raw), "-o", str(tmp_path / "o.csv")]) == 4
    err = capsys.readouterr().err
    assert "none.yaml: does not exist" in err and "Traceback" not in err
    foreign = tmp_path / "foreign.yaml"
    foreign.write_text("schema: something/else\n")
    assert cli.main(["apply", str(foreign), str(raw), "-o", str(tmp_path / "o.csv")]) == 4
    assert "schema is 'something/else'" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def _nine_axis_capture(n: int, seed: int) -> tuple[Capture, dict[str, np.ndarray]]:
    """Raw samples from the forward models of the spec: raw_a = M_a f + b_a, raw_g = M_g w + b_g + G f,
    raw_m = M_m h + b_m, with f, w, h the true specific force, rate and field (accelerometer axes)."""
    rng = np.random.default_rng(seed)
    f = Rot.random(n, random_state=seed).apply([0.0, 0.0, STANDARD_GRAVITY]) + rng.normal(0, 0.5, (n, 3))
    w = rng.normal(0.0, 1.0, (n, 3))
    h = Rot.random(n, random_state=seed + 1).apply([0.0, 20.0, -44.0])
    truth = {"f": f, "w": w, "h": h}
    params = make_params(seed=seed, thermal=False, mag="accel", g_sensitivity=True)
    g_matrix = np.asarray(params.gyro.extra["g_sensitivity"])
    mag = params.other["mag"]
    raw = Capture(t=np.arange(n) / 100.0, acc=params.accel.forward(f),
                  gyro=params.gyro.forward(w) + f @ g_matrix.T,
                  mag=h @ np.asarray(mag["matrix"]).T + np.asarray(mag["bias"]))
    return raw, truth | {"params": params}


def test_apply_corrects_the_field_and_removes_g_sensitivity(tmp_path, capsys) -> None:
    raw, truth = _nine_axis_capture(2000, seed=31)
    params_path, raw_path, out = tmp_path / "unit.yaml", tmp_path / "raw.csv", tmp_path / "corrected.csv"
    truth["params"].save(params_path)
    write_csv(raw_path, raw)
    assert cli.main(["apply", str(params_path), str(raw_path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "g-sensitivity: removed at the corrected specific force" in text
    assert "mag: soft and hard iron, field in accel axes" in text
    header = next(line for line in out.read_text().splitlines() if not line.startswith("#"))  # after metadata
    assert header.split(",")[7:10] == ["mx", "my", "mz"]
    corrected = read_csv(out)
    # The CSV keeps 9 significant digits: the truth comes back to that.
    np.testing.assert_allclose(corrected.acc, truth["f"], atol=1e-6)
    np.testing.assert_allclose(corrected.gyro, truth["w"], atol=1e-7)
    np.testing.assert_allclose(corrected.mag, truth["h"], atol=1e-5)
    # By hand, the spec's equations: true = correction @ (raw - bias) with the file's own correction.
    mag = truth["params"].other["mag"]
    written = read_csv(raw_path)
    np.testing.assert_allclose(corrected.mag, (written.mag - mag["bias"]) @ np.asarray(mag["correction"]).T,
                               rtol=1e-7, atol=1e-6)
    # Without the g-sensitivity the gyro is off by G f (~1e-3 rad/s at 1 g): the term is really there.
    plain = ParamsFile.load(params_path)
    del plain.gyro.extra["g_sensitivity"]
    uncompensated, how = apply_params(plain, written)
    assert how["g-sensitivity"] == "absent"
    assert np.abs(uncompensated.gyro - truth["w"]).max() > 1e-4


def test_apply_without_a_field_or_without_a_mag_section(tmp_path) -> None:
    raw, truth = _nine_axis_capture(50, seed=32)
    params = truth["params"]
    six_axis = Capture(t=raw.t, acc=raw.acc, gyro=raw.gyro)
    corrected, how = apply_params(params, six_axis)
    assert how["mag"] == "not applied: the input has no mx, my, mz columns" and corrected.mag is None
    del params.other["mag"]
    corrected, how = apply_params(params, raw)
    assert how["mag"] == "absent (the input's field is copied)"
    assert np.array_equal(corrected.mag, raw.mag)
