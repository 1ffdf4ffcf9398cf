"""The simulated unit's characterisation features: RESTART (new turn-on biases, clock from 0, power-up
rate), the nonlinear and asymmetric gyro scale terms, g-sensitivity, constant-rate steps on the rig
and on the simulated rate table, and RESTART over a real pty with pyserial."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers import CommandRejected, SerialDevice
from drivers.turntable import Turntable
from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from mocks.rig import ConstantRate, Static, simulate
from mocks.truth import SensorTruth, UnitTruth
from mocks.turntable_sim import TurntableSim
from protocols import native
from protocols.native import NativeDecoder, encode_frame, encode_set_rate, parse_ack
from tests.device_helpers import read_samples


def test_restart_acks_then_starts_again_as_at_power_up_with_new_biases() -> None:
    device = SimDevice(seed=5, rate_hz=100)
    before = device.produce(2.0)
    device.feed(encode_set_rate(250))
    device.produce(3.0)
    (ack,) = NativeDecoder().feed(device.feed(encode_frame(native.RESTART))).messages
    assert parse_ack(ack.payload) == native.Ack(native.RESTART, native.ACK_OK)
    after = device.produce(5.0)
    assert after["seq"][0] == 0 and after["t_us"][0] == 0
    assert np.all(np.diff(after["t_us"].astype(np.int64)) == 10_000)  # the power-up rate again
    assert device.rate_hz == 100 and device.restarts == 1
    assert after["t_us"][-1] == pytest.approx(2.0e6, abs=1e4)  # its own clock: 2 s since the restart
    expected = UnitTruth.random(5).turned_on(1, 5)
    np.testing.assert_array_equal(device.truth.gyro.bias, expected.gyro.bias)
    shift = expected.gyro.bias - device.base_truth.gyro.bias
    assert np.all(np.abs(shift) > 0) and np.all(np.abs(shift) < 5 * device.base_truth.gyro.turn_on_sigma)
    np.testing.assert_allclose(after["gyro"].mean(axis=0) - before["gyro"].mean(axis=0), shift, atol=3e-3)


def test_a_unit_that_cannot_restart_answers_ack_status_1() -> None:
    device = SimDevice(seed=1, restartable=False)
    (ack,) = NativeDecoder().feed(device.feed(encode_frame(native.RESTART))).messages
    assert parse_ack(ack.payload) == native.Ack(native.RESTART, native.ACK_UNKNOWN)
    assert device.restarts == 0


def test_turned_on_draws_biases_with_the_truths_sigma() -> None:
    truth = UnitTruth(gyro=SensorTruth(turn_on_sigma=[1e-3, 2e-3, 3e-3]),
                      accel=SensorTruth(turn_on_sigma=0.02))
    assert truth.turned_on(0, 1) is truth
    draws = np.array([truth.turned_on(k, 1).gyro.bias for k in range(1, 2001)])
    np.testing.assert_allclose(draws.std(axis=0), [1e-3, 2e-3, 3e-3], rtol=0.05)
    np.testing.assert_allclose(draws.mean(axis=0), 0.0, atol=2e-4)


def test_quadratic_and_asymmetric_scale_terms_follow_their_definition() -> None:
    gyro = SensorTruth(scale=[1.0, 1.0, 1.02], scale_quadratic=[0, 0, 2e-4], scale_asymmetry=[0, 0, 3e-4])
    w = np.radians(np.array([-200.0, -50.0, 50.0, 200.0]))
    out = gyro.measure(np.column_stack([0 * w, 0 * w, w]), np.full(4, 25.0), np.zeros(4))[:, 2]
    y = 1.02 * w
    np.testing.assert_allclose(out, y + 1.5e-4 * np.abs(y) + 2e-4 * y**2, rtol=1e-12)
    k_pos = (out[3] - out[2]) / (w[3] - w[2])
    k_neg = (out[1] - out[0]) / (w[1] - w[0])
    assert k_pos > 1.02 > k_neg


def test_g_sensitivity_adds_g_times_the_specific_force() -> None:
    g_sens = np.array([[1e-4, 0, 0], [0, 0, 2e-4], [0, -3e-4, 0]])
    rec = simulate(UnitTruth(g_sensitivity=g_sens), [Static("+z", 1.0), Static("-y", 1.0)], rate_hz=50)
    for label, force in (("+z", [0, 0, 9.80665]), ("-y", [0, -9.80665, 0])):
        rows = np.array([str(s) for s in rec.step]) == label
        np.testing.assert_allclose(rec.gyro[rows].mean(axis=0), g_sens @ force, atol=1e-12)


def test_constant_rate_steps_are_labelled_only_while_steady() -> None:
    rec = simulate(UnitTruth.ideal(), [ConstantRate("+z", 90.0, 1.0, settle_s=0.5),
                                       ConstantRate("-x", 30.0, 1.0, settle_s=0.5)], rate_hz=100)
    labels = np.array([str(s) for s in rec.step])
    for label, axis, rate in (("rate+z:90", 2, 90.0), ("rate-x:30", 0, -30.0)):
        rows = labels == label
        assert 99 <= rows.sum() <= 101
        np.testing.assert_allclose(np.degrees(rec.true_rate[rows, axis]), rate, atol=1e-9)
        np.testing.assert_allclose(rec.acc[rows, axis], 9.80665, atol=1e-9)  # the axis is vertical
    unlabelled = np.degrees(np.abs(rec.true_rate[labels == ""]).max(axis=1))
    assert unlabelled.min() == 0.0 and unlabelled.max() <= 90.0 + 1e-9


def test_the_rate_table_spins_the_unit_through_its_driver() -> None:
    device = SimDevice(seed=2, rate_hz=200, truth=UnitTruth.ideal())
    with PtyServer(device, speed=20.0) as server, TurntableSim(server.device, rate_settle_s=0.5) as table, \
            Turntable(table.port_path) as tt, SerialDevice(server.port_path) as dev:
        dev.read(0.2)
        tt.spin("-z", 120.0, 1.0)
        samples = read_samples(dev, 200 * 3, 5.0)  # spin-up, settling, 1 s steady, spin-down at 20x
        tt.wait_idle(timeout_s=10.0)
        assert "SPIN -z 120 1" in table.commands
        with pytest.raises(CommandRejected, match="SPIN"):
            tt.command("SPIN +z 0 1")
    steady = np.abs(np.degrees(samples["gyro"][:, 2]) + 120.0) < 1e-3
    assert steady.sum() >= 250  # 0.5 s settling + 1 s labelled at 200 Hz, float32 on the wire


def test_restart_over_a_pty_gives_samples_from_zero_and_new_biases() -> None:
    truth = UnitTruth.random(8)
    device = SimDevice(truth, seed=8, rate_hz=200)
    with PtyServer(device, speed=10.0) as server, SerialDevice(server.port_path) as dev:
        first = read_samples(dev, 400, 5.0)
        dev.restart()
        time.sleep(0.05)
        dev.read(0)
        after = read_samples(dev, 400, 5.0)
    assert len(first) >= 400 and len(after) >= 400
    assert after["seq"][0] < 100 and after["t_us"][0] < 500_000  # the clock started again
    assert device.restarts == 1
    shift = after["gyro"].mean(axis=0) - first["gyro"].mean(axis=0)
    np.testing.assert_allclose(shift, device.truth.gyro.bias - truth.gyro.bias, atol=3e-3)


def test_restart_refused_by_a_unit_that_cannot_restart_over_a_pty() -> None:
    device = SimDevice(seed=3, rate_hz=100, restartable=False)
    with PtyServer(device, speed=5.0) as server, SerialDevice(server.port_path) as dev:
        with pytest.raises(CommandRejected) as info:
            dev.restart()
    assert info.value.status == native.ACK_UNKNOWN
