"""The simulated unit served on a real pseudo-terminal and as a ``sim://`` URL, read with pyserial.

Each test streams for a second or two of wall clock; pacing is checked over about two seconds.
"""

from __future__ import annotations

import json
import os
import re
import time

import numpy as np
import pytest
import serial

import mocks
from mocks.device import SimDevice
from mocks.faults import FaultSpec
from mocks.pty_server import PtyServer
from mocks.rig import Static, simulate
from mocks.truth import UnitTruth
from protocols import native
from protocols.native import NativeDecoder, encode_frame, encode_set_rate, parse_ack

mocks.register_sim_url()


class Host:
    """A host on a pyserial port: decodes everything it reads, keeps samples and messages."""

    def __init__(self, port: serial.SerialBase):
        self.port = port
        self.decoder = NativeDecoder()
        self.samples: list[np.ndarray] = []
        self.messages: list[native.Message] = []

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._take(self.port.read(max(1, self.port.in_waiting)))

    def _take(self, data: bytes) -> None:
        d = self.decoder.feed(data)
        if len(d.samples):
            self.samples.append(d.samples)
        self.messages += d.messages

    def ask(self, frame: bytes, answer_id: int, timeout: float = 3.0) -> native.Message:
        """Send a command and read (keeping the samples) until its answer comes."""
        seen = len(self.messages)
        self.port.write(frame)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self._take(self.port.read(max(1, self.port.in_waiting)))
            for m in self.messages[seen:]:
                if m.msg_id == answer_id:
                    return m
        raise AssertionError(f"no answer 0x{answer_id:02x} within {timeout} s")

    def rate_over(self, seconds: float) -> float:
        """Samples per wall-clock second decoded while pumping for ``seconds``."""
        before = len(self.all_samples())
        t0 = time.monotonic()
        self.pump(seconds)
        elapsed = time.monotonic() - t0
        return (len(self.all_samples()) - before) / elapsed

    def all_samples(self) -> np.ndarray:
        """Samples decoded so far (a frame still arriving stays in the decoder)."""
        return np.concatenate(self.samples) if self.samples else np.zeros(0, dtype=native.SAMPLE_DTYPE)

    def end(self) -> np.ndarray:
        """The link is over: flush the decoder and return every sample."""
        tail = self.decoder.flush()
        if len(tail.samples):
            self.samples.append(tail.samples)
        return self.all_samples()


def still_recording(seed: int, n: int, rate_hz: float) -> np.ndarray:
    """What the unit of ``seed`` lying still sends, from simulate() (the pure-function path)."""
    rec = simulate(UnitTruth.random(seed), [Static("+z", n / rate_hz + 1.0)], rate_hz=rate_hz, seed=seed)
    return rec.samples()


# --- pty -------------------------------------------------------------------------------------------

def test_pty_answers_every_command_through_pyserial() -> None:
    with PtyServer(seed=3, rate_hz=200) as srv, serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        info = json.loads(host.ask(encode_frame(native.GET_INFO), native.DEVICE_INFO).payload)
        assert info["serial"] == "SIM-000003" and info["rate_hz"] == 200
        ack = parse_ack(host.ask(encode_set_rate(500), native.ACK).payload)
        assert ack == native.Ack(native.SET_RATE, native.ACK_OK)
        ack = parse_ack(host.ask(encode_frame(native.SET_RATE, b"\x00\x00"), native.ACK).payload)
        assert ack.status == native.ACK_BAD_ARGUMENT
        host.pump(0.3)
        spacing = np.diff(host.all_samples()["t_us"].astype(np.int64)[-20:])
        assert np.all(spacing == 2000)  # 500 Hz
        assert parse_ack(host.ask(encode_frame(native.STOP_STREAM), native.ACK).payload).ok
        host.samples.clear()
        host.pump(0.3)
        assert len(host.all_samples()) == 0
        assert parse_ack(host.ask(encode_frame(native.START_STREAM), native.ACK).payload).ok
        host.pump(0.2)
        assert len(host.all_samples()) > 50
        assert parse_ack(host.ask(encode_frame(0x55), native.ACK).payload).status == native.ACK_UNKNOWN
    assert srv.stats.commands == {"GET_INFO": 1, "SET_RATE": 2, "STOP_STREAM": 1, "START_STREAM": 1,
                                  "0x55": 1}


def test_pty_paces_samples_on_the_wall_clock_within_2_percent() -> None:
    with PtyServer(seed=1, rate_hz=400) as srv, serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        host.pump(0.3)
        rate = host.rate_over(2.0)
    # Blocks of 20 ms at each end bound the count error to ~16 samples of 800 (2 %).
    assert rate == pytest.approx(400.0, rel=0.02)
    samples = host.all_samples()
    assert np.all(np.diff(samples["seq"].astype(np.int64)) == 1)
    # The device clock and the wall clock agree: the last sample is not far behind the schedule.
    assert srv.stats.late_blocks <= 2


def test_pty_sends_the_same_bytes_as_simulate_for_the_same_seed() -> None:
    with PtyServer(seed=6, rate_hz=250) as srv, serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        host.pump(0.8)
    got = host.all_samples()
    assert len(got) > 100
    reference = still_recording(6, int(got["seq"][-1]) + 1, 250.0)
    # The host may have opened the port after power-up: compare by sequence number.
    np.testing.assert_array_equal(got, reference[got["seq"]])
    assert got.tobytes() == reference[got["seq"]].tobytes()


def test_pty_with_faults_delivers_exactly_the_intact_frames() -> None:
    faults = FaultSpec(garbage=0.03, bitflip=0.02, truncate=0.02, drop=0.02, stall=0.005, stall_s=0.1, seed=5)
    with PtyServer(seed=2, rate_hz=500, faults=faults, record=True) as srv, \
            serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        host.pump(1.5)
        # After STOP_STREAM's answer, every sample made before it has been written.
        assert parse_ack(host.ask(encode_frame(native.STOP_STREAM), native.ACK, timeout=5.0).payload).ok
        got = host.end()
        sent = srv.sent()
        intact = sent[srv.injector.intact_indices()]
    counts = srv.injector.counts
    assert counts.dropped and counts.truncated and counts.bitflips and counts.garbage_runs
    # The host opened the port after the first block at most: it gets every intact frame from there.
    first = np.searchsorted(intact["seq"], got["seq"][0])
    assert first <= 25
    np.testing.assert_array_equal(got, intact[first:])
    assert host.decoder.stats.errors > 0


def test_pty_survives_the_host_closing_and_reopening_the_port() -> None:
    with PtyServer(seed=4, rate_hz=200) as srv:
        with serial.Serial(srv.port_path, timeout=0.05) as port:
            first = Host(port)
            first.pump(0.4)
        time.sleep(0.3)  # nobody listens: the samples go nowhere, as on a UART
        with serial.Serial(srv.port_path, timeout=0.05) as port:
            second = Host(port)
            second.pump(0.4)
        assert srv.running
    a, b = first.all_samples(), second.all_samples()
    assert len(a) > 40 and len(b) > 40
    assert b["seq"][0] > a["seq"][-1] + 40  # the samples made while closed were not queued
    assert np.all(np.diff(b["seq"].astype(np.int64)) == 1)
    assert srv.stats.host_opens == 2 and srv.stats.samples_unheard > 40


def test_pty_disconnect_fault_makes_pyserial_raise_and_the_port_vanish(tmp_path) -> None:
    link = tmp_path / "imu"
    faults = FaultSpec(disconnect_after_s=0.6)
    with PtyServer(seed=1, rate_hz=200, faults=faults, link=link) as srv:
        assert os.readlink(link) == srv.port_path
        with serial.Serial(str(link), timeout=0.05) as port:
            host = Host(port)
            with pytest.raises(serial.SerialException):
                host.pump(5.0)
        assert srv.wait_closed(2.0)
        assert srv.stats.disconnected
        assert not os.path.exists(srv.port_path)
        assert not os.path.lexists(link)
    assert len(host.end()) > 50


def test_pty_serves_a_device_driven_live() -> None:
    device = SimDevice(UnitTruth.ideal(), rate_hz=200)
    with PtyServer(device) as srv, serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        host.pump(0.2)
        device.set_pose("-y", move_s=0.5)
        host.pump(1.0)
    acc = host.all_samples()["acc"]
    np.testing.assert_allclose(acc[0], [0, 0, 9.80665], atol=1e-5)
    np.testing.assert_allclose(acc[-1], [0, -9.80665, 0], atol=1e-5)


def test_pty_speed_keeps_the_device_rate_and_shrinks_the_wall_time() -> None:
    # x10: 200 Hz on the device clock is 2000 samples per wall second, timestamps still 5 ms apart.
    with PtyServer(seed=8, rate_hz=200, speed=10.0) as srv, \
            serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        host.pump(0.3)
        before = len(host.all_samples())
        t0 = time.monotonic()
        host.pump(1.5)
        wall = time.monotonic() - t0
        got = host.all_samples()
        info = json.loads(host.ask(encode_frame(native.GET_INFO), native.DEVICE_INFO).payload)
    assert info["rate_hz"] == 200  # the unit states its own rate, not the wall-clock one
    assert np.all(np.diff(got["t_us"].astype(np.int64)) == 5000)
    assert np.all(np.diff(got["seq"].astype(np.int64)) == 1)
    # 20 ms blocks at each end bound the count error to ~80 samples of 3000 (3 %).
    assert (len(got) - before) / wall == pytest.approx(2000.0, rel=0.04)
    assert srv.stats.rate_hz == pytest.approx(200.0, rel=0.01)
    assert srv.stats.device_time_s == pytest.approx(10.0 * srv.stats.elapsed_s)
    # The same bytes as at speed 1: speed changes when samples are sent, never what they are.
    np.testing.assert_array_equal(got, still_recording(8, int(got["seq"][-1]) + 1, 200.0)[got["seq"]])


def test_pty_speed_runs_the_disconnect_fault_on_the_device_clock() -> None:
    with PtyServer(seed=1, rate_hz=200, speed=20.0, faults=FaultSpec(disconnect_after_s=10.0)) as srv, \
            serial.Serial(srv.port_path, timeout=0.05) as port:
        host = Host(port)
        t0 = time.monotonic()
        with pytest.raises(serial.SerialException):
            host.pump(5.0)
        wall = time.monotonic() - t0
    assert wall < 1.5  # 10 s of device clock at x20
    assert 9.5 < host.end()["t_us"][-1] * 1e-6 <= 10.1


def test_simulate_speed_option(capsys) -> None:
    from station.cli import main

    assert main(["simulate", "--duration", "1", "--speed", "10", "--seed", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("speed x10")
    ran = next(line for line in lines if line.startswith("ran "))
    pattern = (r"ran ([0-9.]+) s \(([0-9.]+) s of device clock, x10\): ([0-9]+) samples "
               r"\(([0-9.]+)/s of device clock\)")
    wall, device, samples, rate = (float(x) for x in re.match(pattern, ran).groups())
    assert device == pytest.approx(10 * wall, abs=0.11) and samples == pytest.approx(200 * device, rel=0.02)
    assert rate == pytest.approx(200.0, rel=0.02)
    with pytest.raises(SystemExit) as refused:  # refused while the options are read
        main(["simulate", "--speed", "0"])
    assert refused.value.code == 4
    assert "--speed: 0 is outside the allowed range, above 0 up to 100" in capsys.readouterr().err
    with pytest.raises(ValueError, match="speed"):
        PtyServer(speed=-1.0)


# --- sim:// ---------------------------------------------------------------------------------------

def test_sim_url_answers_commands_and_paces_within_2_percent() -> None:
    with serial.serial_for_url("sim://?seed=3&rate=400", timeout=0.05) as port:
        host = Host(port)
        info = json.loads(host.ask(encode_frame(native.GET_INFO), native.DEVICE_INFO).payload)
        assert info == {"serial": "SIM-000003", "model": "imu-sim-mems", "firmware": "1.0.0", "rate_hz": 400}
        assert host.rate_over(2.0) == pytest.approx(400.0, rel=0.02)
        zero = encode_frame(native.SET_RATE, b"\x00\x00")
        assert parse_ack(host.ask(zero, native.ACK).payload).status == native.ACK_BAD_ARGUMENT
        assert port.device.rate_hz == 400
    samples = host.all_samples()
    np.testing.assert_array_equal(samples, still_recording(3, len(samples), 400.0)[: len(samples)])


def test_sim_url_read_timeouts() -> None:
    with serial.serial_for_url("sim://?rate=10", timeout=0.0) as port:
        assert len(port.read(10_000)) <= 2 * native.SAMPLE_FRAME_SIZE  # non-blocking: only what is due
        port.timeout = 0.35
        t0 = time.monotonic()
        data = port.read(10_000)
        assert 0.3 < time.monotonic() - t0 < 0.6
        assert len(data) % native.SAMPLE_FRAME_SIZE == 0 and len(data) >= 3 * native.SAMPLE_FRAME_SIZE
        port.timeout = None
        assert len(port.read(native.SAMPLE_FRAME_SIZE)) == native.SAMPLE_FRAME_SIZE  # blocks until there


def test_sim_url_faults_and_disconnect() -> None:
    url = ("sim://?seed=2&rate=500&record=1&faults=garbage=0.05,drop=0.02,bitflip=0.02"
           "&truncate=0.02&disconnect_s=1")
    with serial.serial_for_url(url, timeout=0.05) as port:
        host = Host(port)
        with pytest.raises(serial.SerialException, match="disconnected"):
            host.pump(5.0)
        with pytest.raises(serial.SerialException, match="disconnected"):
            port.write(encode_frame(native.GET_INFO))
        intact = port.sent()[port.injector.intact_indices()]
    np.testing.assert_array_equal(host.end(), intact)
    assert 400 < len(intact) < 500


def test_sim_url_stalls_delay_but_lose_nothing() -> None:
    url = "sim://?rate=200&stall=0.01&stall_s=0.3&fault_seed=4&record=1"
    with serial.serial_for_url(url, timeout=0.01) as port:
        host = Host(port)
        arrivals = []
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            data = port.read(4096)
            if data:
                arrivals.append(time.monotonic())
                host._take(data)
        assert port.injector.counts.stalls >= 1
        sent = port.sent()
    got = host.all_samples()
    assert max(np.diff(arrivals)) > 0.25  # the link went quiet for a stall
    np.testing.assert_array_equal(got, sent[: len(got)])  # then burst: nothing lost, nothing changed
    assert len(got) > 150


def test_sim_url_speed_runs_the_device_clock_faster() -> None:
    with serial.serial_for_url("sim://?rate=1000&speed=20&ideal=1", timeout=0.05) as port:
        host = Host(port)
        host.pump(0.5)
    samples = host.all_samples()
    assert samples["t_us"][-1] > 8_000_000  # ~10 s of device time in 0.5 s
    np.testing.assert_allclose(samples["acc"][-1], [0, 0, 9.80665], atol=1e-5)


def test_sim_url_refuses_bad_options() -> None:
    for url, message in (("sim://?speed=0", "speed"), ("sim://?scenario=spin", "unknown scenario"),
                         ("sim://?colour=red", "unknown option"), ("sim://?drop=2", r"\[0, 1\]")):
        with pytest.raises(serial.SerialException, match=message):
            serial.serial_for_url(url)
