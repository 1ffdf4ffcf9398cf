"""Pure checks: stillness, pose angle, saturation, dropouts and the integrated turn angle."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid
from scipy.spatial.transform import Rotation

from drivers.link_stats import LinkMonitor
from protocols.base import SAMPLE_DTYPE
from station.acquisition import checks
from station.acquisition.checks import Limits

G = 9.80665
RNG = np.random.default_rng(7)


def test_stillness_separates_rest_from_hand_motion_and_steady_turns():
    n = 200
    acc_rest = np.array([0, 0, G]) + RNG.normal(0, 0.02, (n, 3))
    gyro_rest = RNG.normal(0, 0.005, (n, 3)) + 0.01  # MEMS noise and a bias of 0.6 deg/s
    rest = checks.stillness(acc_rest, gyro_rest)
    assert rest.still and rest.score == 1.0
    assert rest.acc_std == pytest.approx(0.02, rel=0.25)
    shaking = checks.stillness(acc_rest + RNG.normal(0, 0.5, (n, 3)), gyro_rest)
    assert not shaking.still and 0 < shaking.score < 0.3
    # A steady 90 deg/s turn has a small spread but is not still.
    turning = checks.stillness(acc_rest, gyro_rest + [0, 0, math.radians(90)])
    assert not turning.still
    assert turning.gyro_mean == pytest.approx(math.radians(90), rel=0.02)
    assert not checks.stillness(acc_rest[:1], gyro_rest[:1]).still


def test_pose_angle_against_scipy_rotation():
    # Tilt the +z pose by known angles about a random horizontal axis: the check reports that angle.
    for tilt in (0.0, 3.0, 11.0, 25.0, 90.0, 179.0):
        axis = np.array([math.cos(1.1), math.sin(1.1), 0.0])
        up = Rotation.from_rotvec(math.radians(tilt) * axis).apply([0, 0, 1])
        acc = G * up + RNG.normal(0, 0.01, (100, 3))
        pc = checks.pose_check(acc, np.array([0, 0, 1.0]), tolerance_deg=12.0)
        assert pc.angle_deg == pytest.approx(tilt, abs=0.05)
        assert pc.ok == (tilt <= 12.0)
    diag = checks.pose_check(np.tile(G * np.array([1, 1, 0]) / math.sqrt(2), (10, 1)), np.array([1, 0, 0]), 5)
    assert diag.angle_deg == pytest.approx(45.0) and diag.nearest == "+x+y" and not diag.ok
    assert checks.nearest_pose(np.array([-0.1, 0.05, -9.7])) == "-z"
    assert checks.pose_check(np.zeros((0, 3)), np.array([0, 0, 1.0]), 5).ok is False


def test_vertical_axis_accepts_the_axis_up_or_down():
    down = np.tile([0.2, 0.1, -G], (20, 1))
    vc = checks.vertical_axis_check(down, axis=2, tolerance_deg=5)
    assert vc.ok and vc.nearest == "-z"
    assert not checks.vertical_axis_check(down, axis=0, tolerance_deg=5).ok


def test_saturation_with_a_known_limit_and_by_clipping():
    n = 400
    acc = np.array([0, 0, G]) + RNG.normal(0, 0.02, (n, 3))
    gyro = RNG.normal(0, 0.01, (n, 3))
    assert checks.saturation(acc, gyro).ok
    # A knock: 30 samples beyond a 4 g range clip to the range.
    acc[100:130, 0] = 60.0
    acc_clipped = np.clip(acc, -4 * G, 4 * G)
    sat = checks.saturation(acc_clipped, gyro)
    assert sat.acc_samples == 30 and sat.gyro_samples == 0 and not sat.ok
    assert checks.saturation(acc_clipped, gyro, Limits(acc_saturation=4 * G)).acc_samples == 30
    # A fast turn clipped at 250 deg/s on a coarse quantizer.
    gyro[200:260, 2] = math.radians(250)
    assert checks.saturation(acc, gyro).gyro_samples == 60
    # Quantized rest data repeats values, but never the peak for long at 1 g.
    coarse = np.round(acc[:100] / 0.05) * 0.05
    assert checks.clipped_samples(coarse[:, 2:], floor=15.0) == 0


def test_dropouts_agree_with_the_drivers_link_monitor():
    seq = np.arange(4_294_967_290, 4_294_967_290 + 40, dtype=np.int64) % 2**32
    keep = np.ones(40, bool)
    keep[[3, 4, 5, 12, 30]] = False  # 3 gaps across the u32 wrap, 5 samples lost
    kept = seq[keep].astype(np.uint32)
    d = checks.dropouts(kept)
    assert (d.received, d.lost, d.gaps) == (35, 5, 3)
    assert d.lost_fraction == pytest.approx(5 / 40)
    monitor = LinkMonitor()
    batch = np.zeros(len(kept), SAMPLE_DTYPE)
    batch["seq"] = kept
    batch["t_us"] = np.arange(len(kept)) * 1000
    monitor.add_samples(batch)
    assert monitor.stats.lost == d.lost
    assert checks.dropouts(np.array([5, 5, 6], np.uint32)).lost == 0


def test_integrated_angle_against_scipy_and_rotation_tolerance():
    rate_hz = 200.0
    t = np.arange(0, 6, 1 / rate_hz)
    # Trapezoidal rate profile of a 360 deg turn at 90 deg/s, 0.5 s ramps, plus a bias.
    rate = np.interp(t, [0, 1, 1.5, 1.5 + 3.5, 5.5, 6], [0, 0, 90, 90, 0, 0])
    bias = 0.02
    gyro = np.zeros((len(t), 3))
    gyro[:, 1] = np.radians(rate) + bias
    angle = checks.integrated_angle_deg(t, gyro, axis=1, bias=bias)
    ref = np.degrees(cumulative_trapezoid(gyro[:, 1] - bias, t, initial=0))
    assert np.allclose(angle, ref, atol=1e-9)
    assert angle[-1] == pytest.approx(360.0, abs=0.5)
    ok = checks.rotation_check(angle[-1], 360.0)
    assert ok.ok and ok.tolerance_deg == pytest.approx(18.0) and ok.fraction == pytest.approx(1.0, abs=2e-3)
    wrong_way = checks.rotation_check(-angle[-1], 360.0)
    assert not wrong_way.ok and wrong_way.fraction == 0.0
    assert not checks.rotation_check(180.0, -360.0).ok
    assert checks.rotation_check(92.0, 90.0).ok and not checks.rotation_check(101.0, 90.0).ok
