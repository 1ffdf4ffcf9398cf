"""MAVLink IMU telemetry: unit conversions of every IMU message, agreement with pymavlink's own
parser, source selection, and resynchronisation after damage (skips without pymavlink)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("pymavlink", reason="pymavlink is not installed (pip install 'imu-station[mavlink]')")

import decode_helpers  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402

from protocols.base import SAMPLE_DTYPE  # noqa: E402
from protocols.mavlink import IMU_MESSAGES, MILLI_G, MavlinkDecoder, encode_samples  # noqa: E402


def feed_ragged(decoder, data: bytes, seed: int = 0, max_chunk: int = 53):
    return decode_helpers.feed_ragged(decoder, data, seed, max_chunk)


def make_samples(n: int, seed: int = 0, t0_us: int = 1_000_000) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = t0_us + np.arange(n) * 20_000  # 50 Hz telemetry
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 30 + rng.normal(0, 0.5, n)
    return s


def test_conversions_of_a_hand_built_scaled_imu() -> None:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = mav.scaled_imu_encode(123_456, 1000, -2000, 0, 1000, -500, 0, 0, 0, 0, 2534).pack(mav)
    dec = MavlinkDecoder()
    out = dec.feed(frame).samples
    np.testing.assert_allclose(out["acc"][0], [9.80665, -19.6133, 0], rtol=1e-6)
    np.testing.assert_allclose(out["gyro"][0], [1.0, -0.5, 0], rtol=1e-6)
    assert out["temp"][0] == pytest.approx(25.34) and out["t_us"][0] == 123_456_000
    zero_temp = mav.scaled_imu_encode(123_476, 0, 0, 1000, 0, 0, 0, 0, 0, 0, 0).pack(mav)
    assert math.isnan(dec.feed(zero_temp).samples["temp"][0])  # 0 cdegC: "no temperature"


@pytest.mark.parametrize("message", IMU_MESSAGES)
@pytest.mark.parametrize("mavlink1", [False, True])
def test_every_imu_message_round_trips_with_its_units(message: str, mavlink1: bool) -> None:
    s = make_samples(60, seed=1)
    dec = MavlinkDecoder()
    data = encode_samples(s, message, mavlink1=mavlink1, heartbeat_every=10)
    out, messages = feed_ragged(dec, data, seed=2)
    assert dec.stats.errors == 0 and dec.stats.garbage_bytes == 0 and len(out) == 60
    assert len(messages) == 6 and dec.messages_seen["HEARTBEAT"] == 6
    assert out["seq"].tolist() == list(range(60))
    if message == "HIGHRES_IMU":
        np.testing.assert_allclose(out["acc"], s["acc"], rtol=1e-7)
        np.testing.assert_allclose(out["gyro"], s["gyro"], rtol=1e-7)
        assert (out["t_us"] == s["t_us"]).all()
    else:
        np.testing.assert_allclose(out["acc"], s["acc"], atol=MILLI_G / 2 + 1e-6)
        np.testing.assert_allclose(out["gyro"], s["gyro"], atol=0.5e-3 + 1e-7)
        if message == "RAW_IMU":
            assert (out["t_us"] == s["t_us"]).all()
        else:
            assert (out["t_us"] == s["t_us"] // 1000 * 1000).all()
    # (pymavlink's MAVLink 1 frames carry the extension fields too, temperature among them)
    np.testing.assert_allclose(out["temp"], s["temp"], atol=0.006)


def test_agrees_with_pymavlinks_own_parser() -> None:
    data = encode_samples(make_samples(80, seed=3), "SCALED_IMU2", heartbeat_every=7)
    reference = mavlink.MAVLink(None)
    msgs = [m for m in reference.parse_buffer(data) if m.get_type() == "SCALED_IMU2"]
    out, _ = feed_ragged(MavlinkDecoder(), data, seed=4)
    assert len(msgs) == len(out) == 80
    acc = np.array([[m.xacc, m.yacc, m.zacc] for m in msgs]) * 9.80665e-3
    gyro = np.array([[m.xgyro, m.ygyro, m.zgyro] for m in msgs]) * 1e-3
    np.testing.assert_allclose(out["acc"], acc, rtol=1e-6)
    np.testing.assert_allclose(out["gyro"], gyro, rtol=1e-6)
    assert out["t_us"].tolist() == [m.time_boot_ms * 1000 for m in msgs]


def test_one_source_makes_the_samples_and_the_others_are_listed() -> None:
    s = make_samples(20, seed=5)
    raw = encode_samples(s, "RAW_IMU", system=1)
    imu2 = encode_samples(s, "SCALED_IMU2", system=1)
    other = encode_samples(s, "HIGHRES_IMU", system=2)
    split = [len(encode_samples(s[:1], m)) for m in ("RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU")]
    stream = b"".join(raw[i * split[0] : (i + 1) * split[0]] + imu2[i * split[1] : (i + 1) * split[1]]
                      + other[i * split[2] : (i + 1) * split[2]] for i in range(20))
    dec = MavlinkDecoder()
    out, messages = feed_ragged(dec, stream, seed=6)
    assert len(out) == 20 and len(messages) == 40
    assert dec.sources_seen == {"RAW_IMU 1/1 id 0": 20, "SCALED_IMU2 1/1 id 0": 20,
                                "HIGHRES_IMU 2/1 id 0": 20}
    chosen = MavlinkDecoder(source="HIGHRES_IMU")
    out, _ = feed_ragged(chosen, stream, seed=7)
    np.testing.assert_allclose(out["acc"], s["acc"], rtol=1e-7)
    with pytest.raises(ValueError, match="unknown MAVLink IMU message"):
        MavlinkDecoder(source="ATTITUDE")


def test_time_boot_ms_unwraps() -> None:
    s = make_samples(30, seed=8, t0_us=(2**32 - 300) * 1000)
    out, _ = feed_ragged(MavlinkDecoder(), encode_samples(s, "SCALED_IMU3"), seed=9)
    assert (np.diff(out["t_us"].astype(np.int64)) == 20_000).all()


def test_signed_frames_decode() -> None:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = bytes(32)
    mav.signing.link_id = 0
    mav.signing.sign_outgoing = True
    frame = mav.highres_imu_encode(5, 0, 0, 9.8, 0, 0, 0.1, 0, 0, 0, 0, 0, 0, 25.0, 0x1FFF).pack(mav)
    assert frame[2] & 1 and len(frame) == 12 + 13 + frame[1]
    dec = MavlinkDecoder()
    out = dec.feed(frame + frame)
    assert len(out.samples) == 2 and dec.stats.errors == 0


def test_damage_is_counted_and_good_frames_after_it_survive() -> None:
    s = make_samples(7, seed=10)
    frames = [encode_samples(s[i : i + 1], "SCALED_IMU") for i in range(7)]
    bad_crc = bytearray(frames[1])
    bad_crc[12] ^= 0x40
    bad_flags = b"\xfd\x10\x80\x00\x00"  # an incompatibility flag nobody knows: not a frame start
    unknown = bytes([0xFD, 3, 0, 0, 9, 1, 1, 0x55, 0xAA, 0x7F, 1, 2, 3, 0, 0])  # id 0x7FAA55
    stream = (b"\x00\xfe\x01" + frames[0] + bytes(bad_crc) + frames[2][:15] + frames[3] + bad_flags
              + frames[4] + unknown + frames[5] + b"\xfe\x20\x00" + frames[6] + frames[6][:9])
    dec = MavlinkDecoder()
    out, messages = feed_ragged(dec, stream, seed=11, max_chunk=9)
    assert out["seq"].tolist() == [0, 1, 2, 3, 4]
    np.testing.assert_allclose(out["acc"], s["acc"][[0, 3, 4, 5, 6]], atol=MILLI_G)
    st_ = dec.stats
    # The damaged frames may hold more false starts than the ones placed here: at least these.
    assert st_.crc_errors >= 1 and st_.truncated >= 3 and st_.unknown_ids == 1 and st_.resyncs >= 5
    assert [m.msg_id for m in messages] == [0x7FAA55]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.binary(max_size=40).map(lambda b: b.replace(b"\x01", b"\xfd").replace(b"\x02", b"\xfe")),
                min_size=1, max_size=8), st.integers(0, 2**32 - 1))
def test_random_garbage_with_false_starts_never_loses_a_good_frame(garbage: list[bytes], seed: int) -> None:
    s = make_samples(len(garbage), seed=seed % 1000)
    frames = [encode_samples(s[i : i + 1], "HIGHRES_IMU") for i in range(len(s))]
    dec = MavlinkDecoder()
    out, _ = feed_ragged(dec, b"".join(g + f for g, f in zip(garbage, frames, strict=True)), seed=seed)
    np.testing.assert_array_equal(out["acc"], s["acc"])


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=500), st.integers(0, 2**32 - 1))
def test_arbitrary_bytes_never_raise(data: bytes, seed: int) -> None:
    dec = MavlinkDecoder()
    out, _ = feed_ragged(dec, data.replace(b"\x01", b"\xfd"), seed=seed)
    assert dec.stats.samples == len(out) <= dec.stats.frames
