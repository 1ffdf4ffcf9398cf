"""The decoder faults of the reliability audit (issue 22), each as it was met, and its siblings:
an Xsens time stepping back killed the reader thread, cut Xsens headers swallowed good frames,
over-long numbers broke the text decoder, a replayed MAVLink frame threw the clock 49.7 days
ahead, ``auto`` never decided on a damaged link, and the link rate froze after a wild time."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from device_helpers import read_samples
from fuzz_cases import CASES, feed_chunks, lost_frames, make_samples
from test_drivers_serial import RawPty

from drivers import open_device
from drivers.link_stats import LinkMonitor
from mocks.device import SimDevice
from mocks.encoders_extra import EXTRA_ENCODERS  # noqa: F401  (registers the encoders)
from mocks.faults import FaultInjector, FaultSpec
from mocks.pty_server import PtyServer
from protocols import ascii_lines, mavlink, native, xsens
from protocols.ascii_lines import AsciiDecoder
from protocols.base import SAMPLE_DTYPE
from protocols.detect import AutoDecoder
from station.acquisition.capture import read_capture
from station.cli import main


def xsens_packet(counter: int, ticks: int) -> bytes:
    """An MTData2 packet as an MTi sends it; ``ticks`` (SampleTimeFine) is taken modulo 2^32."""
    return xsens.encode_frame(xsens.MID_MTDATA2,
                              xsens.encode_item(xsens.PACKET_COUNTER, struct.pack(">H", counter))
                              + xsens.encode_item(xsens.SAMPLE_TIME_FINE, struct.pack(">I", ticks % 2**32))
                              + xsens.encode_item(xsens.ACCELERATION, struct.pack(">3f", 0.0, 0.0, 9.81))
                              + xsens.encode_item(xsens.RATE_OF_TURN, struct.pack(">3f", 0.0, 0.0, 0.1)))


# ------------------------------------------------------------------ Xsens: time stepping back


def test_xsens_sample_dated_before_the_first_is_a_bad_payload_not_an_overflow() -> None:
    dec = xsens.XsensDecoder()
    stream = (xsens_packet(0, 100) + xsens_packet(1, 100 - 250) + xsens_packet(2, 101)
              + xsens_packet(3, 2**31 + 101))
    out = dec.feed(stream).samples  # raised OverflowError: -15000 us does not fit t_us
    assert out["seq"].tolist() == [0, 2] and out["t_us"].tolist() == [10_000, 10_100]
    assert dec.stats.bad_payloads == 2 and dec.stats.frames == 2  # 2^31 back from 101 is before zero too


def test_xsens_clock_wraps_forward_and_a_gnss_dated_packet_does_not_move_it() -> None:
    """SampleTimeFine wraps after 4.97 days; a GNSS packet carries the older time of its fix."""
    gnss = xsens.encode_frame(xsens.MID_MTDATA2,
                              xsens.encode_item(xsens.SAMPLE_TIME_FINE, struct.pack(">I", 2**32 - 4000))
                              + xsens.encode_item(0x7010, bytes(94)))
    dec = xsens.XsensDecoder()
    out = dec.feed(xsens_packet(0, 2**32 - 10) + gnss + xsens_packet(1, 5)).samples
    assert out["t_us"].tolist() == [(2**32 - 10) * 100, (2**32 + 5) * 100]
    assert dec.stats.bad_payloads == 0 and dec.stats.frames == 3


def test_the_reader_thread_survives_an_xsens_packet_dated_before_the_first() -> None:
    """The driver's reader thread died on the OverflowError and the capture stopped."""
    pty = RawPty()
    try:
        with open_device(pty.path, protocol="xsens") as dev:
            pty.write(xsens_packet(0, 1000) + xsens_packet(1, -5))  # 0.5 ms before the clock's zero
            first = read_samples(dev, 1, 2.0)
            pty.write(b"".join(xsens_packet(k, 1000 + k) for k in range(2, 50)))
            rest = read_samples(dev, 48, 3.0)
            stats = dev.stats
    finally:
        pty.close()
    assert len(first) == 1 and len(rest) == 48 and stats.bad_payloads == 1


# ------------------------------------------------------------------ Xsens: framing


def _xsens_case():
    return next(c for c in CASES if c.name == "xsens-float32")


def test_xsens_loses_no_intact_frame_through_the_fault_injector() -> None:
    """Before: 9 of 18,444 intact frames were lost behind cut frames whose checksum passed."""
    case = _xsens_case()
    good = case.frames(make_samples(20_000, seed=1))
    injector = FaultInjector(FaultSpec(garbage=0.05, garbage_max=40, bitflip=0.02, truncate=0.05, drop=0.01,
                                       seed=1), record=True)
    data = injector.apply(good).data
    intact = injector.intact_frames()
    cuts = list(range(4096, len(data), 4096))
    assert lost_frames(case, intact, feed_chunks(case.decoder(), data, cuts)) == []


def _cut_header_swallowing(frames: list[bytes], span_end: int) -> bytes:
    """A cut frame's start whose claimed length reaches ``span_end`` bytes into ``frames`` and whose
    checksum passes (its last cut byte is what the 1-in-256 chance would have had to make it)."""
    body = b"".join(frames)
    cut = bytearray(xsens_packet(7, 7)[:12])
    cut[3] = len(cut) + span_end - 5  # header 4 + payload + checksum 1 end span_end into the frames
    cut[-1] = (cut[-1] - sum(cut[1:]) - sum(body[:span_end])) & 0xFF
    return bytes(cut)


@pytest.mark.parametrize("reach", ["inside the second frame", "right to the third frame"])
def test_a_cut_header_whose_checksum_passes_swallows_no_good_frame(reach: str) -> None:
    frames = [xsens_packet(k, 100 + k) for k in range(4)]
    span_end = len(frames[0]) + 20 if reach == "inside the second frame" else len(frames[0]) + len(frames[1])
    false_start = _cut_header_swallowing(frames, span_end)
    dec = xsens.XsensDecoder()
    out = feed_chunks(dec, false_start + b"".join(frames), [7, 30, 61])
    assert out["seq"].tolist() == [0, 1, 2, 3]
    assert dec.stats.truncated == 1


def test_a_good_frame_holding_a_chance_frame_is_kept_even_before_garbage() -> None:
    """``FA FF E2 00 1F`` is a whole valid (empty) frame: inside a good packet's payload it must not
    make the packet a false start, whatever follows the packet."""
    chance = b"\xfa\xff\xe2\x00\x1f"
    assert not sum(chance[1:]) & 0xFF
    payload = xsens_packet(5, 500)[4:-1] + xsens.encode_item(0x7020, chance)
    good = xsens.encode_frame(xsens.MID_MTDATA2, payload)
    after = xsens_packet(9, 900)[:15]  # a cut frame: garbage after the good one
    stream = xsens_packet(4, 400) + good + after + xsens_packet(6, 600)
    for cuts in ([], [len(stream) - 20], list(range(3, len(stream), 5))):
        out = feed_chunks(xsens.XsensDecoder(), stream, cuts)
        assert out["seq"].tolist() == [4, 5, 6]


# ------------------------------------------------------------------ text lines: over-long numbers


def test_an_over_long_time_on_the_block_path_is_a_bad_payload_not_a_garbage_timestamp() -> None:
    dec = AsciiDecoder()
    dec.feed(b"0.1,0,0,9.8,0,0,0,25\n")  # past the first line: the vectorised block path is on
    lines = b"0.2,0,0,9.8,0,0,0,25\n" + b"9" * 300 + b",0,0,9.8,0,0,0,25\n0.3,0,0,9.8,0,0,0,25\n"
    out = dec.feed(lines).samples
    assert out["t_us"].tolist() == [200_000, 300_000] and dec.stats.bad_payloads == 1


@pytest.mark.parametrize("line", [
    b"9" * 300 + b",0,0,9.8,0,0,0,25",  # t: 1e300 s, past t_us's 64 bits
    b"Raw:" + b"9" * 320 + b",0,8192,0,0,0,0,0,0",  # a count past any float
    b"Raw:0,0,8192,0,0,0," + b"9" * 40 + b",0,0",  # even in an ignored field
])
def test_an_over_long_number_on_the_line_path_is_a_bad_payload(line: bytes) -> None:
    dec = AsciiDecoder(columns="t,ax,ay,az,gx,gy,gz,temp")
    out = dec.feed(b"junk line\n" + line + b"\n" + b"0.5,0,0,9.8,0,0,0,25\n")  # raised OverflowError
    assert len(out.samples) == 1 and dec.stats.bad_payloads == 1


def test_a_counter_past_64_bits_is_a_bad_payload() -> None:
    dec = AsciiDecoder(columns="seq,ax,ay,az,gx,gy,gz")
    out = dec.feed(b"x\n1,0,0,9.8,0,0,0\n" + b"9" * 25 + b",0,0,9.8,0,0,0\n2,0,0,9.8,0,0,0\n")
    assert out.samples["seq"].tolist() == [1, 2] and dec.stats.bad_payloads == 1


def test_a_vectornav_sentence_after_a_cut_line_or_noise_is_read() -> None:
    sentences = [ascii_lines.encode_vectornav(make_samples(3, seed=k)[k : k + 1]) for k in range(3)]
    stream = b"$VNYMR,+000.0" + sentences[0] + b"\x93\x00noise" + sentences[1] + sentences[2][:-2]
    dec = AsciiDecoder()
    out = feed_chunks(dec, stream, [5, 40])
    assert len(out) == 3 and dec.stats.resyncs == 2 and dec.stats.errors == 0


def test_a_motioncal_line_after_a_cut_line_is_read_and_a_banner_stays_text() -> None:
    lines = ascii_lines.encode_motioncal(make_samples(3)).split(b"\r\n")
    stream = lines[0][:9] + lines[1] + b"\r\n" + b"Output Raw: on\r\n" + lines[2] + b"\r\n"
    dec = AsciiDecoder()
    out = feed_chunks(dec, b"\r\n" + stream, [6, 30])
    assert len(out) == 2 and dec.kinds_seen == {"motioncal": 2, "text": 1}
    assert dec.stats.resyncs == 1 and dec.stats.errors == 0


# ------------------------------------------------------------------ MAVLink: a replayed frame


def test_a_replayed_scaled_imu_frame_steps_back_not_49_days_ahead() -> None:
    pytest.importorskip("pymavlink")
    s = np.zeros(5, dtype=SAMPLE_DTYPE)
    s["t_us"] = [1_000_000, 1_020_000, 1_000_000, 1_040_000, 1_000]  # the third is an older frame again
    s["acc"][:, 2] = 9.8
    dec = mavlink.MavlinkDecoder()
    out = dec.feed(mavlink.encode_samples(s, "SCALED_IMU")).samples
    assert out["t_us"].tolist() == [1_000_000, 1_020_000, 1_000_000, 1_040_000, 1_000]
    wrapped = s[:2].copy()
    wrapped["t_us"] = [(2**32 - 10) * 1000, 5 * 1000]  # a real wrap after 49.7 days still unwraps
    dec = mavlink.MavlinkDecoder()
    assert dec.feed(mavlink.encode_samples(wrapped, "SCALED_IMU")).samples["t_us"].tolist() == [
        (2**32 - 10) * 1000, (2**32 + 5) * 1000]


def test_a_scaled_imu_frame_before_the_first_is_a_bad_payload() -> None:
    pytest.importorskip("pymavlink")
    s = np.zeros(3, dtype=SAMPLE_DTYPE)
    s["t_us"] = [100_000, (2**32 - 50) * 1000, 120_000]  # 150 ms before the stream's zero
    dec = mavlink.MavlinkDecoder()
    out = dec.feed(mavlink.encode_samples(s, "SCALED_IMU")).samples
    assert out["t_us"].tolist() == [100_000, 120_000] and dec.stats.bad_payloads == 1


# ------------------------------------------------------------------ auto on a damaged link

HEAVY = FaultSpec(garbage=0.3, garbage_max=40, bitflip=0.4, truncate=0.3, seed=4)


@pytest.mark.parametrize("name", ["native", "xsens-float32"])
def test_auto_decides_on_a_heavily_damaged_link_and_loses_no_sample(name: str) -> None:
    """Before: more than a quarter of the frames damaged, it never decided and dropped every byte."""
    case = next(c for c in CASES if c.name == name)
    data = FaultInjector(HEAVY).apply(case.frames(make_samples(600, seed=2))).data
    cuts = list(range(97, len(data), 97))
    alone = case.decoder()
    expected = feed_chunks(alone, data, cuts)
    auto = AutoDecoder()
    got = feed_chunks(auto, data, cuts)
    assert auto.protocol == name.split("-")[0]
    assert alone.stats.errors > alone.stats.frames // 4  # the old rule's limit: damage beyond it
    assert got.tobytes() == expected.tobytes()
    explanation = auto.explain()
    assert "chosen on a damaged link" in explanation and "check the cable and the baud rate" in explanation
    assert "at about 200 Hz" in explanation  # from neighbours in seq: steps across losses read 67 Hz


def test_auto_that_cannot_decide_says_how_many_bytes_it_saw_and_what_to_try() -> None:
    rng = np.random.default_rng(5)
    good = native.encode_samples(make_samples(2))
    noise = rng.integers(0, 256, 6000, dtype=np.uint8).tobytes()
    auto = AutoDecoder()
    auto.feed(noise[:3000] + good + noise[3000:])
    text = auto.explain()
    assert auto.protocol is None and f"in {6000 + len(good)} bytes" in text
    assert "native: 2 good frames" in text and "--protocol NAME" in text and "baud rate" in text


def test_auto_at_the_end_of_a_short_stream_keeps_its_samples() -> None:
    auto = AutoDecoder()
    data = b"\x00\x13" + native.encode_samples(make_samples(2))
    assert len(auto.feed(data).samples) == 0
    assert len(auto.flush().samples) == 2 and auto.protocol == "native"


def test_capture_auto_records_a_heavily_damaged_xsens_unit(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mti.csv"
    faults = FaultSpec(garbage=0.3, garbage_max=40, bitflip=0.2, truncate=0.2, seed=6)
    with PtyServer(SimDevice(seed=2, rate_hz=200, encoder="xsens"), faults=faults) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "auto", "--duration", "1",
                     "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "protocol: xsens:" in err and "chosen on a damaged link" in err
    assert len(read_capture(out)) > 50


# ------------------------------------------------------------------ link statistics after a wild time


def test_the_link_rate_follows_the_unit_after_a_sample_an_hour_ahead() -> None:
    """The rate window kept the wild time as its start: it stopped sliding, and the rate became the
    average since the wild sample (382 Hz here, for a unit at 400 Hz)."""
    mon = LinkMonitor()
    slow = make_samples(600, rate_hz=200)
    slow["t_us"][549] += 3_600_000_000  # the last of a batch
    fast = make_samples(2000, rate_hz=400)
    fast["t_us"] += int(slow["t_us"][-1]) + 2500
    for batch in (slow, fast):
        for i in range(0, len(batch), 50):
            mon.add_samples(batch[i : i + 50])
    assert mon.stats.rate_hz == pytest.approx(400.0, rel=0.01)


def _seq_batch(seq: list[int]) -> np.ndarray:
    s = np.zeros(len(seq), dtype=SAMPLE_DTYPE)
    s["seq"] = seq
    s["t_us"] = np.arange(len(seq)) * 5000
    return s


@pytest.mark.parametrize("odd", [4_000_000_000, 1_000_000, 97])
def test_a_lone_wild_or_replayed_seq_is_an_outlier_not_lost_samples(odd: int) -> None:
    """Before: a wild seq counted a million lost samples (or, replayed, 3 phantom ones and a reset)."""
    mon = LinkMonitor()
    for part in ([98, 99, 100], [odd], [101, 102], [103, 105, odd, 106]):
        mon.add_samples(_seq_batch(part))
    assert mon.stats.lost == 1 and mon.stats.seq_resets == 0 and mon.stats.seq_outliers == 2
    assert "2 seq outliers" in mon.stats.summary()


def test_a_restart_and_a_long_gap_the_next_sample_confirms_still_count() -> None:
    mon = LinkMonitor()
    mon.add_samples(_seq_batch([10, 11, 5011, 5012]))  # 4,999 lost
    mon.add_samples(_seq_batch([0]))
    mon.add_samples(_seq_batch([1, 2]))  # the unit restarted its counter
    assert mon.stats.lost == 4999 and mon.stats.seq_resets == 1 and mon.stats.seq_outliers == 0
