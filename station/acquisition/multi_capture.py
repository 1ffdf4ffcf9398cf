"""Record many units at once from one thread: one event loop, one file per unit named by its serial.

Every port is a :class:`~drivers.polled_port.PolledPort` registered with one selector (epoll).
The loop wakes every ``READ_PERIOD_S`` and reads the ports that have bytes, each in one read
of a large buffer (a port's buffer never fills); a port's bytes gather and are decoded in one batch
every ``DECODE_PERIOD_S`` (every turn while the unit is asked who it is), so a unit costs one
system call per turn and a decoder call every other turn, whatever its rate and however its bytes
arrive (a reader thread per port wakes for every few bytes). Each unit's samples gather
for ``WRITE_PERIOD_S`` and go to its :class:`~station.acquisition.recorder.Recorder` in one
batch; the units take turns, so the writes are spread over the period, not all on one turn.
The recorders write from a thread of their own, in order: a disk that stalls (writeback, a slow
card) delays the files, never the reading of the ports, whose buffers hold well under a second.

A unit is asked who it is (GET_INFO) as its port opens; its file is ``SERIAL.csv`` (or ``.h5``) in
the directory. A unit that does not answer (twice), or speaks a protocol without commands, is named
after its port. A serial reported by two ports names the second file ``SERIAL-2`` (the third
``SERIAL-3``...), noted in the outcome: no samples are dropped for a provisioning mistake. Samples
that come before the answer wait in memory and open the file.

A unit that fails (its port does not open, vanishes, sends no sample in ``NO_SAMPLES_TIMEOUT_S``,
floods more than its bounded share of a turn decodes) ends with its error, keeping every sample it
sent; the others go on at their full rate. Ctrl-C ends every unit, keeping every sample received.
"""

from __future__ import annotations

import math
import re
import selectors
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers import DEFAULT_BAUDRATE, CommandRejected, DriverError, LinkStats, NoSamples
from drivers.message_log import no_answer
from drivers.polled_port import PolledPort, join_samples
from protocols import native
from station.acquisition.file_syncer import FileSyncer
from station.acquisition.recorder import (
    FLUSH_INTERVAL_S,
    NO_SAMPLES_TIMEOUT_S,
    CaptureResult,
    Recorder,
    _install_sigint,
    _link,
    _no_rows,
    _with_clock,
)
from station.common.text import printable

READ_PERIOD_S = 0.02  # a pty holds ~20 KB: 0.4 s of a 1 kHz unit, far more than a turn
# A port is read every turn (its buffer never fills), its bytes decoded every DECODE_PERIOD_S or once
# DECODE_BYTES gathered (every turn while it is asked who it is); BEHIND_BYTES undecoded: it floods.
DECODE_PERIOD_S, DECODE_BYTES, BEHIND_BYTES = 0.04, 16_384, 65_536
WRITE_PERIOD_S = 1.0  # the HDF5 writer costs ~1 ms a call whatever the rows: fewer, larger batches
STATUS_INTERVAL_S = 0.25
INFO_TIMEOUT_S = 0.5
INFO_TRIES = 2
FORMATS = {"csv": ".csv", "h5": ".h5"}


@dataclass
class UnitStatus:
    """One unit as the live display shows it: name, link statistics, rows, device time, state."""

    port: str
    name: str  # the file's stem once known, else the port
    stats: LinkStats
    rows: int
    device_time_s: float
    state: str  # "preparing", "recording", "done", or "failed: " and the error that ended it


StatusCallback = Callable[[Sequence[UnitStatus]], None]
"""Called with every unit's :class:`UnitStatus` as the capture goes."""
StatusDisplay = Callable[[Sequence[str], float | None], AbstractContextManager[StatusCallback]]
"""Makes the live display for the given ports and duration; entering it gives the callback."""


@dataclass
class UnitOutcome:
    """How one unit's capture ended.

    ``capture`` is None when the port never opened (``error`` says why); else it is the unit's
    :class:`CaptureResult`, whose ``error`` is this ``error``. ``note`` says what the station
    decided about the file's name, when it was not simply the serial.
    """

    port: str
    serial: str | None
    capture: CaptureResult | None
    error: DriverError | None
    note: str = ""


def file_stem(text: str) -> str:
    """A file name from a serial or a port: what is not a letter, digit, ``.``, ``_`` or ``-`` becomes
    ``_`` (a serial is the unit's, not a path), and a leading dot is dropped."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", text).lstrip(".") or "unit"


def _port_stem(port: str) -> str:
    """``/dev/ttyUSB0`` -> ``ttyUSB0``, ``/dev/pts/5`` -> ``pts-5``."""
    return file_stem(port.removeprefix("/dev/").replace("/", "-"))


@dataclass
class _Ask:
    """A command the unit is asked before its file opens, and how often it was sent."""

    command_id: int
    payload: bytes = b""
    tries: int = 0
    mark: int = 0  # the port's message count when it was last sent
    due: float = 0.0  # when to send it again


class _Unit:
    """One port in the loop: asked who it is (and to set its rate), then recorded until it is done."""

    def __init__(self, index: int, port: PolledPort, now: float, rate_hz: int | None):
        self.index = index
        self.port = port
        self.opened_at = now
        self.serial: str | None = None
        self.stem: str | None = None
        self.note = ""
        self.recorder: Recorder | None = None  # made by the writer thread once the unit is named
        self.batch: list[np.ndarray] = []
        # What prepare_device asks of a single unit: who it is, and with a rate, to set it and who it
        # is then (the file records the unit's info at the new rate).
        self.asks: list[_Ask] = []
        if port.protocol == "native":
            self.asks.append(_Ask(native.GET_INFO))
            if rate_hz is not None:
                self.asks += [_Ask(native.SET_RATE, rate_hz.to_bytes(2, "little")), _Ask(native.GET_INFO)]
        self.done = False
        self.ended_by = "stopped"
        self.error: DriverError | None = None
        self.result: CaptureResult | None = None  # set by the writer thread once the file is closed
        self.finishing = False  # the loop is done with it: port closed, the file's close queued
        self.received = 0  # samples read from the port
        self.gathered = 0  # bytes read from the port and not yet decoded

    def gather(self) -> None:
        """Read what the port has, to be decoded later (:meth:`receive`)."""
        self.gathered = self.port.gather()

    def receive(self, read: bool = True) -> None:
        """Take what the port has (``read`` False: what :meth:`gather` read); a broken link ends the
        unit once its samples are taken."""
        self.gathered = 0
        try:
            batch = self.port.read_now() if read else self.port.read_gathered()
        except DriverError as exc:
            self.error, self.ended_by, self.done = exc, "link error", True
            return
        if len(batch):
            self.batch.append(batch)
            self.received += len(batch)

    def status(self) -> UnitStatus:
        """The unit's line on the live display."""
        rec = self.recorder
        if self.done:
            state = "done" if self.error is None else f"failed: {self.error}"
        else:
            behind = self.port.backlog_bytes
            state = ("recording" if self.stem is not None else "preparing") + (
                f", {behind // 1024} KiB not decoded yet (the port floods)" if behind > BEHIND_BYTES else "")
        return UnitStatus(self.port.port, self.stem or self.port.port, self.port.stats,
                          rec.rows if rec is not None else 0, rec.device_time_s if rec is not None else 0.0,
                          state)


class _Session:
    """The units of one capture and the loop that serves them."""

    def __init__(self, directory: Path, suffix: str, duration_s: float | None):
        self.directory = directory
        self.suffix = suffix
        self.duration_s = duration_s
        self.units: list[_Unit] = []
        self.stems: dict[str, str] = {}  # stem -> port that has it
        self.unopened: list[UnitStatus] = []  # ports that did not open, shown as failed
        self.syncer = FileSyncer() if suffix == ".csv" else None
        self.writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="capture-writer")
        self.write_error: BaseException | None = None  # the writer thread's first error, for the loop

    def close(self) -> None:
        """Finish every unit still open, wait for the writer thread, then make the files durable a last
        time; raise what the writer failed with (a full disk)."""
        try:
            for unit in self.units:
                if not unit.finishing:
                    self.finish(unit)
        finally:
            self.writer.shutdown(wait=True)
            if self.syncer is not None:
                self.syncer.close()
        if self.write_error is not None:
            raise self.write_error

    def statuses(self) -> list[UnitStatus]:
        """Every port's line: those that did not open, then the units."""
        return self.unopened + [u.status() for u in self.units]

    def prepare(self, unit: _Unit, now: float) -> None:
        """Ask the unit's questions in turn, each sent up to ``INFO_TRIES`` times, then open its file.

        An unanswered GET_INFO leaves the unit unnamed (recorded anyway: a unit streams from
        power-up); a refused or unanswered SET_RATE ends the unit with that error, as it ends a
        capture of one unit. Samples before the rate's ACK are at the old rate: not recorded.
        """
        port = unit.port
        while unit.asks:
            ask = unit.asks[0]
            try:
                answered = ask.tries > 0 and port.answer_since(ask.command_id, ask.mark) is not None
            except CommandRejected as exc:
                self.fail(unit, exc)
                return
            if answered:
                if ask.command_id == native.SET_RATE:
                    unit.batch = []
                unit.asks.pop(0)
            elif now < ask.due:
                return
            elif ask.tries < INFO_TRIES:
                ask.tries, ask.mark, ask.due = ask.tries + 1, port.message_count, now + INFO_TIMEOUT_S
                port.send(ask.command_id, ask.payload)
                return
            elif ask.command_id == native.SET_RATE:
                self.fail(unit, no_answer(port.port, port.protocol, native.SET_RATE, INFO_TRIES,
                                          INFO_TIMEOUT_S))
                return
            else:
                unit.asks.pop(0)
        self.open_file(unit)

    @staticmethod
    def fail(unit: _Unit, error: DriverError) -> None:
        """End a unit that could not be prepared: nothing it sent is recorded."""
        unit.asks.clear()
        unit.batch = []
        unit.error, unit.ended_by, unit.done = error, "link error", True

    def open_file(self, unit: _Unit) -> None:
        """Name the unit's file by the serial it said (else by its port) and start recording it."""
        port = unit.port
        serial = port.info.get("serial")
        if serial is not None:
            unit.serial = printable(serial)
            stem = file_stem(str(serial))
        else:
            stem = _port_stem(port.port)
            unit.note = (f"the unit did not say its serial (no answer to GET_INFO in {INFO_TRIES} tries of "
                         f"{INFO_TIMEOUT_S:g} s): its file is named after its port"
                         if port.protocol == "native" else
                         f"the {port.protocol} protocol does not say the unit's serial: its file is named "
                         f"after its port")
        unit.stem = self._unique(stem, unit)
        path = self.directory / (unit.stem + self.suffix)
        # Made in the writer thread, like every write after it: an HDF5 file takes ~10 ms to create,
        # and 32 of them at once would leave the ports unread for 0.4 s.
        self.writer.submit(self._guarded, self._open_recorder, unit, path, port.info)
        if port.protocol == "native" and unit.received == 0:
            port.send(native.START_STREAM)  # a unit streams from power-up; one that was stopped starts

    def _unique(self, stem: str, unit: _Unit) -> str:
        """``stem``, or ``stem-2``, ``stem-3``... when another port already has it (noted)."""
        first = stem
        count = 1
        while stem in self.stems:
            count += 1
            stem = f"{first}-{count}"
        if count > 1:
            unit.note = (f"serial {printable(first)} is also reported by {self.stems[first]}: this unit's "
                         f"file is {stem}{self.suffix}; give the units distinct serials")
        self.stems[stem] = unit.port.port
        return stem

    def _open_recorder(self, unit: _Unit, path: Path, info: dict[str, object]) -> None:
        """In the writer thread: create the unit's file."""
        port = unit.port
        # A CSV's rows reach the OS as they are written; its flush is an fsync, left to the syncer's
        # thread. An HDF5 file's flush writes its metadata, which only the writing thread may do.
        flush_s = FLUSH_INTERVAL_S if self.syncer is None else math.inf
        unit.recorder = Recorder(path, device=info, port=port.port, protocol=port.protocol,
                                 duration_s=self.duration_s, flush_interval_s=flush_s)
        if self.syncer is not None:
            self.syncer.add(path)

    def write(self, unit: _Unit) -> None:
        """Queue the unit's gathered samples for its recorder, in one batch."""
        if unit.stem is None or not unit.batch:
            return
        batch = unit.batch[0] if len(unit.batch) == 1 else join_samples(unit.batch)
        unit.batch = []
        self.writer.submit(self._guarded, self._record, unit, batch)

    @staticmethod
    def _record(unit: _Unit, batch: np.ndarray) -> None:
        """In the writer thread: one batch to the unit's file, with the link statistics so far (a
        snapshot of the loop's counters, each read whole)."""
        rec = unit.recorder
        assert rec is not None  # _open_recorder() ran first, in the same thread
        rec.write(batch, _link(unit.port, rec))

    def _guarded(self, call: Callable[..., object], *args: object, closing: bool = False) -> None:
        """Run ``call`` in the writer thread, keeping its first error for the loop to raise. After an
        error (a full disk) no more samples are written, but every file is still ``closing``."""
        if self.write_error is not None and not closing:
            return
        try:
            call(*args)
        except BaseException as exc:  # the loop raises it: nothing of the writer's may pass unseen
            if self.write_error is None:
                self.write_error = exc

    def check(self, unit: _Unit, now: float, wall_deadline: float | None) -> None:
        """End a unit that sent no sample in time, or ran past the wall-clock guard."""
        if unit.received == 0 and now - unit.opened_at > NO_SAMPLES_TIMEOUT_S:
            stats = unit.port.stats
            unit.error = NoSamples(f"{unit.port.port}: no sample arrived in {NO_SAMPLES_TIMEOUT_S:g} s "
                                   f"({stats.bytes} bytes read, {stats.garbage_bytes} of them not frames); "
                                   f"check that the unit streams, and the --protocol and baud rate",
                                   unit.port.port)
            unit.ended_by, unit.done = "link error", True
        elif wall_deadline is not None and now > wall_deadline:
            unit.ended_by, unit.done = "duration", True

    def finish(self, unit: _Unit) -> None:
        """Close the unit's port and queue what is left of it: its last samples, then the file's close
        and the unit's result."""
        unit.finishing = True
        if unit.gathered and unit.error is None:  # the bytes read last, not yet decoded
            unit.receive(read=False)
        try:
            if unit.stem is None:  # the capture ends before the unit was prepared
                unit.asks.clear()
                self.open_file(unit)
            self.write(unit)
        finally:
            unit.port.close()
        self.writer.submit(self._guarded, self._close_file, unit, closing=True)

    @staticmethod
    def _close_file(unit: _Unit) -> None:
        """In the writer thread: close the unit's file and keep its result."""
        port, rec = unit.port, unit.recorder
        if rec is None:  # its file could not be made: the writer's error says why
            return
        rec.close(_link(port, rec))
        if rec.rows == 0:
            unit.error, unit.ended_by = _no_rows(port, rec, unit.error, unit.ended_by), "link error"
        unit.result = CaptureResult(path=rec.path, rows=rec.rows, device_time_s=rec.device_time_s,
                                    link=_with_clock(port.stats, rec), ended_by=unit.ended_by,
                                    error=unit.error, non_increasing=rec.non_increasing,
                                    clock_jumps=list(rec.clock_jumps))


def capture_many(ports: Sequence[str], directory: str | Path, fmt: str = "csv", protocol: str = "native",
                 duration_s: float | None = None, rate_hz: int | None = None,
                 baudrate: int = DEFAULT_BAUDRATE, status: StatusDisplay | None = None,
                 stop: threading.Event | None = None, handle_sigint: bool = True) -> list[UnitOutcome]:
    """Record every unit at ``ports`` into its own file in ``directory`` until each has ``duration_s``
    of device clock, or Ctrl-C, or ``stop``; a unit that fails ends alone.

    Parameters
    ----------
    ports : sequence of str
        Device paths or ptys (not URLs: the loop watches their file descriptors).
    directory : str or Path
        Where the files go (made if missing): ``SERIAL.csv`` or ``SERIAL.h5``.
    fmt : str
        ``csv`` or ``h5``.
    protocol : str
        Decoder name, with its option if any, for every port.
    duration_s : float, optional
        Seconds of device clock to record from each unit; None: until Ctrl-C or ``stop``.
    rate_hz : int, optional
        Output rate to set each unit to first (SET_RATE; native units only).
    baudrate : int
        Line speed of real serial ports.
    status : callable, optional
        Makes the live display (see :data:`StatusDisplay`); None shows nothing.
    stop : threading.Event, optional
        Set it to end the capture (from another thread).
    handle_sigint : bool
        The first Ctrl-C ends the capture cleanly (main thread only).

    Returns
    -------
    list of UnitOutcome
        One per port, in the order of ``ports``.

    Raises
    ------
    OutputFileError
        A file cannot be written (the disk is full): every file is closed first.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    session = _Session(directory, FORMATS[fmt], duration_s)
    outcomes: dict[int, UnitOutcome] = {}
    selector = selectors.DefaultSelector()
    interrupted = threading.Event()
    restore = _install_sigint(interrupted) if handle_sigint else None
    now = time.monotonic()
    try:
        for index, name in enumerate(ports):
            try:
                port = PolledPort(name, protocol=protocol, baudrate=baudrate)
            except DriverError as exc:
                outcomes[index] = UnitOutcome(name, None, None, exc)
                session.unopened.append(UnitStatus(name, name, LinkStats(), 0, 0.0, f"failed: {exc}"))
                continue
            unit = _Unit(index, port, now, rate_hz)
            session.units.append(unit)
            selector.register(port, selectors.EVENT_READ, unit)
            session.prepare(unit, now)
        wall_deadline = None if duration_s is None else now + duration_s * 1.5 + 5.0
        display = (status([u.port for u in session.statuses()], duration_s) if status is not None
                   else nullcontext(None))
        with display as on_status:
            _serve(session, selector, interrupted, stop, wall_deadline, on_status)
    finally:
        if restore is not None:
            restore()
        selector.close()
        session.close()
    for unit in session.units:
        outcomes[unit.index] = UnitOutcome(unit.port.port, unit.serial, unit.result, unit.error, unit.note)
    return [outcomes[i] for i in range(len(ports))]


def _serve(session: _Session, selector: selectors.BaseSelector, interrupted: threading.Event,
           stop: threading.Event | None, wall_deadline: float | None,
           on_status: StatusCallback | None) -> None:
    """The loop: every turn, read the ready ports; name, write, check the units; show the status."""
    write_every = max(1, round(WRITE_PERIOD_S / READ_PERIOD_S))
    decode_every = max(1, round(DECODE_PERIOD_S / READ_PERIOD_S))
    start = time.monotonic()
    last_status = 0.0
    turn = 0
    units = session.units
    try:
        while not all(u.done for u in units):
            if interrupted.is_set() or (stop is not None and stop.is_set()):
                for unit in units:
                    if not unit.done:
                        unit.ended_by, unit.done = "interrupted" if interrupted.is_set() else "stopped", True
                break
            turn += 1
            delay = start + turn * READ_PERIOD_S - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            for key, _ in selector.select(0):
                unit = key.data
                unit.gather()
                if unit.gathered >= DECODE_BYTES or unit.stem is None or unit.port.failed is not None:
                    unit.receive(read=False)
            now = time.monotonic()
            if session.write_error is not None:
                raise session.write_error
            for unit in units:
                if unit.finishing:
                    continue
                if unit.gathered and (turn + unit.index) % decode_every == 0:
                    unit.receive(read=False)
                rec = unit.recorder
                if unit.stem is None and not unit.done:
                    session.prepare(unit, now)
                elif rec is not None and rec.full and not unit.done:  # the writer reached --duration
                    unit.ended_by, unit.done = "duration", True
                if unit.done or (turn + unit.index) % write_every == 0:
                    session.write(unit)
                if not unit.done:
                    session.check(unit, now, wall_deadline)
                else:
                    selector.unregister(unit.port)
                    session.finish(unit)
            if on_status is not None and now - last_status >= STATUS_INTERVAL_S:
                on_status(session.statuses())
                last_status = now
    except KeyboardInterrupt:
        for unit in units:
            if not unit.done:
                unit.ended_by, unit.done = "interrupted", True
    if on_status is not None:
        on_status(session.statuses())
