"""Xsens Xbus / MTData2: real captures against their golden decodes, every precision and flag,
deltas, counters that wrap, and resynchronisation after any damage."""

from __future__ import annotations

import struct
from pathlib import Path

import decode_helpers
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.base import SAMPLE_DTYPE
from protocols.xsens import (
    ACCELERATION,
    MAX_PAYLOAD,
    MID_MTDATA2,
    PACKET_COUNTER,
    RATE_OF_TURN,
    SAMPLE_TIME_FINE,
    XsensDecoder,
    _decode_values,
    _encode_values,
    encode_frame,
    encode_item,
    encode_samples,
)

GOLDEN_FOLDERS = ["1", "2", "3"]


def feed_ragged(decoder, data: bytes, seed: int = 0, max_chunk: int = 97) -> np.ndarray:
    """Feed ``data`` in random chunks of 1..max_chunk bytes; all samples, flushed at the end."""
    return decode_helpers.feed_ragged(decoder, data, seed, max_chunk)[0]


def read_golden(path: Path) -> list[dict[str, list[str]]]:
    """The golden decode: blank-line separated blocks of ``Name:`` and indented value lines."""
    blocks = []
    for text in path.read_text().strip().split("\n\n"):
        block: dict[str, list[str]] = {}
        name = None
        for line in text.splitlines():
            if line.startswith(" "):
                block[name].append(line.strip())
            else:
                name = line.rstrip(":").split("(")[0]
                block[name] = []
        blocks.append(block)
    return blocks


def xyz(values: list[str]) -> list[float]:
    return [float(v.split(":")[1]) for v in values]


def make_samples(n: int, seed: int = 0, seq0: int = 0, t0_us: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n) + seq0
    s["t_us"] = t0_us + np.arange(n) * 2500  # 400 Hz, a whole number of 100 us ticks
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 30 + rng.normal(0, 0.1, n)
    return s


# ------------------------------------------------------------------ real captures, golden decodes


@pytest.mark.parametrize("folder", GOLDEN_FOLDERS)
def test_every_inertial_sample_of_the_golden_decode_comes_out(reference_data: Path, folder: str) -> None:
    base = reference_data / "xsens-mtdata2" / folder
    blocks = read_golden(base / "output.golden")
    dec = XsensDecoder()
    samples = feed_ragged(dec, (base / "output.bin").read_bytes(), seed=int(folder))
    inertial = [b for b in blocks if "Acceleration" in b or "RateOfTurn" in b]
    assert len(inertial) == 96 and len(samples) == len(inertial)
    assert dec.stats.errors == 0 and dec.stats.garbage_bytes == 0
    assert dec.stats.frames == len(blocks) and dec.stats.samples == len(inertial)
    acc = np.array([xyz(b["Acceleration"]) for b in inertial], dtype=np.float32)
    gyro = np.array([xyz(b["RateOfTurn"]) for b in inertial], dtype=np.float32)
    np.testing.assert_allclose(samples["acc"], acc, rtol=2e-7, atol=1e-9)
    np.testing.assert_allclose(samples["gyro"], gyro, rtol=2e-7, atol=1e-9)
    fine = np.array([int(b["SampleTimeFine"][0]) for b in inertial], dtype=np.uint64)
    assert (samples["t_us"] == fine * 100).all()
    assert samples["seq"].tolist() == [int(b["PacketCounter"][0]) for b in inertial]
    assert np.isnan(samples["temp"]).all()  # these captures carry no Temperature item


def test_folder_without_inertial_data_decodes_without_error(reference_data: Path) -> None:
    base = reference_data / "xsens-mtdata2" / "5"
    blocks = read_golden(base / "output.golden")
    dec = XsensDecoder()
    rng = np.random.default_rng(5)
    data = (base / "output.bin").read_bytes()
    messages, samples, pos = [], 0, 0
    while pos < len(data):
        n = int(rng.integers(1, 64))
        out = dec.feed(data[pos : pos + n])
        messages += out.messages
        samples += len(out.samples)
        pos += n
    dec.flush()
    assert samples == 0 and dec.stats.errors == 0 and dec.stats.garbage_bytes == 0
    assert len(messages) == len(blocks) == 100 and all(m.msg_id == MID_MTDATA2 for m in messages)
    assert dec.items_seen["Temperature(float32)"] == sum("Temperature" in b for b in blocks)


def _items(payload: bytes) -> list[tuple[int, bytes]]:
    """MTData2 items, read independently of the decoder (id u16 BE, size u8, data)."""
    items, pos = [], 0
    while pos < len(payload):
        data_id, size = struct.unpack_from(">HB", payload, pos)
        items.append((data_id, payload[pos + 3 : pos + 3 + size]))
        pos += 3 + size
    return items


def _frames(data: bytes) -> list[tuple[int, bytes]]:
    frames, pos = [], 0
    while pos < len(data):
        assert data[pos : pos + 2] == b"\xfa\xff"
        mid, length = data[pos + 2], data[pos + 3]
        header = 4
        if length == 0xFF:
            length, header = struct.unpack_from(">H", data, pos + 4)[0], 6
        frames.append((mid, data[pos + header : pos + header + length]))
        pos += header + length + 1
    return frames


@pytest.mark.parametrize("folder", GOLDEN_FOLDERS)
def test_deltas_alone_give_the_devices_acceleration_and_rate(reference_data: Path, folder: str) -> None:
    """DeltaV and DeltaQ, with Acceleration and RateOfTurn removed from the real packets, turn
    into the device's own Acceleration and RateOfTurn (the golden values) within 0.2 % and the
    quantization of the format."""
    base = reference_data / "xsens-mtdata2" / folder
    inertial = [b for b in read_golden(base / "output.golden") if "Acceleration" in b]
    stream = bytearray()
    for mid, payload in _frames((base / "output.bin").read_bytes()):
        kept = b"".join(encode_item(i, d) for i, d in _items(payload)
                        if i & 0xF8F0 not in (ACCELERATION, RATE_OF_TURN))
        stream += encode_frame(mid, kept)
    dec = XsensDecoder()
    samples = feed_ragged(dec, bytes(stream), seed=3)
    assert len(samples) == len(inertial) and dec.stats.errors == 0
    acc = np.array([xyz(b["Acceleration"]) for b in inertial])
    gyro = np.array([xyz(b["RateOfTurn"]) for b in inertial])
    np.testing.assert_allclose(samples["acc"], acc, rtol=2e-3, atol=2e-3)
    # fp1220 quantizes DeltaQ to 2^-20, i.e. the rate over 10 ms to 2 * 2^-20 / 0.01 = 1.9e-4 rad/s.
    gyro_atol = 5e-4 if folder == "2" else 2e-5
    np.testing.assert_allclose(samples["gyro"], gyro, rtol=2e-3, atol=gyro_atol)


# ------------------------------------------------------------------ precisions and flags


def test_fixed_point_formats_against_hand_computed_bytes() -> None:
    assert _decode_values(bytes.fromhex("00100000"), 1, 1) == (1.0,)
    assert _decode_values(bytes.fromhex("fff00000"), 1, 1) == (-1.0,)
    assert _decode_values(bytes.fromhex("00080000"), 1, 1) == (0.5,)
    # 16.32: -1.5 * 2^32 = 0x...FFFE_8000_0000 -> fraction 80000000, integer FFFE
    assert _decode_values(bytes.fromhex("80000000fffe"), 2, 1) == (-1.5,)
    assert _decode_values(bytes.fromhex("400000000003"), 2, 1) == (3.25,)
    assert _decode_values(bytes.fromhex("3ff8000000000000"), 3, 1) == (1.5,)
    assert _decode_values(bytes.fromhex("3fc00000"), 0, 1) == (1.5,)


@pytest.mark.parametrize("precision", ["float32", "fp1220", "fp1632", "float64"])
@pytest.mark.parametrize("coords", ["enu", "ned", "nwu"])
def test_every_precision_and_coordinate_flag_round_trips_in_sensor_frame(precision: str, coords: str) -> None:
    s = make_samples(40, seed=1)
    dec = XsensDecoder()
    out = feed_ragged(dec, encode_samples(s, precision=precision, coordinate_system=coords), seed=2)
    assert dec.stats.errors == 0 and len(out) == len(s)
    assert (out["seq"] == s["seq"]).all() and (out["t_us"] == s["t_us"]).all()
    tol = 2.0**-20 if precision == "fp1220" else 0.0
    for field in ("acc", "gyro", "temp"):
        np.testing.assert_allclose(out[field], s[field], rtol=1e-7, atol=tol)


@pytest.mark.parametrize("precision", ["float32", "fp1632", "float64"])
def test_delta_packets_give_the_rates_they_integrate(precision: str) -> None:
    s = make_samples(30, seed=4)
    dec = XsensDecoder()
    out = feed_ragged(dec, encode_samples(s, precision=precision, deltas=True), seed=5)
    assert len(out) == len(s) and dec.stats.errors == 0
    np.testing.assert_allclose(out["acc"], s["acc"], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(out["gyro"], s["gyro"], rtol=1e-4, atol=1e-4)


def test_counters_and_sample_time_unwrap() -> None:
    s = make_samples(50, seed=6, seq0=65_510, t0_us=(2**32 - 40) * 100)
    dec = XsensDecoder()
    out = feed_ragged(dec, encode_samples(s), seed=7)
    assert out["seq"].tolist() == list(range(65_510, 65_560))
    assert (np.diff(out["t_us"].astype(np.int64)) == 2500).all()
    assert int(out["t_us"][0]) == (2**32 - 40) * 100


def test_packet_without_time_or_counter_is_still_a_sample() -> None:
    payload = encode_item(ACCELERATION, struct.pack(">3f", 0, 0, 9.81))
    dec = XsensDecoder(nominal_rate_hz=50)
    out = dec.feed(encode_frame(MID_MTDATA2, payload) * 3).samples
    assert out["seq"].tolist() == [0, 1, 2] and out["t_us"].tolist() == [0, 20_000, 40_000]
    assert np.allclose(out["acc"][:, 2], 9.81) and np.isnan(out["gyro"]).all()


# ------------------------------------------------------------------ framing and damage


def test_extended_length_frame_and_checksum() -> None:
    payload = bytes(range(256)) * 2
    frame = encode_frame(0x42, payload)
    assert frame[:4] == b"\xfa\xff\x42\xff" and struct.unpack(">H", frame[4:6])[0] == 512
    assert sum(frame[1:]) % 256 == 0
    dec = XsensDecoder()
    out = dec.feed(frame)
    assert out.messages[0].payload == payload and dec.stats.errors == 0
    with pytest.raises(ValueError):
        encode_frame(0x36, bytes(MAX_PAYLOAD + 1))


def test_damage_is_counted_and_good_frames_after_it_survive() -> None:
    s = make_samples(6, seed=8)
    frames = [encode_samples(s[i : i + 1]) for i in range(6)]
    bad_sum = bytearray(frames[1])
    bad_sum[10] ^= 0xFF
    too_long = b"\xfa\xff\x36\xff\x10\x00"  # extended length 4096 > 2048
    item_overrun = encode_frame(MID_MTDATA2, encode_item(PACKET_COUNTER, b"\x00\x01")[:-1] + b"\x10\x60\x09")
    stream = (b"noise\xfa" + frames[0] + bytes(bad_sum) + too_long + frames[2] + frames[3][:20] + frames[4]
              + item_overrun + frames[5] + b"\xfa\xff\x36")
    dec = XsensDecoder()
    out = feed_ragged(dec, stream, seed=9, max_chunk=7)
    assert out["seq"].tolist() == [s["seq"][i] for i in (0, 2, 4, 5)]
    st_ = dec.stats
    assert st_.crc_errors == 1 and st_.length_errors == 1 and st_.truncated == 2 and st_.bad_payloads == 1
    assert st_.garbage_bytes > 0 and st_.resyncs > 0


def test_wrong_item_size_is_a_bad_payload() -> None:
    dec = XsensDecoder()
    out = dec.feed(encode_frame(MID_MTDATA2, encode_item(RATE_OF_TURN, bytes(10))))
    assert len(out) == 0 and dec.stats.bad_payloads == 1
    out = dec.feed(encode_frame(MID_MTDATA2, encode_item(SAMPLE_TIME_FINE, bytes(3))))
    assert dec.stats.bad_payloads == 2


def test_other_messages_are_returned_by_id() -> None:
    dec = XsensDecoder()
    out = dec.feed(encode_frame(0x3E) + encode_frame(0x01, b"\x03\x70\x12\x34") + encode_frame(0x99, b"x"))
    assert [m.msg_id for m in out.messages] == [0x3E, 0x01, 0x99]
    assert dec.stats.unknown_ids == 1 and dec.stats.errors == 0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.binary(max_size=40), min_size=1, max_size=8), st.integers(0, 2**32 - 1))
def test_random_garbage_between_frames_never_loses_a_good_frame(garbage: list[bytes], seed: int) -> None:
    # Garbage without false frame starts: with an 8-bit checksum, 1 false start in 256 passes it
    # and may swallow what follows. False starts that fail are covered by the damage test above.
    s = make_samples(len(garbage), seed=seed % 1000)
    stream = b"".join(g.replace(b"\xfa", b"") + encode_samples(s[i : i + 1]) for i, g in enumerate(garbage))
    dec = XsensDecoder()
    out = feed_ragged(dec, stream, seed=seed)
    assert out["seq"].tolist() == s["seq"].tolist()


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=600), st.integers(0, 2**32 - 1))
def test_arbitrary_bytes_never_raise(data: bytes, seed: int) -> None:
    dec = XsensDecoder()
    out = feed_ragged(dec, b"\xfa\xff" + data, seed=seed, max_chunk=50)
    assert dec.stats.samples == len(out) <= dec.stats.frames


_PRECISION_TYPES = {0x0810, 0x2010, 0x2020, 0x2030, 0x4010, 0x4020, 0x4030, 0x4040, 0x5020, 0x5030, 0x5040,
                    0x8020, 0x8030, 0x8040, 0xC020, 0xD010}


@pytest.mark.parametrize("precision", [3, 2])
def test_real_packets_in_float64_and_fp1632_with_extended_lengths(reference_data: Path,
                                                                  precision: int) -> None:
    """Folder 1's packets with every float32 item rewritten in float64 (or 16.32 fixed point), as an
    MTi configured so would send them, and a 120-byte GNSSSatInfo item added to every other one,
    which takes those past 254 bytes into the extended-length form."""
    base = reference_data / "xsens-mtdata2" / "1"
    inertial = [b for b in read_golden(base / "output.golden") if "Acceleration" in b]
    stream, extended = bytearray(), 0
    for k, (mid, payload) in enumerate(_frames((base / "output.bin").read_bytes())):
        items = []
        for data_id, data in _items(payload):
            if data_id & 0xF8F0 in _PRECISION_TYPES and data_id & 3 == 0:
                values = struct.unpack(f">{len(data) // 4}f", data)
                data = _encode_values(values, precision)
                data_id = (data_id & ~3) | precision
            items.append(encode_item(data_id, data))
        if k % 2:
            items.append(encode_item(0x7020, bytes(range(120))))
        frame = encode_frame(mid, b"".join(items))
        extended += frame[3] == 0xFF
        stream += frame
    assert extended > 0
    dec = XsensDecoder()
    samples = feed_ragged(dec, bytes(stream), seed=precision)
    assert len(samples) == len(inertial) and dec.stats.errors == 0
    acc = np.array([xyz(b["Acceleration"]) for b in inertial], dtype=np.float32)
    gyro = np.array([xyz(b["RateOfTurn"]) for b in inertial], dtype=np.float32)
    np.testing.assert_allclose(samples["acc"], acc, rtol=2e-7, atol=1e-9)
    np.testing.assert_allclose(samples["gyro"], gyro, rtol=2e-7, atol=1e-9)


def _hr_packet(counter: int, ticks: int, acc: tuple, gyro: tuple) -> bytes:
    return encode_frame(MID_MTDATA2, encode_item(PACKET_COUNTER, struct.pack(">H", counter))
                        + encode_item(SAMPLE_TIME_FINE, struct.pack(">I", ticks))
                        + encode_item(0x4040, struct.pack(">3f", *acc))
                        + encode_item(0x8040, struct.pack(">3f", *gyro)))


@pytest.mark.parametrize("source", [None, "hr"])
def test_high_rate_packets_and_normal_ones_never_mix(source: str | None) -> None:
    """An MTi-600 sends AccelerationHR/RateOfTurnHR packets at 1 kHz between its 100 Hz packets."""
    normal = make_samples(5, seed=11)
    normal["t_us"] = np.arange(5) * 10_000
    stream, counter, hr_acc, normal_seq, hr_seq = bytearray(), 0, [], [], []
    for i in range(5):
        one = normal[i : i + 1].copy()
        one["seq"] = counter
        normal_seq.append(counter)
        stream += encode_samples(one)
        counter += 1
        for k in range(10):
            acc = (float(i), float(k), 9.81)
            hr_acc.append(acc)
            hr_seq.append(counter)
            stream += _hr_packet(counter, i * 100 + k * 10 + 1, acc, (0.0, 0.0, 0.1))
            counter += 1
    dec = XsensDecoder(source=source)
    out = feed_ragged(dec, bytes(stream), seed=12)
    if source is None:  # the first inertial packet was a normal one
        assert dec.source == "normal" and len(out) == 5 and dec.other_source_packets == 50
        np.testing.assert_allclose(out["acc"], normal["acc"], rtol=1e-7)
        assert out["seq"].tolist() == normal_seq  # the packet counter: the other kind's packets are gaps
    else:
        assert len(out) == 50 and dec.other_source_packets == 5
        np.testing.assert_allclose(out["acc"], np.array(hr_acc, dtype=np.float32))
        assert (np.diff(out["t_us"].astype(np.int64))[:9] == 1000).all()
        assert out["seq"].tolist() == hr_seq


def test_frame_ending_in_the_preamble_byte_is_not_garbage_when_the_stream_is_cut_after_it() -> None:
    samples = make_samples(2000, seed=5)
    frames = [encode_samples(samples[i : i + 1]) for i in range(len(samples))]
    assert any(f.endswith(b"\xfa") for f in frames), "the stream must hold a frame whose checksum is 0xFA"
    dec = XsensDecoder()
    got = np.concatenate([dec.feed(f).samples for f in frames])
    assert len(got) == len(samples)
    assert dec.stats.garbage_bytes == 0 and dec.stats.resyncs == 0


def test_a_bad_checksum_then_a_frame_cut_after_its_first_preamble_byte_loses_nothing() -> None:
    # A false start (its checksum fails) and a good frame whose 0xFA ends the chunk: the 0xFA is kept
    # for the next chunk, not skipped with the false start (found by the fuzz test, seed 0).
    s = make_samples(2, seed=0)
    good = [encode_samples(s[i : i + 1]) for i in range(2)]
    false_start = b"\xfa\xff\x00\x00\x00\x00\x00\x00\x00"  # BID 0, MID 0, LEN 0, checksum 0 (not 1)
    stream = good[0] + false_start + good[1]
    cut = len(good[0]) + len(false_start) + 1
    dec = XsensDecoder()
    got = np.concatenate([dec.feed(stream[:cut]).samples, dec.feed(stream[cut:]).samples,
                          dec.flush().samples])
    assert got["seq"].tolist() == s["seq"].tolist()
    assert dec.stats.crc_errors == 1 and dec.stats.garbage_bytes == len(false_start)
