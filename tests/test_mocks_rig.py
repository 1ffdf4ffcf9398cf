"""The rig: poses, rotations and hand-held moves are physically consistent, labels follow the spec.

The attitude reference is independent of the rig's closed form: scipy's Rotation composes
the sampled true rates (second-order midpoint integration), and the rates are compared with
finite differences of the rig's attitudes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation as R

from mocks.rig import (
    SIX_POSITION,
    TWELVE_POSITION,
    Move,
    Rotation,
    Static,
    TemperatureProfile,
    Timeline,
    UnitSampler,
    constant,
    handheld_session,
    ramp,
    sequence_segments,
    simulate,
)
from mocks.truth import NoiseGenerator, NoiseSpec, UnitTruth
from protocols.base import SAMPLE_DTYPE

G = 9.80665


def segments_of(rec) -> list[tuple[str, slice]]:
    labels = np.asarray(rec.step)
    change = np.flatnonzero(labels[1:] != labels[:-1]) + 1
    bounds = np.concatenate([[0], change, [len(labels)]])
    return [(str(labels[a]), slice(int(a), int(b))) for a, b in zip(bounds[:-1], bounds[1:], strict=True)
            if labels[a] != ""]


def integrate_rates(rate: np.ndarray, dt: float, start: np.ndarray) -> np.ndarray:
    """Attitude after composing body rates sample by sample (midpoint rule), scipy rotations."""
    mid = 0.5 * (rate[1:] + rate[:-1]) * dt
    steps = R.from_rotvec(mid)
    out = R.from_matrix(start)
    for step in steps:  # sequential composition is what an integrator does; 1e4 steps at most here
        out = out * step
    return out.as_matrix()


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(R.from_matrix(a.T @ b).as_rotvec()))


def test_six_position_sequence_labels_and_gravity_per_pose() -> None:
    rec = simulate(UnitTruth.ideal(), sequence_segments("six-position", hold_s=1.0), rate_hz=100)
    segs = segments_of(rec)
    rotations = ["rot+x", "rot-x", "rot+y", "rot-y", "rot+z", "rot-z"]
    assert [label for label, _ in segs] == SIX_POSITION + rotations
    for label, sl in segs[:6]:
        up = {"x": 0, "y": 1, "z": 2}[label[1]]
        expected = np.zeros(3)
        expected[up] = G if label[0] == "+" else -G
        np.testing.assert_allclose(rec.acc[sl], np.broadcast_to(expected, rec.acc[sl].shape), atol=1e-12)
        np.testing.assert_allclose(rec.gyro[sl], 0.0, atol=1e-15)


def test_twelve_position_diagonal_poses_read_g_times_the_unit_vector() -> None:
    rec = simulate(UnitTruth.ideal(), sequence_segments("twelve-position", rotations=False, hold_s=0.5),
                   rate_hz=50)
    segs = dict(segments_of(rec))
    assert list(segs) == TWELVE_POSITION
    v = np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
    np.testing.assert_allclose(rec.acc[segs["+y+z"]].mean(axis=0), G * v, atol=1e-12)
    np.testing.assert_allclose(rec.acc[segs["-z-x"]].mean(axis=0), -G * np.array([1.0, 0, 1.0]) / np.sqrt(2),
                               atol=1e-12)


@pytest.mark.parametrize(("rotation", "label", "axis", "degrees"), [
    (Rotation("+z"), "rot+z", 2, 360.0),
    (Rotation("-y", rate_dps=120.0), "rot-y", 1, -360.0),
    (Rotation("+x", 180.0), "rot+x:180", 0, 180.0),
    (Rotation("-z", 10.0, rate_dps=90.0), "rot-z:10", 2, -10.0),  # triangle: never reaches 90 deg/s
])
def test_rotations_integrate_to_the_labelled_angle(rotation: Rotation, label: str, axis: int,
                                                   degrees: float) -> None:
    rate_hz = 400.0
    rec = simulate(UnitTruth.ideal(), [Static("+z", 0.5), rotation], rate_hz=rate_hz)
    sl = dict(segments_of(rec))[label]
    total = np.degrees(rec.gyro[sl].sum(axis=0) / rate_hz)
    # Rectangle sum of a piecewise-linear rate: the only error is at the ramp corners, O(alpha dt^2).
    assert total[axis] == pytest.approx(degrees, abs=1e-3)
    assert np.all(np.abs(np.delete(total, axis)) < 1e-9)
    peak = np.degrees(np.abs(rec.gyro[sl, axis]).max())
    assert peak <= rotation.rate_dps + 1e-9
    if abs(degrees) >= 90:
        assert peak == pytest.approx(rotation.rate_dps, rel=1e-9)
    # The axis is vertical throughout: the accelerometer reads g along it only.
    np.testing.assert_allclose(rec.acc[sl, axis], G, atol=1e-9)


def test_a_noisy_gyro_still_integrates_to_the_angle_within_its_noise() -> None:
    n_density = 1e-3  # rad/s/sqrt(Hz): the integrated angle has std N sqrt(T)
    truth = UnitTruth.ideal().with_noise(gyro=NoiseSpec(N=n_density))
    rec = simulate(truth, [Rotation("+z", 360.0, rate_dps=180.0)], rate_hz=200, seed=2)
    sl = dict(segments_of(rec))["rot+z"]
    duration = (sl.stop - sl.start) / 200
    angle = rec.gyro[sl, 2].sum() / 200
    assert abs(angle - 2 * np.pi) < 4 * n_density * np.sqrt(duration)


def test_handheld_moves_integrate_to_the_attitude_change() -> None:
    rate_hz = 500.0
    segments = handheld_session(n_poses=4, seed=11, hold_s=0.5, initial_still_s=0.5)
    rec = simulate(UnitTruth.ideal(), segments, rate_hz=rate_hz)
    att = rec.attitude()
    integrated = integrate_rates(rec.true_rate, 1.0 / rate_hz, att[0])
    # Over four large random moves the midpoint integrator stays within 1e-5 rad of the rig.
    assert angle_between(integrated, att[-1]) < 1e-5
    moving = np.linalg.norm(rec.true_rate, axis=1) > 0
    assert moving.mean() > 0.5  # there were real moves
    assert angle_between(att[0], att[-1]) > 0.1


def test_true_rate_is_the_derivative_of_the_attitude() -> None:
    odd = R.from_euler("xyz", [40, -70, 160], degrees=True).as_matrix()
    segments = [Static("+z", 0.2), Move(1.0), Static("-x+y", 0.2), Rotation("+y", 90.0, settle_s=0.1),
                Move(1.5), Static("", 0.2, attitude=odd)]
    timeline = Timeline(segments)
    t = np.linspace(0.0, timeline.duration_s, 4001)
    att = timeline.attitudes(t)
    h = 1e-6
    plus, minus = timeline.attitudes(t + h), timeline.attitudes(np.maximum(t - h, 0.0))
    fd = np.array([R.from_matrix(m.T @ p).as_rotvec() for m, p in zip(minus, plus, strict=True)])
    fd /= ((t + h) - np.maximum(t - h, 0.0))[:, None]
    rate = timeline.evaluate(t, [])[0]
    # Away from piece boundaries (where the rate has corners) the derivative matches to 1e-6 rad/s.
    inner = np.ones(len(t), bool)
    for p in timeline.pieces[:-1]:
        inner &= np.abs(t - p.t1) > 2 * h
    np.testing.assert_allclose(fd[inner], rate[inner], atol=1e-6)
    # And the specific force is the attitude's view of gravity.
    _, (force,), _ = timeline.evaluate(t, [np.array([0.0, 0.0, G])])
    np.testing.assert_allclose(force, np.einsum("nji,j->ni", att, [0.0, 0.0, G]), atol=1e-9)


def test_implicit_moves_keep_the_attitude_continuous() -> None:
    segments = [Static("+z", 0.5), Static("-y", 0.5), Rotation("+x", 90.0)]
    rec = simulate(UnitTruth.ideal(), segments, rate_hz=200)
    assert [label for label, _ in segments_of(rec)] == ["+z", "-y", "rot+x:90"]
    step = np.linalg.norm(np.diff(rec.acc, axis=0), axis=1)
    assert step.max() < 0.5  # m/s^2 per 5 ms: no jump anywhere
    integrated = integrate_rates(rec.true_rate, 1 / 200, rec.attitude()[0])
    assert angle_between(integrated, rec.attitude()[-1]) < 1e-5


def test_handheld_session_structure() -> None:
    segments = handheld_session(n_poses=5, seed=1, hold_s=2.0, initial_still_s=7.0)
    assert isinstance(segments[0], Static) and segments[0].duration_s == 7.0
    statics = [s for s in segments if isinstance(s, Static)]
    moves = [s for s in segments if isinstance(s, Move)]
    assert len(statics) == 6 and len(moves) == 5
    again = handheld_session(n_poses=5, seed=1, hold_s=2.0, initial_still_s=7.0)
    np.testing.assert_array_equal(statics[3].attitude, again[6].attitude)
    rec = simulate(UnitTruth.ideal(), segments, rate_hz=100)
    assert np.all(rec.true_rate[:700] == 0)
    assert set(rec.step) == {""}


def test_temperature_ramp_and_its_rate() -> None:
    profile = ramp([(0.0, 20.0), (2.0, 30.0), (3.0, 30.0)])
    rec = simulate(UnitTruth.ideal(), [Static("+z", 4.0)], rate_hz=100, temperature=profile,
                   temp_noise_degc=0.05, seed=4)
    np.testing.assert_allclose(rec.temp_true, np.interp(rec.t, [0, 2, 3], [20, 30, 30]), atol=1e-12)
    np.testing.assert_allclose(rec.dtemp_true[rec.t < 2], 5.0)
    np.testing.assert_allclose(rec.dtemp_true[rec.t >= 2], 0.0)
    assert np.std(rec.temp - rec.temp_true) == pytest.approx(0.05, rel=0.15)
    np.testing.assert_allclose(constant(21.5)(np.array([0.0, 100.0])), 21.5)
    np.testing.assert_allclose(TemperatureProfile.ramp([(0, 10.0), (10, 20.0)]).rate(np.array([5.0])), 1.0)
    # Any callable works as a profile: its rate comes from a central difference.
    rec2 = simulate(UnitTruth.ideal(), [Static("+z", 1.0)], rate_hz=10, temperature=lambda t: 25 + 0.1 * t)
    np.testing.assert_allclose(rec2.dtemp_true, 0.1, rtol=1e-6)


def test_thermal_bias_appears_in_the_raw_output() -> None:
    truth = UnitTruth.ideal()
    truth.gyro.thermal.coeffs[:, 2] = [1e-3, -2e-3, 0.5e-3]  # rad/s per degC
    rec = simulate(truth, [Static("+z", 2.0)], rate_hz=50, temperature=ramp([(0, 25.0), (2, 35.0)]))
    np.testing.assert_allclose(rec.gyro, np.outer(rec.temp_true - 25.0, [1e-3, -2e-3, 0.5e-3]), atol=1e-12)


def test_same_seed_same_arrays_and_blocks_do_not_matter() -> None:
    truth = UnitTruth.random(5)
    segments = sequence_segments("six-position", hold_s=0.5)
    a = simulate(truth, segments, rate_hz=200, seed=9)
    b = simulate(truth, segments, rate_hz=200, seed=9)
    c = simulate(truth, segments, rate_hz=200, seed=10)
    np.testing.assert_array_equal(a.acc, b.acc)
    np.testing.assert_array_equal(a.gyro, b.gyro)
    np.testing.assert_array_equal(a.temp, b.temp)
    assert not np.array_equal(a.gyro, c.gyro)
    sampler = UnitSampler(truth, Timeline(segments), rate_hz=200, seed=9)
    blocks = [sampler.next(n) for n in (3, 250, 1, len(a) - 254)]
    np.testing.assert_array_equal(np.vstack([r.gyro for r in blocks]), a.gyro)
    np.testing.assert_array_equal(np.concatenate([r.samples() for r in blocks]), a.samples())


def test_samples_and_capture_views() -> None:
    rec = simulate(UnitTruth.random(2), [Static("+x", 1.0)], rate_hz=250)
    s = rec.samples()
    assert s.dtype == SAMPLE_DTYPE
    np.testing.assert_array_equal(s["seq"], np.arange(len(rec)))
    np.testing.assert_array_equal(s["t_us"], np.arange(len(rec)) * 4000)
    np.testing.assert_array_equal(s["acc"], rec.acc.astype(np.float32))
    cap = rec.to_capture()
    assert cap.device["serial"] == "SIM-000002" and cap.device["rate_hz"] == 250
    assert cap.rate_hz == pytest.approx(250.0)
    assert [label for label, _ in cap.segments()] == ["+x"]
    assert cap.dtemp is None
    assert rec.to_capture(true_dtemp=True).dtemp is not None


def test_bad_segments_are_refused() -> None:
    with pytest.raises(ValueError, match="signed axes"):
        simulate(UnitTruth.ideal(), [Static("up", 1.0)])
    with pytest.raises(ValueError, match="twice"):
        simulate(UnitTruth.ideal(), [Static("+x-x", 1.0)])
    with pytest.raises(ValueError, match="signed axis"):
        simulate(UnitTruth.ideal(), [Rotation("z")])
    with pytest.raises(ValueError, match="unknown sequence"):
        sequence_segments("seven-position")
    with pytest.raises(ValueError, match="non-positive"):
        simulate(UnitTruth.ideal(), [Static("+z", 0.0)])


def test_recording_carries_the_bias_each_triad_really_had() -> None:
    """acc_bias/gyro_bias: static bias + thermal bias + bias instability + random walk, per sample.

    With the white noise off and no quantization, raw - M true is exactly that realized bias; the
    drift it carries is the noise generator's own slowly varying part, with the same numbers."""
    truth = UnitTruth.random(21)
    quiet = [replace(s.noise, N=0.0) for s in (truth.accel, truth.gyro)]
    truth = truth.with_noise(*quiet)
    truth.accel.resolution = truth.gyro.resolution = None
    truth.accel.thermal.coeffs[:, 2] = [1e-3, -2e-3, 0.5e-3]
    rec = simulate(truth, sequence_segments("six-position", hold_s=20.0), rate_hz=50, seed=21,
                   temperature=ramp([(0.0, 20.0), (300.0, 35.0)]))
    np.testing.assert_allclose(rec.acc - rec.true_specific_force @ truth.accel.matrix.T, rec.acc_bias,
                               atol=1e-12)
    np.testing.assert_allclose(rec.gyro - rec.true_rate @ truth.gyro.matrix.T, rec.gyro_bias, atol=1e-12)
    # the bias moved during the session (drift and thermal), away from the static truth
    assert np.ptp(rec.acc_bias - truth.accel.bias, axis=0).min() > 1e-4
    # asking for the drift changes no number of the noise itself
    gen_a = NoiseGenerator(truth.accel.noise, 50.0, np.random.SeedSequence(3))
    gen_b = NoiseGenerator(truth.accel.noise, 50.0, np.random.SeedSequence(3))
    total, drift = gen_a.next_with_drift(500)
    np.testing.assert_array_equal(total, gen_b.next(500))
    assert np.abs(drift).max() > 0
