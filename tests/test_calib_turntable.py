"""Turntable method: recovery of the simulated unit's truth, agreement with imucal, real data, and
the clear errors for data that cannot determine the parameters.

Simulated sequences use realistic MEMS noise (``UnitTruth.random``: white noise, bias instability
50 ug / 5 deg/h, rate random walk, 16-bit quantization) at 100 Hz with 360 deg turns at 90 deg/s.
That unit's accelerometer bias wanders about its static truth.bias by about 5e-4 m/s^2 (1 sigma,
Gauss-Markov with a 100 s correlation time, plus the random walk), so the issue's 1e-3 m/s^2 is about
two sigma of that drift per axis: against the static truth it holds for most captures, not all (the
Monte Carlo at the end, and benchmarks/calibration.py section 3, measure how often). The fixed-seed
tests keep that check on one unit each; the Monte Carlo applies the tolerance to the bias the unit
really had (``Recording.acc_bias``) and the reported 3-sigma, which carries the drift budget, to the
static truth.
"""

from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
from imucal import FerrarisCalibration
from imucal.ferraris_calibration import FerrarisSignalRegions

from mocks.rig import Move, Rotation, Static, sequence_segments, simulate
from mocks.truth import UnitTruth
from station.engines.calibration._static import fit_poses, six_position
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.errors import EngineInputError

HOLD_S = 60.0
RATE_HZ = 100.0


def _recording(sequence: str, seed: int, hold_s: float = HOLD_S):
    truth = UnitTruth.random(seed)
    segments = sequence_segments(sequence, True, hold_s=hold_s)
    return truth, simulate(truth, segments, rate_hz=RATE_HZ, seed=seed)


@pytest.fixture(scope="module")
def twelve():
    return _recording("twelve-position", 3)


@pytest.fixture(scope="module")
def six():
    return _recording("six-position", 1)


@pytest.fixture(scope="module")
def short_six():
    return _recording("six-position", 11, hold_s=8.0)


def _check_recovery(report, truth, bias_tolerance: bool = True) -> None:
    """The issue's tolerances against the truth: matrix 2e-4, bias 1e-3 m/s^2 and 1e-4 rad/s against
    the static truth.bias (unless ``bias_tolerance`` is False), every group inside its 3-sigma."""
    for cal, tr, bias_tol in ((report.accel, truth.accel, 1e-3), (report.gyro, truth.gyro, 1e-4)):
        dm = cal.matrix - tr.matrix
        db = cal.bias - tr.bias
        assert np.abs(dm).max() < 2e-4
        if bias_tolerance:
            assert np.abs(db).max() < bias_tol
        # inside the reported 3-sigma, entry by entry
        assert np.all(np.abs(dm) < 3 * cal.stddev["matrix"])
        assert np.all(np.abs(db) < 3 * cal.stddev["bias"])
        ds = cal.scale - tr.scale
        assert np.all(np.abs(ds) < 3 * cal.stddev["scale"])
        mis = cal.misalignment - tr.misalignment
        off = ~np.eye(3, dtype=bool)
        assert np.all(np.abs(mis[off]) < 3 * cal.stddev["misalignment"][off])


def test_twelve_position_with_rotations_recovers_truth(twelve) -> None:
    truth, rec = twelve
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step, rate_hz=RATE_HZ),
                                 TurntableSettings(gravity=truth.gravity))
    _check_recovery(report, truth)
    assert report.warnings == []
    assert "12-pose" in report.accel.method
    labels = [p["label"] for p in report.poses]
    assert labels[:12] == ["+x", "-x", "+y", "-y", "+z", "-z", "+x+y", "-x-y", "+y+z", "-y-z", "+z+x", "-z-x"]
    assert all(abs(p["norm_error"]) < 5e-3 for p in report.poses if p["kind"] == "static")
    assert all(abs(p["angle_error_deg"]) < 0.05 for p in report.poses if p["kind"] == "rotation")


def test_six_position_with_rotations_recovers_truth_and_matches_imucal(six) -> None:
    truth, rec = six
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                                 TurntableSettings(gravity=truth.gravity))
    _check_recovery(report, truth)
    assert "six-position" in report.accel.method

    # imucal's Ferraris calibration on the same regions: the accelerometer solution is the same
    # analytic one; imucal's gyro (deg/s, bias from the statics, one turn per axis) agrees closely.
    regions = {}
    for label, name in (("+x", "x_p"), ("-x", "x_a"), ("+y", "y_p"), ("-y", "y_a"), ("+z", "z_p"),
                        ("-z", "z_a"), ("rot-x", "x_rot"), ("rot-y", "y_rot"), ("rot-z", "z_rot")):
        rows = rec.step == label
        regions[f"acc_{name}"] = rec.acc[rows]
        regions[f"gyr_{name}"] = np.degrees(rec.gyro[rows])
    info = FerrarisCalibration(grav=truth.gravity).compute(FerrarisSignalRegions(**regions), RATE_HZ, "m/s^2",
                                                           "deg/s")
    np.testing.assert_allclose(report.accel.matrix, info.K_a @ info.R_a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(report.accel.bias, info.b_a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(report.gyro.bias, np.radians(info.b_g), atol=1e-12)
    np.testing.assert_allclose(report.gyro.matrix, info.K_g @ info.R_g, atol=1e-3)


def test_six_position_is_the_least_squares_solution_with_ferraris_bias(six) -> None:
    truth, rec = six
    labels = ["+x", "-x", "+y", "-y", "+z", "-z"]
    means = {lab: rec.acc[rec.step == lab].mean(axis=0) for lab in labels}
    up = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    m, b = six_position(means, truth.gravity)
    fit = fit_poses(np.array([means[k] for k in labels]), up, truth.gravity, np.full((6, 3), 1e-8), labels)
    np.testing.assert_allclose(fit.matrix, m, atol=1e-12)
    # least squares takes the mean of all six for the bias; Ferraris the pair along each axis
    np.testing.assert_allclose(fit.bias, np.mean(list(means.values()), axis=0), atol=1e-12)
    pairs = [(means[f"+{a}"][i] + means[f"-{a}"][i]) / 2 for i, a in enumerate("xyz")]
    np.testing.assert_allclose(b, pairs, atol=1e-12)


def test_earth_rate_compensation_on_a_unit_that_sees_it() -> None:
    truth = UnitTruth.random(5, grade="tactical")
    truth.earth_rate = True
    truth.latitude_deg = 45.0
    rec = simulate(truth, sequence_segments("six-position", True, hold_s=20.0), rate_hz=RATE_HZ, seed=5)
    plain = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                                TurntableSettings(gravity=truth.gravity))
    comp = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                               TurntableSettings(gravity=truth.gravity, latitude_deg=45.0))
    # the vertical Earth rate adds Omega sin(45 deg) * duration to every turn's integrated angle;
    # compensating it brings the gyro scale closer to the truth
    err_plain = np.abs(plain.gyro.scale - truth.gyro.scale).max()
    err_comp = np.abs(comp.gyro.scale - truth.gyro.scale).max()
    assert err_comp < err_plain
    assert comp.gyro.extra["earth_rate_compensated"] is True


def _relabel(step: np.ndarray, old: str, new: str) -> np.ndarray:
    out = step.copy()
    out[out == old] = new
    return out


def test_refuses_too_few_poses(short_six) -> None:
    truth, rec = short_six
    step = rec.step.copy()
    for lab in ("-y", "+z", "-z"):
        step = _relabel(step, lab, "")
    with pytest.raises(EngineInputError, match="only 3 static poses"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, step),
                            TurntableSettings(gravity=truth.gravity))


def test_rank_deficiency_names_the_axis_the_poses_miss(short_six) -> None:
    truth, rec = short_six
    step = _relabel(_relabel(rec.step, "+z", ""), "-z", "")
    step = _relabel(step, "rot+z", "")  # keep the accel problem the only one
    with pytest.raises(EngineInputError, match="no pose has gravity along the z axis"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, step),
                            TurntableSettings(gravity=truth.gravity))
    # without -x the other poses still fix the bias, so it is solvable but flagged
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, _relabel(rec.step, "-x", "")),
                                 TurntableSettings(gravity=truth.gravity))
    assert any("x axis was never held near both up and down" in w for w in report.warnings)


def test_missing_rotations_are_named(short_six) -> None:
    truth, rec = short_six
    step = _relabel(_relabel(rec.step, "rot+y", ""), "rot-y", "")
    with pytest.raises(EngineInputError, match="no rotation about the y axis"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, step),
                            TurntableSettings(gravity=truth.gravity))
    no_rotations = np.array([s if not s.startswith("rot") else "" for s in rec.step], dtype=object)
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, no_rotations),
                                 TurntableSettings(gravity=truth.gravity))
    assert report.gyro is None
    assert any("no rotation steps" in w for w in report.warnings)


def test_refuses_a_unit_that_moved_during_a_static_step() -> None:
    truth = UnitTruth.random(12)
    segments = [Static("+z", 8.0), Move(2.0), Static("-z", 8.0), Move(2.0), Static("+x", 8.0), Move(2.0),
                Static("-x", 8.0), Move(2.0), Static("+y", 8.0), Move(2.0), Static("-y", 8.0)]
    rec = simulate(truth, segments, rate_hz=RATE_HZ, seed=12)
    step = rec.step.copy()
    moving = np.flatnonzero(step == "")[-150:]  # the last move, labelled as if it were still
    step[moving] = "+x+y"
    with pytest.raises(EngineInputError, match=r"moved during static step '\+x\+y'"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, step),
                            TurntableSettings(gravity=truth.gravity))


def test_refuses_saturated_rotation(short_six) -> None:
    truth, rec = short_six
    gyro = np.clip(rec.gyro, -1.2, 1.2)  # the turns reach 90 deg/s = 1.57 rad/s
    with pytest.raises(EngineInputError, match="gyroscope . axis is saturated"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, gyro, rec.step),
                            TurntableSettings(gravity=truth.gravity))


def test_refuses_a_wrong_sample_rate_and_gaps_in_rotations(short_six) -> None:
    truth, rec = short_six
    with pytest.raises(EngineInputError, match="stated sample rate 200 Hz disagrees"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step, rate_hz=200.0),
                            TurntableSettings(gravity=truth.gravity))
    rows = np.flatnonzero(rec.step == "rot+z")
    keep = np.ones(len(rec.t), bool)
    keep[rows[100:140]] = False
    with pytest.raises(EngineInputError, match="rotation step 'rot\\+z'.*gap"):
        calibrate_turntable(TurntableCapture(rec.t[keep], rec.acc[keep], rec.gyro[keep], rec.step[keep]),
                            TurntableSettings(gravity=truth.gravity))


def test_refuses_unlabelled_data(short_six) -> None:
    truth, rec = short_six
    with pytest.raises(EngineInputError, match="no step labels"):
        calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, np.full(len(rec.t), "", dtype=object)),
                            TurntableSettings(gravity=truth.gravity))


def _imucal_session(reference_data):
    path = reference_data / "imucal-ferraris" / "annotated_session.csv.gz"
    with gzip.open(path, "rt") as fh:
        header = fh.readline().strip().split(",")
        rows = [line.strip().split(",") for line in fh if line.strip()]
    assert header[:2] == ["part", "samples"]
    part = np.array([r[0] for r in rows])
    values = np.array([[float(v) for v in r[1:]] for r in rows])
    order = np.argsort(values[:, 0])
    part, values = part[order], values[order]
    # x_p: x up; x_a: x down; x_rot: -360 deg about x (imucal's convention)
    names = {"x_p": "+x", "x_a": "-x", "y_p": "+y", "y_a": "-y", "z_p": "+z", "z_a": "-z",
             "x_rot": "rot-x", "y_rot": "rot-y", "z_rot": "rot-z"}
    step = np.array([names[p] for p in part], dtype=object)
    return values[:, 0] / 204.8, values[:, 1:4], values[:, 4:7], step


def test_real_ferraris_session_against_imucal(reference_data) -> None:
    t, acc, gyr, step = _imucal_session(reference_data)
    report = calibrate_turntable(TurntableCapture(t, acc, gyr, step, rate_hz=204.8),
                                 TurntableSettings(gravity=9.81))
    for pose in report.poses:
        if pose["kind"] == "static":
            assert abs(pose["norm_error"]) < 0.01, pose
    cal = json.loads((reference_data / "imucal-ferraris" / "example_cal.json").read_text())
    k_a, r_a, b_a = (np.asarray(cal[k]) for k in ("K_a", "R_a", "b_a"))
    np.testing.assert_allclose(report.accel.matrix, k_a @ r_a, rtol=1e-9)
    np.testing.assert_allclose(report.accel.bias, b_a, rtol=1e-9)
    # imucal's gyro also removes an acceleration sensitivity we do not model: agree to 0.1%
    k_g, r_g, b_g = (np.asarray(cal[k]) for k in ("K_g", "R_g", "b_g"))
    m_imucal = k_g @ r_g * 180.0 / np.pi  # counts per deg/s -> counts per rad/s
    assert np.abs(report.gyro.matrix - m_imucal).max() < 1e-3 * np.abs(np.diag(m_imucal)).min()
    np.testing.assert_allclose(report.gyro.bias, b_g, rtol=1e-9)
    assert any("one way only" in w for w in report.warnings)


def test_rotations_by_any_angle_in_any_order() -> None:
    truth = UnitTruth.random(17)
    segments = [Static(p, 20.0) for p in ("+z", "-z", "+x", "-x", "+y", "-y")]
    segments += [Rotation("+x", 180.0), Rotation("-y", 540.0, rate_dps=120.0), Rotation("+z", 270.0),
                 Rotation("-x", 180.0), Rotation("+y", 540.0, rate_dps=120.0), Rotation("-z", 270.0)]
    rec = simulate(truth, segments, rate_hz=RATE_HZ, seed=17)
    assert {"rot+x:180", "rot-y:540", "rot+z:270"} <= set(rec.step)
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                                 TurntableSettings(gravity=truth.gravity))
    dm = report.gyro.matrix - truth.gyro.matrix
    assert np.abs(dm).max() < 2e-4
    assert np.all(np.abs(dm) < 3 * report.gyro.stddev["matrix"])


# --- Monte Carlo over fresh units ------------------------------------------------------------------
# Seeds 100..105 were fixed before any run. Each capture is a new UnitTruth.random(seed) at realistic
# MEMS noise, 30 s holds at 100 Hz. (With 10 s holds seed 103 failed: a session shorter than about two
# correlation times of the bias instability cannot see how far the bias sits from its long-run value,
# so the drift budget under-covers there; README, "what truth is".) The truth for the bias is
# twofold: the static truth.bias, which the reported sigma must cover (it carries the drift budget),
# and the bias the unit really had, averaged over the samples the estimate uses (Recording.acc_bias /
# gyro_bias), which the tolerances apply to: the unit's bias instability moves its bias by
# about 5e-4 m/s^2 (1 sigma) around truth.bias, a drift no capture can tell from the bias itself.
MC_SEEDS = range(100, 106)


def _realized_bias(rec, sequence: str) -> tuple[np.ndarray, np.ndarray]:
    """Mean realized bias over the samples each estimate averages: every static step for the
    twelve-pose least squares (equal holds, opposite poses: b is the mean of the pose means) and for
    the gyro; the pair along each axis for the six-position accelerometer (Ferraris' eq. 3)."""
    static = np.array([s != "" and not s.startswith("rot") for s in rec.step])
    gyro = rec.gyro_bias[static].mean(axis=0)
    if sequence == "twelve-position":
        return rec.acc_bias[static].mean(axis=0), gyro
    pair = [rec.acc_bias[(rec.step == f"+{a}") | (rec.step == f"-{a}"), i].mean()
            for i, a in enumerate("xyz")]
    return np.array(pair), gyro


@pytest.mark.parametrize("sequence", ["twelve-position", "six-position"])
def test_monte_carlo_over_fresh_units(sequence: str) -> None:
    for seed in MC_SEEDS:
        truth = UnitTruth.random(seed)
        rec = simulate(truth, sequence_segments(sequence, True, hold_s=30.0), rate_hz=RATE_HZ, seed=seed)
        report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step),
                                     TurntableSettings(gravity=truth.gravity))
        acc_real, gyro_real = _realized_bias(rec, sequence)
        for cal, real, tol in ((report.accel, acc_real, 1e-3), (report.gyro, gyro_real, 1e-4)):
            assert np.abs(cal.bias - real).max() < tol, (seed, cal.bias - real)
        _check_recovery(report, truth, bias_tolerance=False)
