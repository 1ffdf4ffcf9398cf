"""SerialDevice over real pseudo-terminals with pyserial: samples, faults, commands, errors, closing.

The far end of each pty is driven by the test itself (``RawPty``): it writes frames made by the
protocol encoder and, where a test needs it, answers commands like a unit would.
"""

from __future__ import annotations

import os
import select
import threading
import time

import numpy as np
import pytest
from device_helpers import read_samples

from drivers import (
    CommandRejected,
    CommandTimeout,
    PortBusy,
    PortLost,
    PortNotFound,
    SerialDevice,
    open_device,
)
from mocks.raw_pty import open_raw_pty
from protocols import native
from protocols.base import SAMPLE_DTYPE
from protocols.native import NativeDecoder, encode_ack, encode_device_info, encode_samples

INFO = {"serial": "PTY-1", "model": "test-unit", "firmware": "0.1", "rate_hz": 1000}


class RawPty:
    """A raw pseudo-terminal whose master end the test writes and reads."""

    def __init__(self) -> None:
        self.master, self._slave, self.path = open_raw_pty()
        self.closed = False

    def write(self, data: bytes) -> None:
        """Write all of ``data``; nothing once the pty is closed (a feeding thread that outlived its test,
        which would otherwise write to a closed or reused descriptor)."""
        view = memoryview(data)
        while view and not self.closed:
            try:
                view = view[os.write(self.master, view):]
            except OSError:
                if not self.closed:
                    raise
                return

    def vanish(self) -> None:
        """The unit goes away: both ends of the pty close."""
        self.closed = True
        for fd in (self.master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def close(self) -> None:
        self.vanish()


class Responder(threading.Thread):
    """Answers native commands on the master end, like a unit; ``ignore`` drops the first N commands."""

    def __init__(self, pty: RawPty, ack_status: int = native.ACK_OK, ignore: int = 0):
        super().__init__(daemon=True)
        self.pty, self.ack_status, self.ignore = pty, ack_status, ignore
        self.received: list[int] = []
        self.rate_hz: int | None = None
        self._halt = threading.Event()

    def run(self) -> None:
        dec = NativeDecoder()
        while not self._halt.is_set():
            ready, _, _ = select.select([self.pty.master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self.pty.master, 4096)
            except OSError:
                return
            for msg in dec.feed(data).messages:
                self.received.append(msg.msg_id)
                if self.ignore:
                    self.ignore -= 1
                    continue
                # Answers arrive between sample frames, as from a streaming unit.
                self.pty.write(encode_samples(make_samples(3)))
                if msg.msg_id == native.GET_INFO:
                    self.pty.write(encode_device_info(INFO))
                else:
                    if msg.msg_id == native.SET_RATE:
                        self.rate_hz = int.from_bytes(msg.payload, "little")
                    self.pty.write(encode_ack(msg.msg_id, self.ack_status))

    def stop(self) -> None:
        self._halt.set()
        self.join(1)


def make_samples(n: int, first_seq: int = 0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = (np.arange(n) + first_seq) % 2**32
    s["t_us"] = (np.arange(n) + first_seq) * 1000 + 17
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25 + rng.normal(0, 0.1, n)
    return s


@pytest.fixture
def pty():
    p = RawPty()
    yield p
    p.close()


def test_samples_arrive_bit_exact_with_link_stats(pty: RawPty) -> None:
    sent = make_samples(2000)
    with open_device(pty.path) as dev:
        pty.write(encode_samples(sent))
        got = read_samples(dev, len(sent), timeout=5.0)
        stats = dev.stats
    assert got.tobytes() == sent.tobytes()
    assert stats.samples == 2000 and stats.bytes == 2000 * native.SAMPLE_FRAME_SIZE
    assert stats.errors == 0 and stats.lost == 0 and stats.overflow_drops == 0
    assert stats.rate_hz == pytest.approx(1000.0)  # t_us steps of 1 ms, measured on the device clock


def test_faults_on_the_wire_lose_only_the_damaged_frames(pty: RawPty) -> None:
    sent = make_samples(600, seed=3)
    frames = [encode_samples(sent[i:i + 1]) for i in range(len(sent))]
    rng = np.random.default_rng(5)
    wire, good = bytearray(), []
    for i, frame in enumerate(frames):
        kind = i % 10
        if kind == 3:  # one bit flipped inside the payload: bad CRC
            f = bytearray(frame)
            f[10 + int(rng.integers(30))] ^= 1 << int(rng.integers(8))
            wire += f
        elif kind == 6:  # cut short by the next frame
            wire += frame[: int(rng.integers(3, 40))]
        elif kind == 8:  # garbage before a good frame
            # Without 0xA5 the garbage holds no sync candidate, so the error counts below are exact.
            junk = rng.integers(0, 256, int(rng.integers(1, 30)), dtype=np.uint8)
            wire += bytes(junk[junk != 0xA5])
            wire += frame
            good.append(i)
        else:
            wire += frame
            good.append(i)
    with open_device(pty.path) as dev:
        pty.write(bytes(wire))
        got = read_samples(dev, len(good), timeout=5.0)
        time.sleep(0.1)
        stats = dev.stats
    assert got.tobytes() == sent[good].tobytes()
    # A frame cut inside its length field is seen as an impossible length, any later cut as truncation.
    assert stats.crc_errors == 60 and stats.truncated + stats.length_errors == 60
    assert stats.lost == 120  # the seq gaps of the damaged frames
    assert stats.resyncs >= 120


def test_seq_gaps_and_wrap_counted_over_the_port(pty: RawPty) -> None:
    sent = make_samples(100, first_seq=2**32 - 50)
    kept = np.delete(sent, [10, 11, 70])  # 70 is after the wrap
    with open_device(pty.path) as dev:
        pty.write(encode_samples(kept))
        got = read_samples(dev, len(kept), timeout=5.0)
        assert dev.stats.lost == 3 and dev.stats.seq_resets == 0
    assert got.tobytes() == kept.tobytes()


def test_port_vanishing_delivers_everything_received_then_raises_port_lost(pty: RawPty) -> None:
    sent = make_samples(500)
    dev = open_device(pty.path)
    try:
        pty.write(encode_samples(sent))
        time.sleep(0.3)  # the driver has read them; the unit then disappears
        pty.vanish()
        got = []
        with pytest.raises(PortLost, match=r"went away.*check the cable"):
            while True:
                got.append(dev.read(1.0))
        assert np.concatenate(got).tobytes() == sent.tobytes()
        with pytest.raises(PortLost):  # and it stays lost
            dev.read(0.1)
    finally:
        dev.close()


def test_missing_port_and_unknown_url_scheme_are_port_not_found() -> None:
    with pytest.raises(PortNotFound, match=r"/dev/imu-does-not-exist: no such port.*imu-station ports"):
        open_device("/dev/imu-does-not-exist")
    with pytest.raises(PortNotFound, match=r"no handler for URL scheme 'nosuch://'"):
        open_device("nosuch://unit")
    assert PortNotFound("x").exit_code == 3


def test_second_opener_gets_port_busy_and_close_releases_the_port(pty: RawPty) -> None:
    dev = open_device(pty.path)
    with pytest.raises(PortBusy, match=r"busy, another program has it open.*fuser"):
        open_device(pty.path)
    dev.close()
    dev.close()  # twice is fine
    assert dev.closed and not dev._thread.is_alive()
    with open_device(pty.path) as again:  # released
        pty.write(encode_samples(make_samples(5)))
        assert len(read_samples(again, 5, timeout=5.0)) == 5


def test_commands_get_their_answers_between_samples(pty: RawPty) -> None:
    responder = Responder(pty)
    responder.start()
    try:
        with open_device(pty.path) as dev:
            assert dev.get_info() == INFO
            assert dev.info == INFO
            dev.set_rate(400)
            dev.start()
            dev.stop()
            # The samples sent around each answer still arrive.
            assert len(read_samples(dev, 12, timeout=5.0)) == 12
    finally:
        responder.stop()
    assert responder.rate_hz == 400
    assert responder.received == [native.GET_INFO, native.SET_RATE, native.START_STREAM, native.STOP_STREAM]


def test_a_lost_answer_is_retried(pty: RawPty) -> None:
    responder = Responder(pty, ignore=1)
    responder.start()
    try:
        with open_device(pty.path) as dev:
            dev.start(timeout=0.3, retries=1)
    finally:
        responder.stop()
    assert responder.received == [native.START_STREAM, native.START_STREAM]


def test_refused_and_unanswered_commands_raise(pty: RawPty) -> None:
    responder = Responder(pty, ack_status=native.ACK_BAD_ARGUMENT)
    responder.start()
    try:
        with open_device(pty.path) as dev:
            with pytest.raises(CommandRejected, match="refused SET_RATE: bad argument") as exc:
                dev.set_rate(7)
            assert exc.value.status == native.ACK_BAD_ARGUMENT
    finally:
        responder.stop()
    with open_device(pty.path) as dev:  # nobody answers now
        t0 = time.monotonic()
        with pytest.raises(CommandTimeout, match=r"no answer to GET_INFO in 2 tries of 0.2 s"):
            dev.get_info(timeout=0.2, retries=1)
        assert time.monotonic() - t0 < 1.0


def test_slow_consumer_overflows_without_blocking_the_reader(pty: RawPty) -> None:
    with SerialDevice(pty.path, max_buffered_samples=100) as dev:
        for i in range(10):  # 10 batches of 50 while nobody reads: only 2 fit
            pty.write(encode_samples(make_samples(50, first_seq=50 * i)))
            time.sleep(0.05)
        time.sleep(0.2)
        stats = dev.stats
        assert stats.samples == 500 and stats.overflow_drops + 100 >= 500 > stats.overflow_drops
        first = dev.read(0.1)
        assert len(first) == 500 - stats.overflow_drops
        pty.write(encode_samples(make_samples(30, first_seq=500)))  # the reader is still alive
        later = read_samples(dev, 30, timeout=5.0)
    assert later["seq"].tolist() == list(range(500, 530))
