"""Several IMUs on one board, decoded: MAVLink SCALED_IMU/2/3 and HIGHRES_IMU ids as streams of their own,
a frame description whose fields give ``imu: k``, damage, and a single stream left as it was (skips the
MAVLink half without pymavlink)."""

from __future__ import annotations

import numpy as np
import pytest
from decode_helpers import feed_ragged

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE
from protocols.frame import FrameDecoder, encode_frames
from protocols.frame_description import FrameDescriptionError, describe
from protocols.instances import InstancesDecoded
from protocols.mag_batches import join_batches

pymavlink = pytest.importorskip("pymavlink", reason="pymavlink is not installed")

from protocols.mavlink import MILLI_G, MavlinkDecoder, encode_samples  # noqa: E402


def board_samples(n: int, count: int = 3, seed: int = 0, t0_us: int = 1_000_000) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        s = np.zeros(n, dtype=SAMPLE_DTYPE)
        s["seq"] = np.arange(n)
        s["t_us"] = t0_us + np.arange(n) * 20_000
        s["acc"] = rng.normal(0, 5, (n, 3)) + k
        s["gyro"] = rng.normal(0, 1, (n, 3))
        s["temp"] = 30 + k + rng.normal(0, 0.5, n)
        out.append(s)
    return out


def interleaved(instances: list[np.ndarray], messages: list[str], heartbeat: bool = True) -> bytes:
    frames = []
    for i in range(len(instances[0])):
        if heartbeat and i % 10 == 0:
            frames.append(encode_samples(instances[0][i : i + 1], "SCALED_IMU", heartbeat_every=1)[:21])
        for k, (s, message) in enumerate(zip(instances, messages, strict=True)):
            frames.append(encode_samples(s[i : i + 1], message, imu_id=k))
    return b"".join(frames)


Decodes = tuple[MavlinkDecoder, dict[int, np.ndarray]]


def decode_instances(data: bytes, seed: int = 1, max_chunk: int = 53,
                     cls: type[MavlinkDecoder] = MavlinkDecoder) -> Decodes:
    dec = cls()
    dec.decode_instances()
    rng = np.random.default_rng(seed)
    got: dict[int, list[np.ndarray]] = {}
    pos = 0
    outs = []
    while pos < len(data):
        n = int(rng.integers(1, max_chunk))
        outs.append(dec.feed(data[pos : pos + n]))
        pos += n
    outs.append(dec.flush())
    for out in outs:
        assert isinstance(out, InstancesDecoded)
        got.setdefault(0, []).append(out.samples)
        for k, batch in out.instances.items():
            got.setdefault(k, []).append(batch)
    return dec, {k: join_batches(b) for k, b in got.items()}


def assert_scaled_equal(got: np.ndarray, sent: np.ndarray) -> None:
    assert len(got) == len(sent)
    np.testing.assert_allclose(got["acc"], sent["acc"], atol=MILLI_G / 2 + 1e-6)
    np.testing.assert_allclose(got["gyro"], sent["gyro"], atol=0.5e-3 + 1e-7)
    np.testing.assert_allclose(got["temp"], sent["temp"], atol=0.006)
    assert got["t_us"].tolist() == (sent["t_us"] // 1000 * 1000).tolist()
    assert got["seq"].tolist() == list(range(len(sent)))


def test_scaled_imu_1_2_3_are_three_streams_of_their_own() -> None:
    sent = board_samples(120)
    data = interleaved(sent, ["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"])
    dec, got = decode_instances(data)
    assert sorted(got) == [0, 1, 2]
    for k in range(3):
        assert_scaled_equal(got[k], sent[k])
    assert dec.instances_seen == {0: 120, 1: 120, 2: 120} and dec.instance == 0
    assert dec.stats.errors == 0 and dec.stats.samples == 360 and dec.messages_seen["HEARTBEAT"] == 12


def test_highres_imu_ids_are_instances() -> None:
    sent = board_samples(60, seed=2)
    data = interleaved(sent, ["HIGHRES_IMU"] * 3, heartbeat=False)
    _, got = decode_instances(data, seed=3)
    for k in range(3):
        np.testing.assert_allclose(got[k]["acc"], sent[k]["acc"], rtol=1e-7)
        assert got[k]["t_us"].tolist() == sent[k]["t_us"].tolist()


def test_each_instance_unwraps_its_own_time_boot_ms_and_keeps_its_own_field() -> None:
    sent = board_samples(50, count=2, t0_us=(2**32 - 300) * 1000)  # wraps past 2^32 ms in the middle
    with_field = np.zeros(50, MAG_SAMPLE_DTYPE)
    for name in SAMPLE_DTYPE.names:
        with_field[name] = sent[1][name]
    with_field["mag"] = 25.0
    data = interleaved([sent[0], with_field], ["SCALED_IMU", "SCALED_IMU2"], heartbeat=False)
    _, got = decode_instances(data, seed=4)
    for k in range(2):
        assert (np.diff(got[k]["t_us"].astype(np.int64)) == 20_000).all()
    assert got[0].dtype == SAMPLE_DTYPE and got[1].dtype == MAG_SAMPLE_DTYPE
    np.testing.assert_allclose(got[1]["mag"], 25.0, atol=0.06)


def test_damage_costs_only_the_damaged_frames_of_each_instance() -> None:
    sent = board_samples(200, seed=5)
    data = bytearray(interleaved(sent, ["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"], heartbeat=False))
    size = [len(encode_samples(sent[k][:1], m)) for k, m in enumerate(["SCALED_IMU", "SCALED_IMU2",
                                                                        "SCALED_IMU3"])]
    step = sum(size)
    hit = {0: [10, 77], 1: [31], 2: [150, 151]}  # sample instants whose frame of that instance is flipped
    for k, instants in hit.items():
        for i in instants:
            data[i * step + sum(size[:k]) + 14] ^= 0x5A
    data[60 * step : 60 * step] = b"\xfd\x09garbage\xfe"
    dec, got = decode_instances(bytes(data), seed=6, max_chunk=200)
    for k in range(3):
        keep = np.setdiff1d(np.arange(200), hit[k])
        assert len(got[k]) == len(keep)
        np.testing.assert_allclose(got[k]["acc"], sent[k]["acc"][keep], atol=MILLI_G / 2 + 1e-6)
    # the five flipped frames, and the false starts in the garbage (counted, never costing a good frame)
    assert dec.stats.crc_errors >= 5 and dec.stats.garbage_bytes > 0


def test_another_board_and_a_second_message_of_an_instance_stay_messages() -> None:
    sent = board_samples(30, seed=7)
    mine = interleaved(sent, ["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"], heartbeat=False)
    raw0 = encode_samples(sent[0], "RAW_IMU")  # instance 0 again, in another message
    other = encode_samples(sent[1], "SCALED_IMU2", system=9)  # another board's
    dec = MavlinkDecoder()
    dec.decode_instances()
    out = dec.feed(mine + raw0 + other)
    assert len(out.samples) == 30 and {k: len(b) for k, b in out.instances.items()} == {1: 30, 2: 30}
    assert len(out.messages) == 60
    assert dec.instances_seen == {0: 30, 1: 30, 2: 30}


def test_without_decode_instances_one_stream_as_before_and_the_others_are_seen() -> None:
    sent = board_samples(40, seed=8)
    data = interleaved(sent, ["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"], heartbeat=False)
    dec = MavlinkDecoder()
    out, messages = feed_ragged(dec, data, 9, 53)
    assert type(dec.feed(b"")) is not InstancesDecoded
    assert_scaled_equal(out, sent[0])
    assert len(messages) == 80 and dec.instance == 0 and dec.instances_seen == {0: 40, 1: 40, 2: 40}


def test_a_message_source_and_instances_exclude_each_other() -> None:
    dec = MavlinkDecoder(source="SCALED_IMU2")
    with pytest.raises(ValueError, match="picks one IMU message"):
        dec.decode_instances()


# ------------------------------------------------------------------------------------- frame description


def board_description(**extra_field: object) -> dict:
    fields = [{"name": "seq", "at": 2, "type": "u16"}, {"name": "t", "at": 4, "type": "u32", "scale": 1e-6}]
    at = 8
    for k in range(3):
        for name in ("ax", "ay", "az", "gx", "gy", "gz", "temp"):
            field: dict = {"name": name, "at": at, "type": "i16", "scale": 0.01 if name != "temp" else 0.01}
            if k:
                field["imu"] = k
            fields.append(field)
            at += 2
    fields[-1].update(extra_field)
    return {"schema": "imu-station/frame/1", "name": "tri-imu", "sync": [0xAA, 0x55], "length": at + 2,
            "checksum": {"type": "crc16-ccitt-false"}, "fields": fields}


def frame_values(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    values = {"seq": np.arange(n, dtype=float), "t": 1.0 + np.arange(n) * 0.005}
    for k in range(3):
        tag = "" if k == 0 else f".imu{k}"
        for name in ("ax", "ay", "az", "gx", "gy", "gz"):
            values[name + tag] = np.round(rng.normal(0, 3, n), 2) + k
        values["temp" + tag] = np.round(25 + k + rng.normal(0, 1, n), 2)
    return values


def test_a_frame_of_three_imus_decodes_into_three_instances() -> None:
    desc = describe(board_description())
    assert desc.instances == (0, 1, 2) and desc.field("ax", 2).imu == 2  # type: ignore[union-attr]
    values = frame_values(300)
    data = bytearray(encode_frames(desc, values))
    data[100 * desc.length + 9] ^= 0xFF  # one damaged frame: every instance loses that sample
    dec = FrameDecoder(desc)
    dec.decode_instances()
    outs = [dec.feed(bytes(data[i : i + 97])) for i in range(0, len(data), 97)] + [dec.flush()]
    got = {0: join_batches([o.samples for o in outs])}
    for k in (1, 2):
        got[k] = join_batches([o.instances[k] for o in outs if k in o.instances])  # type: ignore[attr-defined]
    keep = np.setdiff1d(np.arange(300), [100])
    for k in range(3):
        tag = "" if k == 0 else f".imu{k}"
        assert len(got[k]) == 299
        np.testing.assert_allclose(got[k]["acc"][:, 0], values["ax" + tag][keep], atol=1e-5)
        np.testing.assert_allclose(got[k]["gyro"][:, 2], values["gz" + tag][keep], atol=1e-5)
        np.testing.assert_allclose(got[k]["temp"], values["temp" + tag][keep], atol=1e-4)
        assert got[k]["t_us"].tolist() == got[0]["t_us"].tolist()
    assert dec.stats.crc_errors == 1 and dec.instances_seen == {0: 299, 1: 299, 2: 299}


def test_without_decode_instances_a_frame_of_three_imus_gives_instance_0_as_a_frame_of_one() -> None:
    desc = describe(board_description())
    values = frame_values(50, seed=1)
    out = FrameDecoder(desc).feed(encode_frames(desc, values))
    assert type(out) is not InstancesDecoded and len(out.samples) == 50
    np.testing.assert_allclose(out.samples["acc"][:, 1], values["ay"], atol=1e-5)


@pytest.mark.parametrize(("change", "words"), [
    (lambda d: d["fields"][0].update(imu=1), r"key 'fields\[0\].imu' \(field seq\): seq is the board's"),
    (lambda d: d["fields"][-1].update(imu=99),
     r"key 'fields\[22\].imu' \(field temp\): 99: give an integer 0..15"),
    (lambda d: d["fields"][-1].update(imu="two"), r"fields\[22\].imu' \(field temp\)"),
    (lambda d: d["fields"].pop(16), r"missing required field\(s\) ax of imu 2"),
    (lambda d: d["fields"][16].update(name="ay"),
     r"key 'fields\[17\].name' \(field ay\): given twice for imu 2"),
])
def test_a_wrong_imu_index_is_refused_naming_the_field(change, words: str) -> None:
    doc = board_description()
    change(doc)
    with pytest.raises(FrameDescriptionError, match=words):
        describe(doc)


def test_interleaved_instances_decode_alike_with_and_without_the_fast_path() -> None:
    from test_mavlink_fast import PerFrameDecoder, assert_same, damaged

    sent = board_samples(300, seed=10)
    for messages in (["SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3"], ["HIGHRES_IMU"] * 3):
        data = interleaved(sent, messages)
        assert_same(data, chunks=(7, 64, 4096))  # one stream, the others as messages
        assert_same(damaged(data, 11), chunks=(61, 4096))
        for stream in (data, damaged(data, 12)):
            fast, fast_samples = decode_instances(stream, seed=13)
            slow, slow_samples = decode_instances(stream, seed=13, cls=PerFrameDecoder)
            assert fast.stats.as_dict() == slow.stats.as_dict() and fast_samples.keys() == slow_samples.keys()
            for k, samples in fast_samples.items():
                assert samples.tobytes() == slow_samples[k].tobytes()
