"""The simulated device as a state machine: commands, streaming schedule, live motion, determinism."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from mocks.device import ENCODERS, SimDevice
from mocks.rig import Move, Rotation, Static, simulate
from mocks.truth import UnitTruth
from protocols import native
from protocols.native import NativeDecoder, encode_frame, encode_samples, encode_set_rate, parse_ack

G = 9.80665


def answers(device: SimDevice, data: bytes) -> list[native.Message]:
    return NativeDecoder().feed(device.feed(data)).messages


def test_get_info_answers_device_info() -> None:
    device = SimDevice(seed=4, rate_hz=250)
    (msg,) = answers(device, encode_frame(native.GET_INFO))
    assert msg.msg_id == native.DEVICE_INFO
    info = json.loads(msg.payload)
    assert info == {"serial": "SIM-000004", "model": "imu-sim-mems", "firmware": "1.0.0", "rate_hz": 250}


def test_set_rate_changes_the_sample_spacing_and_refuses_bad_rates() -> None:
    device = SimDevice(seed=1, rate_hz=200)
    first = device.produce(0.1)  # samples 0..20 at 5 ms
    assert len(first) == 21
    (ack,) = answers(device, encode_set_rate(1000))
    assert parse_ack(ack.payload) == native.Ack(native.SET_RATE, native.ACK_OK)
    after = device.produce(0.2)
    t = np.concatenate([first["t_us"], after["t_us"]]).astype(np.int64)
    assert np.all(np.diff(first["t_us"].astype(np.int64)) == 5000)
    assert t[21] == 105_000  # the next sample keeps its due time, then 1 ms spacing
    assert np.all(np.diff(after["t_us"].astype(np.int64)) == 1000)
    assert after["t_us"][-1] == 200_000
    np.testing.assert_array_equal(np.diff(np.concatenate([first["seq"], after["seq"]]).astype(int)), 1)
    assert json.loads(answers(device, encode_frame(native.GET_INFO))[0].payload)["rate_hz"] == 1000
    for bad in (encode_frame(native.SET_RATE, struct.pack("<H", 0)), encode_set_rate(60000),
                encode_frame(native.SET_RATE, b"\x10")):
        (ack,) = answers(device, bad)
        assert parse_ack(ack.payload) == native.Ack(native.SET_RATE, native.ACK_BAD_ARGUMENT)
    assert device.rate_hz == 1000


def test_stop_and_start_stream() -> None:
    device = SimDevice(seed=2, rate_hz=100)
    assert len(device.produce(0.5)) == 51  # streams from power-up
    (ack,) = answers(device, encode_frame(native.STOP_STREAM))
    assert parse_ack(ack.payload).ok and ack.payload[0] == native.STOP_STREAM
    assert len(device.produce(1.0)) == 0
    answers(device, encode_frame(native.START_STREAM))
    resumed = device.produce(1.5)
    assert resumed["seq"][0] == 51  # no sample was lost: none was made for the host
    assert resumed["t_us"][0] == 1_010_000  # the device clock went on
    assert len(resumed) == 50


def test_unknown_commands_get_ack_status_1_and_split_commands_work() -> None:
    device = SimDevice()
    stream = encode_frame(0x7E) + encode_frame(native.GET_INFO) + b"\x00\x13garbage"
    got = []
    for i in range(len(stream)):  # one byte at a time
        got += NativeDecoder().feed(device.feed(stream[i : i + 1])).messages
    assert [m.msg_id for m in got] == [native.ACK, native.DEVICE_INFO]
    assert parse_ack(got[0].payload) == native.Ack(0x7E, native.ACK_UNKNOWN)
    assert device.commands == {"0x7e": 1, "GET_INFO": 1}


def test_samples_fall_due_on_an_absolute_schedule() -> None:
    device = SimDevice(rate_hz=300)
    counts = [len(device.produce(t)) for t in np.arange(0.0, 2.0, 0.0137)]
    total = sum(counts) + len(device.produce(2.0))
    assert total == 601  # samples 0..600 at k / 300 s, however the calls fall
    assert device.next_due_s() == pytest.approx(601 / 300)


def test_device_bytes_equal_simulate_for_the_same_seed() -> None:
    truth = UnitTruth.random(8)
    segments = [Static("+z", 1.0), Move(1.0), Static("-x", 1.0), Rotation("+y", 90.0, settle_s=0.2)]
    rec = simulate(truth, segments, rate_hz=200, seed=8)
    device = SimDevice(truth, seed=8, rate_hz=200, scenario=segments)
    rng = np.random.default_rng(0)
    out = bytearray()
    t = 0.0
    while len(out) < len(rec) * native.SAMPLE_FRAME_SIZE:
        t += rng.uniform(0.0, 0.2)
        out += device.encode_samples(device.produce(t))
    n = len(rec)
    assert bytes(out[: n * native.SAMPLE_FRAME_SIZE]) == encode_samples(rec.samples())


def test_set_pose_moves_the_unit() -> None:
    device = SimDevice(UnitTruth.ideal(), rate_hz=100)
    np.testing.assert_allclose(device.produce(1.0)["acc"][-1], [0, 0, G], atol=1e-5)
    end = device.set_pose("-x", move_s=1.5)
    assert end == pytest.approx(1.01 + 1.5 + 1.0)
    during = device.produce(2.0)
    assert np.linalg.norm(during["gyro"], axis=1).max() > 0.5  # it turned
    later = device.produce(4.0)
    np.testing.assert_allclose(later["acc"][-1], [-G, 0, 0], atol=1e-5)
    np.testing.assert_allclose(later["gyro"][-1], 0.0, atol=1e-7)
    device.rotate("+x", 90.0, rate_dps=90.0, settle_s=0.2)
    turned = device.produce(8.0)
    angle = np.degrees(turned["gyro"][:, 0].astype(float).sum() / 100)
    assert angle == pytest.approx(90.0, abs=0.01)


def test_looped_scenario_repeats_without_jumps() -> None:
    segments = [Static("+z", 1.0), Static("+x", 1.0)]
    device = SimDevice(UnitTruth.ideal(), rate_hz=50, scenario=segments, loop=True)
    assert device.timeline.duration_s == pytest.approx(4.0)  # +z, implicit move, +x
    samples = device.produce(17.0)  # then each loop: move back to +z (2 s), +z, move, +x
    acc = samples["acc"].astype(float)
    assert np.linalg.norm(np.diff(acc, axis=0), axis=1).max() < 1.0  # continuous through the loops
    up_z = np.isclose(acc[:, 2], G, atol=1e-4)
    starts = np.flatnonzero(up_z[1:] & ~up_z[:-1]) + 1
    np.testing.assert_allclose(starts / 50, [6.0, 12.0], atol=0.2)  # came back to +z each loop


def test_still_scenario_and_named_scenarios() -> None:
    device = SimDevice(UnitTruth.ideal(), scenario="still")
    s = device.produce(100.0)
    np.testing.assert_allclose(s["acc"], np.broadcast_to([0, 0, G], s["acc"].shape), atol=1e-5)
    device.produce(101.0)
    assert len(device.timeline.pieces) == 1  # pieces left behind are pruned as it runs
    for name in ("six-position", "twelve-position", "six-position-static", "handheld"):
        assert len(SimDevice(seed=1, scenario=name).produce(3.0)) == 601
    with pytest.raises(ValueError, match="unknown scenario"):
        SimDevice(scenario="tumbling")
    with pytest.raises(ValueError, match="unknown encoder"):
        SimDevice(encoder="morse")
    with pytest.raises(ValueError, match="rate"):
        SimDevice(rate_hz=0)


def test_encoders_are_pluggable() -> None:
    assert ENCODERS["native"] is native.encode_samples
    ENCODERS["test-hex"] = lambda samples: samples.tobytes().hex().encode()
    try:
        device = SimDevice(seed=3, encoder="test-hex")
        s = device.produce(0.02)
        assert bytes.fromhex(device.encode_samples(s).decode()) == s.tobytes()
    finally:
        del ENCODERS["test-hex"]
