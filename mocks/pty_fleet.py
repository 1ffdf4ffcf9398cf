"""Many simulated units on pseudo-terminals, served cheaply by one thread from precomputed bytes.

A tray of units at 1 kHz is more than one :class:`~mocks.pty_server.PtyServer` thread per unit
can produce on a small machine without the feed itself falling behind, so :class:`PtyFleet`
encodes each unit's whole stream once, up front (a :class:`~mocks.device.SimDevice` per unit,
its samples for ``duration_s`` of device clock), and then only copies slices of it to the ptys on
an absolute schedule: sample k goes out at t0 + k / rate, t0 being when the host first spoke to
the unit (it sends GET_INFO on opening). Host commands are answered by the unit's
:class:`SimDevice`, between frames; the precomputed stream itself does not change (a unit
told to stop keeps streaming).

Besides a clean unit, a unit can be ``garbage`` (random bytes at the same byte rate, no
answers), ``flood`` (native frame headers that announce the longest payload, overlapping, as fast
as the pty takes them: every byte a false start the decoder must check, no answers), ``silent``
(nothing at all) or ``vanish`` after ``vanish_after_s`` (its pty closes, as a unit unplugged).
The fleet keeps each slave end open itself, so that it can measure the bytes
waiting for the host (the backlog: what the pty's line buffer holds, up to its 4 KiB, plus what a
full pty refused).
"""

from __future__ import annotations

import fcntl
import os
import struct
import termios
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from mocks.device import SimDevice
from mocks.pty_server import read_host
from mocks.raw_pty import open_raw_pty
from protocols import native

MODES = ("stream", "garbage", "flood", "silent", "vanish")
# A sample frame's header announcing the longest payload, the sync repeated inside it: each byte
# starts a candidate the decoder can reject only by a CRC over a whole frame.
FLOOD_BLOCK = (native.SYNC + bytes([native.IMU_SAMPLE]) + native.MAX_PAYLOAD.to_bytes(2, "little")) * 4096
# FIONREAD on a pty counts what its line buffer holds, at most this; the bytes beyond wait unseen in
# the tty's own buffers (~20 KB in all before a write is refused).
LINE_BUFFER_BYTES = 4095


@dataclass
class FleetUnit:
    """One unit of the fleet: what it is and how it behaves.

    ``device`` answers the host's commands and makes the samples; ``mode`` is one of
    :data:`MODES`; ``duration_s`` of device clock are streamed (plus the sample at its end);
    ``vanish`` closes the port after ``vanish_after_s`` of streaming.
    """

    device: SimDevice
    duration_s: float
    mode: str = "stream"
    vanish_after_s: float = 1.0


@dataclass
class FeedStats:
    """What the fleet did for one unit: samples and bytes out, the worst backlog, late ticks."""

    serial: str
    samples_sent: int = 0  # samples whose bytes the pty took
    bytes_sent: int = 0
    max_backlog_bytes: int = 0  # the most bytes waiting for the host at a tick (in the pty or not fitting)
    max_unwritten_bytes: int = 0  # the most bytes the full pty refused at a tick (the feed backing up)
    full_line_ticks: int = 0  # ticks at which the pty's line buffer was full (the backlog seen is a floor)
    watched_ticks: int = 0  # ticks over which the backlog was measured
    started: bool = False  # the host spoke to the unit and the stream began
    finished: bool = False  # the whole stream was taken by the pty (or the unit vanished)
    answers: int = 0


@dataclass
class _Feed:
    """The serving state of one unit."""

    unit: FleetUnit
    stream: bytes  # everything the unit sends, precomputed
    frame_size: int
    master: int
    slave: int
    path: str
    stats: FeedStats
    t0: float = 0.0
    due_bytes: int = 0  # stream bytes queued so far
    pending: bytearray = field(default_factory=bytearray)  # bytes for the pty: answers first, then stream
    answer_front: int = 0  # answer bytes at the front of ``pending``
    answers: bytearray = field(default_factory=bytearray)  # answers waiting for a frame boundary


class PtyFleet:
    """Serve ``units`` on ptys from one thread: ``with PtyFleet(units) as fleet: fleet.ports``.

    Parameters
    ----------
    units : list of FleetUnit
        The units, one pty each (``ports`` in the same order).
    tick_s : float
        Period of the feed: every tick each unit gets the samples due by then in one write.
    watch_s : float, optional
        The backlog is measured over the first ``watch_s`` of each unit's stream only (the host
        stops reading a unit once it has what it wanted, and the bytes after that wait forever);
        None: over the whole stream.
    write_s : float, optional
        Hand the stream over in writes of ``write_s`` of frames each, as a USB serial adapter hands
        over what it gathered (10 ms: ten 1 kHz frames a write), a write once its last frame is due,
        several writes when a tick comes late. None: at every tick, everything due in one write.
    """

    def __init__(self, units: list[FleetUnit], tick_s: float = 0.01, watch_s: float | None = None,
                 write_s: float | None = None):
        for unit in units:
            if unit.mode not in MODES:
                raise ValueError(f"unknown mode {unit.mode!r}; known: {', '.join(MODES)}")
        self.tick_s = tick_s
        self.watch_s = watch_s
        self.write_s = write_s
        self._feeds = [self._prepare(unit) for unit in units]
        self.late_ticks = 0  # ticks served more than a tick late (the feeder itself falling behind)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    @staticmethod
    def _prepare(unit: FleetUnit) -> _Feed:
        device = unit.device
        samples = device.produce(unit.duration_s)
        stream = device.encode_samples(samples)
        frame_size = len(stream) // max(1, len(samples))
        if unit.mode == "garbage":
            noise = np.random.default_rng(len(stream)).integers(0, 256, len(stream), dtype=np.uint8)
            stream = noise.tobytes()
        elif unit.mode == "flood":
            stream = FLOOD_BLOCK
        master, slave, path = open_raw_pty()
        os.set_blocking(master, False)
        stats = FeedStats(serial=str(device.info().get("serial", "")))
        return _Feed(unit, stream, frame_size, master, slave, path, stats)

    @property
    def ports(self) -> list[str]:
        """The units' port paths, in the order of ``units``."""
        return [feed.path for feed in self._feeds]

    @property
    def stats(self) -> list[FeedStats]:
        """What was fed to each unit, in the order of ``units``."""
        return [feed.stats for feed in self._feeds]

    @property
    def finished(self) -> bool:
        """Every unit that started has sent its whole stream (or vanished)."""
        return all(feed.stats.finished or feed.unit.mode in ("silent", "flood") for feed in self._feeds)

    # -- life cycle ----------------------------------------------------------------------------

    def start(self) -> PtyFleet:
        """Serve from a thread; returns self."""
        self._thread = threading.Thread(target=self._run, name="pty-fleet", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            self.serve(self._stop)
        except BaseException as exc:  # surfaced by stop(): a test must see a crashed feed
            self._error = exc

    def stop(self) -> None:
        """Stop serving and close every pty; raise what the serving thread failed with."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for feed in self._feeds:
            for fd in (feed.master, feed.slave):
                if fd >= 0:
                    os.close(fd)
            feed.master = feed.slave = -1
        if self._error is not None:
            error, self._error = self._error, None
            raise RuntimeError("the pty fleet failed") from error

    def __enter__(self) -> PtyFleet:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- serving -------------------------------------------------------------------------------

    def serve(self, stop: threading.Event) -> None:
        """Feed every unit on the tick until ``stop`` is set (call it from a thread or a process)."""
        start = time.monotonic()
        tick = 0
        while not stop.is_set():
            tick += 1
            delay = start + tick * self.tick_s - time.monotonic()
            if delay > 0 and stop.wait(delay):
                return
            now = time.monotonic()
            if delay < -self.tick_s:
                self.late_ticks += 1
            for feed in self._feeds:
                if feed.master >= 0 and feed.unit.mode != "silent":
                    self._serve_one(feed, now)

    def _serve_one(self, feed: _Feed, now: float) -> None:
        unit, stats = feed.unit, feed.stats
        host_bytes = read_host(feed.master)
        if host_bytes:
            if not stats.started:
                stats.started, feed.t0 = True, now
            if unit.mode not in ("garbage", "flood"):
                answer = unit.device.feed(host_bytes)
                if answer:
                    stats.answers += 1
                    feed.answers += answer
        if not stats.started:
            return
        if unit.mode == "flood":
            for _ in range(16):  # as much as the pty takes, a bounded number of writes a tick
                if len(feed.pending) < len(FLOOD_BLOCK):
                    feed.pending += FLOOD_BLOCK
                waiting = len(feed.pending)
                self._write(feed)
                if len(feed.pending) == waiting:
                    break
            return
        elapsed = now - feed.t0
        if unit.mode == "vanish" and elapsed >= unit.vanish_after_s:
            self._vanish(feed)
            return
        if feed.answers and not feed.pending:  # between frames: nothing of a frame is waiting
            feed.pending += feed.answers
            feed.answer_front = len(feed.answers)
            feed.answers.clear()
        frames_due = int(elapsed * unit.device.rate_hz) + 1
        block = 0
        if self.write_s is not None:  # only whole writes' worth of frames, each write its own
            per_write = max(1, round(self.write_s * unit.device.rate_hz))
            frames_due -= frames_due % per_write
            block = per_write * feed.frame_size
        due = min(len(feed.stream), frames_due * feed.frame_size)
        if due > feed.due_bytes:
            feed.pending += feed.stream[feed.due_bytes:due]
            feed.due_bytes = due
        self._write(feed, block)
        if self.watch_s is None or elapsed < self.watch_s:
            stats.max_unwritten_bytes = max(stats.max_unwritten_bytes, len(feed.pending))
            waiting = struct.unpack("i", fcntl.ioctl(feed.slave, termios.FIONREAD, b"\0\0\0\0"))[0]
            stats.max_backlog_bytes = max(stats.max_backlog_bytes, waiting + len(feed.pending))
            stats.watched_ticks += 1
            stats.full_line_ticks += waiting >= LINE_BUFFER_BYTES
        if unit.mode != "garbage":
            stats.samples_sent = (feed.due_bytes - len(feed.pending) + feed.answer_front) // feed.frame_size
        if feed.due_bytes == len(feed.stream) and not feed.pending:
            stats.finished = True

    def _write(self, feed: _Feed, block: int = 0) -> None:
        """Write what is pending: in one write, or (``block`` > 0) in writes of ``block`` stream bytes
        each, the answers waiting at the front going with the first."""
        while feed.pending:
            size = len(feed.pending) if block <= 0 else min(len(feed.pending), feed.answer_front + block)
            try:
                chunk = feed.pending if size == len(feed.pending) else feed.pending[:size]
                written = os.write(feed.master, chunk)
            except BlockingIOError:
                return
            del feed.pending[:written]
            feed.answer_front -= min(written, feed.answer_front)
            feed.stats.bytes_sent += written
            if block <= 0 or written < size:
                return

    @staticmethod
    def _vanish(feed: _Feed) -> None:
        """Unplug: close both ends, so the host's next read fails."""
        for fd in (feed.master, feed.slave):
            os.close(fd)
        feed.master = feed.slave = -1
        feed.stats.finished = True
