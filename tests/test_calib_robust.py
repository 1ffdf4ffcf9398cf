"""Calibration on captures unlike the project's own: raw counts, large errors, a reversed gyro axis,
1 kHz sessions, short still periods, and the clear errors for mislabelled or damaged captures.

Each test pins a failure the robustness sweep found (the sweep itself runs every scenario end to end
through the command line; these are its cheap regressions)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mocks.rig import handheld_session, sequence_segments, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.engines.calibration.common import convert_convention, covariance
from station.engines.calibration.free import FreeCapture, FreeSettings, _check_gyro_saturation, calibrate_free
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.errors import EngineInputError
from station.export.params.file import ParamsFile

DEG = np.pi / 180


def _in_counts(tr: SensorTruth, unit: float, rng: np.random.Generator, bias_max: float,
               reverse: int | None = None) -> SensorTruth:
    """A triad with scale 0.9..1.1, misalignment up to 3 deg and a large bias, reporting ``unit``
    counts per SI unit (noise, quantization and range in counts too)."""
    scale = rng.uniform(0.9, 1.1, 3)
    if reverse is not None:
        scale[reverse] *= -1
    mis = rng.uniform(-3 * DEG, 3 * DEG, (3, 3))
    np.fill_diagonal(mis, 0)
    n = tr.noise
    noise = NoiseSpec(N=n.N * unit, B=n.B * unit, K=n.K * unit, Q=n.Q * unit, b_corr_time_s=n.b_corr_time_s)
    return dataclasses.replace(tr, scale=scale * unit, misalignment=mis,
                               bias=rng.uniform(-bias_max, bias_max, 3) * unit, noise=noise,
                               thermal=dataclasses.replace(tr.thermal, coeffs=tr.thermal.coeffs * unit),
                               saturation=1.2 * tr.saturation * unit,
                               resolution=1.0 if unit > 1 else tr.resolution)


def _unit(seed: int, acc_unit: float = 1.0, gyro_unit: float = 1.0, reverse: int | None = None) -> UnitTruth:
    base = UnitTruth.random(seed)
    rng = np.random.default_rng(seed)
    return dataclasses.replace(base, accel=_in_counts(base.accel, acc_unit, rng, 0.5),
                               gyro=_in_counts(base.gyro, gyro_unit, rng, 5 * DEG, reverse))


@pytest.fixture(scope="module")
def labelled():
    """A short twelve-position + rotations capture of a unit with large errors (3 s holds, 50 Hz)."""
    truth = _unit(41)
    rec = simulate(truth, sequence_segments("twelve-position", True, hold_s=3.0), rate_hz=50.0, seed=41)
    return truth, rec


def _relabel(step: np.ndarray, mapping: dict[str, str]) -> np.ndarray:
    return np.array([mapping.get(s, s) for s in step], dtype=object)


def test_large_errors_recovered_and_swapped_rotations_warned(labelled) -> None:
    truth, rec = labelled
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                                 TurntableSettings(gravity=truth.gravity))
    assert np.abs(report.accel.matrix - truth.accel.matrix).max() < 1e-3
    assert np.abs(report.gyro.matrix - truth.gyro.matrix).max() < 1e-3
    assert report.warnings == []
    # rot+y and rot-y swapped is a reversed y axis to the data: accepted with a warning that says both
    swapped = _relabel(rec.step, {"rot+y": "rot-y", "rot-y": "rot+y"})
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, swapped),
                                 TurntableSettings(gravity=truth.gravity))
    assert report.gyro.scale[1] < 0
    assert any("y axis turns opposite to the labels" in w and "rot+y and rot-y were swapped" in w
               for w in report.warnings)


@pytest.mark.parametrize(("mapping", "message"), [
    ({"+x": "-x", "-x": "+x"}, r"accelerometer x axis reads -g where the labels put \+x up"),
    ({"+y": "+z"}, r"static step '\+z' \(t = .*\) disagrees with its label: .* reads nearest '\+y' up"),
    ({"+x": "+x+y"}, r"static step '\+x\+y' .* reads nearest '\+x' up"),
    ({"rot+z": "rot-x", "rot-x": "rot+z"}, r"rotation step 'rot(\+z|-x)' .* deg from the vertical"),
    ({"rot+z": "rot+z:180"}, r"rotation step 'rot\+z:180' .* the label says 180.0 deg"),
])
def test_mislabelled_steps_are_refused_by_name(labelled, mapping, message) -> None:
    truth, rec = labelled
    with pytest.raises(EngineInputError, match=message):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, _relabel(rec.step, mapping)),
                            TurntableSettings(gravity=truth.gravity))


def test_six_position_with_swapped_poses_is_refused() -> None:
    # six poses fit any sign of a column exactly: only the sign of the scale shows the swap
    truth = _unit(42)
    rec = simulate(truth, sequence_segments("six-position", True, hold_s=2.0), rate_hz=50.0, seed=42)
    step = _relabel(rec.step, {"+z": "-z", "-z": "+z"})
    with pytest.raises(EngineInputError, match=r"the steps \+z and -z are swapped"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, step),
                            TurntableSettings(gravity=truth.gravity))


def test_labels_that_reach_into_the_moves_are_refused(labelled) -> None:
    truth, rec = labelled
    late = np.concatenate([np.array([""] * 25, dtype=object), rec.step[:-25]])   # labels 0.5 s late
    with pytest.raises(EngineInputError, match=r"moved during static step .* of the gravity reading"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, late),
                            TurntableSettings(gravity=truth.gravity))


def test_a_steady_turn_under_coarse_resolution_is_not_saturation() -> None:
    # gyro noise a sixth of its 16-bit step: a steady 90 deg/s turn reads one value for many samples
    base = UnitTruth.random(45)
    n = base.gyro.noise
    quiet = NoiseSpec(N=n.N / 10, B=n.B / 10, K=n.K / 10, b_corr_time_s=n.b_corr_time_s)
    truth = dataclasses.replace(base, gyro=dataclasses.replace(base.gyro, noise=quiet))
    rec = simulate(truth, sequence_segments("six-position", True, hold_s=2.0), rate_hz=100.0, seed=45)
    turn = rec.step == "rot-y"
    assert _longest_run(rec.gyro[turn, 1]) >= 10
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                                 TurntableSettings(gravity=truth.gravity))
    assert np.abs(report.gyro.matrix - truth.gyro.matrix).max() < 2e-3


def _longest_run(x: np.ndarray) -> int:
    change = np.flatnonzero(np.diff(x) != 0)
    return int(np.diff(np.concatenate([[-1], change, [len(x) - 1]])).max())


def test_covariance_of_parameters_of_very_different_sizes() -> None:
    # a bias in counts (1e4) beside a scale in SI per count (1e-4): J^T J has a condition number of 1e16
    rng = np.random.default_rng(5)
    base = rng.standard_normal((200, 3))
    sizes = np.array([1e-4, 1.0, 1e4])
    jac = base / sizes
    residual = rng.standard_normal(200)
    cov, s2 = covariance(jac, residual)
    # the exact answer in the unscaled parameters, mapped back: cov = D cov_base D
    cov_base, _ = covariance(base, residual)
    np.testing.assert_allclose(cov, cov_base * np.outer(sizes, sizes), rtol=1e-9)
    assert s2 == pytest.approx(residual @ residual / 197)


def test_handheld_session_in_counts_with_reversed_gyro_and_short_still_period(tmp_path) -> None:
    """Raw counts (accel 16000 per m/s^2, gyro 400 per rad/s), gyro z reversed, a 4 s still period,
    through the command line; the accelerometer bias's 1-sigma is in counts (it was in m/s^2)."""
    acc_unit, gyro_unit = 16000.0, 400.0
    truth = _unit(43, acc_unit, gyro_unit, reverse=2)
    rec = simulate(truth, handheld_session(n_poses=24, seed=43, hold_s=4.0, initial_still_s=4.0),
                   rate_hz=100.0, seed=43)
    capture = rec.to_capture()
    capture.step = None
    csv = tmp_path / "counts.csv"
    write_csv(csv, capture)
    params = tmp_path / "unit.yaml"
    assert cli.main(["calibrate", str(csv), "--method", "free", "-o", str(params)]) == 0
    loaded = ParamsFile.load(params)
    acc_c, gyro_c, _ = convert_convention(np.linalg.inv(truth.accel.matrix), np.linalg.inv(truth.gyro.matrix),
                                          "lower")
    still = np.linalg.norm(rec.true_rate, axis=1) == 0
    for cal, m_true, realized, unit, tol in (
            (loaded.accel, np.linalg.inv(acc_c), rec.acc_bias[still].mean(axis=0), acc_unit, 1e-3),
            (loaded.gyro, np.linalg.inv(gyro_c), rec.gyro_bias[still].mean(axis=0), gyro_unit, 1e-4)):
        assert np.abs(cal.matrix - m_true).max() < 5e-4 * unit
        assert np.abs(cal.bias - realized).max() < tol * unit
        sd = np.asarray(cal.stddev["bias"])
        assert np.all(np.abs(cal.bias - realized) < 3 * sd)
        assert np.all(sd < 3 * tol * unit)            # a sigma of the right size, in counts
    assert loaded.gyro.matrix[2, 2] < 0


def test_lost_samples_inside_a_move_are_refused() -> None:
    truth = UnitTruth.random(44)
    rec = simulate(truth, handheld_session(n_poses=14, seed=44, hold_s=3.0, initial_still_s=5.0),
                   rate_hz=50.0, seed=44)
    keep = (rec.t < 10.9) | (rec.t > 11.2)    # the move from 10 to 12 s loses 0.3 s
    with pytest.raises(EngineInputError, match=r"move at t = .* has a gap of 0\.3.. s .*lost samples"):
        calibrate_free(FreeCapture(rec.t[keep], rec.acc[keep], rec.gyro[keep]),
                       FreeSettings(gravity=truth.gravity))


def test_a_quantized_smooth_peak_is_not_saturation() -> None:
    rate = 100.0
    t = np.arange(0, 20, 1 / rate)
    rng = np.random.default_rng(6)
    gyro = 1e-5 * rng.standard_normal((len(t), 3))
    gyro[:500] *= 300.0                             # the still period's noise spans several steps
    lsb = 2000 * DEG / 32768
    # a slow move's rate peaks smoothly near 2.16 rad/s, just below a quantization step's upper edge:
    # quantized, it reads one value for several samples
    peak = lsb * (np.round(2.16 / lsb) + 0.45)
    u = np.clip((t - 12.0) / 4.0, 0, 1)
    gyro[:, 1] += peak * 16 * u**2 * (1 - u) ** 2
    quantized = np.round(gyro / lsb) * lsb
    peak = np.abs(quantized[:, 1] - quantized[:, 1].max()) == 0
    assert peak.sum() >= 5
    _check_gyro_saturation(t, quantized, 500)
    clipped = quantized.copy()
    clipped[:, 1] = np.minimum(clipped[:, 1], 1.5)  # pinned for about 0.5 s
    with pytest.raises(EngineInputError, match="gyroscope y axis is saturated"):
        _check_gyro_saturation(t, clipped, 500)


def test_short_holds_keep_every_static_interval() -> None:
    # 2.2 s holds leave intervals of about 1.2 s under a 1 s window: every one is used (trimming the
    # ends for the means must not drop them below the 1 s minimum)
    truth = UnitTruth.random(46)
    rec = simulate(truth, handheld_session(n_poses=16, seed=46, hold_s=2.2, initial_still_s=5.0),
                   rate_hz=50.0, seed=46)
    report = calibrate_free(FreeCapture(rec.t, rec.acc, rec.gyro), FreeSettings(gravity=truth.gravity))
    assert report.accel.extra["static_intervals"] == 17
