"""A unit read without a thread: the caller's event loop says when its port has bytes.

:class:`PolledPort` is a :class:`~drivers.interface.Device` whose bytes are read by whoever owns
it, not by a reader thread of its own: it exposes the port's file descriptor for a selector
(epoll), :meth:`PolledPort.read_now` reads and decodes what is there without waiting, and
:meth:`PolledPort.send` writes a command without waiting for its answer. One loop can so serve
many ports in one thread, decoding each port's bytes in one batch per turn (a thread per port
wakes for every few bytes: that wake-up, not the decoding, is what a unit costs at 1 kHz).
The blocking calls of the interface (``read(timeout)``, the commands) are built on the same two;
``read(timeout)`` returns as soon as bytes are there, so a loop that wants batches waits between
its calls, as an event loop does.

Every call is bounded, so that one port cannot starve the others served by the same loop: a call
reads at most ``READ_BUDGET_BYTES`` and decodes for at most ``DECODE_BUDGET_S`` (in slices sized
to what the port's bytes decode in a fraction of it); what is left waits for the next call. Clean
frames decode at tens of MB/s, so a unit's bytes are always decoded in one call; bytes that are
all false starts (a frame header announcing a long payload, repeated) cost a CRC over a frame per
byte, a thousand times more. A port whose undecoded bytes pass ``FLOOD_BACKLOG_BYTES`` is
dropped with :class:`~drivers.errors.PortFlooding`, its samples decoded before delivered.

It needs a port with a file descriptor: a device path or a pty, not a pyserial URL such as
``sim://`` (served by a Python object, not by the kernel).
"""

from __future__ import annotations

import os
import select
import time
from time import perf_counter
from typing import Any

import numpy as np
import serial

from drivers.errors import DriverError, PortError, PortFlooding, PortLost
from drivers.interface import Device
from drivers.link_stats import LinkMonitor, LinkStats
from drivers.message_log import MessageLog, no_answer, unsupported
from drivers.serial_device import DEFAULT_BAUDRATE, open_serial, set_rate_payload
from protocols import native
from protocols.base import EMPTY_SAMPLES, Message
from protocols.registry import make_decoder

READ_CHUNK = 65_536
LINE_BUFFER_BYTES = 4095  # the most a tty's line discipline holds for a read (raw mode)
# A call's share of the loop: 64 KiB is 1.3 s of a 1 kHz native unit (a turn is 20 ms), and 5 ms of
# decoding is a quarter of a turn, so four flooding ports still leave the others their turns.
READ_BUDGET_BYTES = 65_536
DECODE_BUDGET_S = 0.005
SLICE_BYTES = (256, 65_536)  # the least and most bytes handed to the decoder at once
# Undecoded bytes beyond this (5 s of a 1 kHz native unit) mean the port sends faster than its share
# decodes: it would only fall further behind.
FLOOD_BACKLOG_BYTES = 262_144


def join_samples(batches: list[np.ndarray]) -> np.ndarray:
    """The batches end to end: ``np.concatenate``, ten times faster for samples of one structured dtype
    (joined as whole records, not field by field: numpy promotes each field of each array)."""
    dtype = batches[0].dtype
    if dtype.names is None or not all(b.dtype == dtype and b.flags.c_contiguous for b in batches):
        return np.concatenate(batches)
    record = np.dtype((np.void, dtype.itemsize))
    return np.concatenate([b.view(record) for b in batches]).view(dtype)


class PolledPort(Device):
    """One unit on a port with a file descriptor, read by the caller's loop.

    Parameters
    ----------
    port : str
        Device path (``/dev/ttyUSB0``, a pty such as ``/dev/pts/5``).
    protocol : str
        Decoder name from ``protocols.registry``; commands exist for ``native`` only.
    baudrate : int
        Line speed; ignored by pseudo-terminals.
    exclusive : bool
        Take an exclusive lock on the port (a second opener gets ``PortBusy``).

    Raises
    ------
    PortError
        The port cannot be opened, or it is a URL without a file descriptor.
    """

    def __init__(self, port: str, protocol: str = "native", baudrate: int = DEFAULT_BAUDRATE,
                 exclusive: bool = True):
        self.port = port
        self._decoder = make_decoder(protocol)
        self.protocol = self._decoder.label or protocol
        self._serial = open_serial(port, baudrate, exclusive)
        try:
            self._fd = self._serial.fileno()
        except (AttributeError, serial.SerialException, OSError):
            self._serial.close()
            raise PortError(f"{port}: a URL has no file descriptor to watch; give a device path or a pty "
                            f"(serve simulated units with `imu-station simulate`)", port) from None
        os.set_blocking(self._fd, False)
        self._hangup = select.poll()
        self._hangup.register(self._fd, select.POLLHUP | select.POLLERR | select.POLLNVAL)
        self._pending: list[np.ndarray] = []
        self._gathered: list[bytes] = []  # bytes read and not yet decoded (gather())
        self._gathered_bytes = 0
        self._slice = SLICE_BYTES[0]  # bytes decoded at once: grows to what decodes in a part of the budget
        self._log = MessageLog()
        self._monitor = LinkMonitor()
        self._error: DriverError | None = None
        self._closed = False

    def fileno(self) -> int:
        """The port's file descriptor, for a selector: readable when bytes arrived."""
        return self._fd

    @property
    def failed(self) -> DriverError | None:
        """The link's error once it broke (samples received before it may still wait in :meth:`read_now`)."""
        return self._error

    @property
    def backlog_bytes(self) -> int:
        """Bytes read from the port and not decoded yet (beyond a call's share they wait for the next)."""
        return self._gathered_bytes

    @property
    def message_count(self) -> int:
        """Messages other than samples received so far (a mark for :meth:`answer_since`)."""
        return self._log.count

    # -- reading -------------------------------------------------------------------------------

    def _read_port(self) -> None:
        """Read the bytes waiting at the port, at most ``READ_BUDGET_BYTES``, into the gathered
        bytes, without blocking or decoding.

        A read shorter than the tty's line buffer took all the line discipline held: the port is
        drained then, without the read that finds it empty (a read of an empty tty waits for the
        kernel to push what it still holds, and costs as much as a full one). Bytes that arrive
        meanwhile, or beyond the budget (a port that never runs dry), wait for the next call.
        """
        if self._error is not None or self._closed:
            return
        chunks = self._gathered
        got = False
        budget = READ_BUDGET_BYTES
        try:
            while budget > 0:
                data = os.read(self._fd, READ_CHUNK)
                if not data:
                    # pyserial's ports read nothing when nothing came (VMIN 0): only a hang-up says gone
                    if not got and self._hangup.poll(0):
                        raise OSError("hang-up")
                    break
                got = True
                chunks.append(data)
                self._gathered_bytes += len(data)
                budget -= len(data)
                if len(data) < LINE_BUFFER_BYTES:
                    break
                # a tty gives at most its line buffer (4 KiB) a read: read on
        except BlockingIOError:
            pass
        except OSError as exc:
            self._error = PortLost(f"{self.port}: the port went away ({exc}); every sample received before "
                                   f"was kept; check the cable or the simulator and capture again", self.port)

    def gather(self) -> int:
        """Read what the port has without decoding it (:meth:`read_now` decodes it, in one batch with
        what it reads then); the bytes gathered so far. An event loop that serves many ports reads
        each every turn, so that no port's buffer fills, and decodes a port's bytes less often."""
        self._read_port()
        return self._gathered_bytes

    def _decode_gathered(self) -> None:
        """Decode the bytes gathered so far, in one batch when they decode within ``DECODE_BUDGET_S``
        (clean frames always do), else in slices until the budget is spent: the rest waits for the
        next call, and a port whose rest passes ``FLOOD_BACKLOG_BYTES`` is dropped."""
        chunks = self._gathered
        if not chunks:
            return
        data = chunks[0] if len(chunks) == 1 else b"".join(chunks)
        deadline = perf_counter() + DECODE_BUDGET_S
        done = 0
        while done < len(data):
            piece = data if done == 0 and self._slice >= len(data) else data[done : done + self._slice]
            began = perf_counter()
            self._ingest(piece)
            now = perf_counter()
            done += len(piece)
            # the next slice: what these bytes say decodes in a quarter of the budget
            per_byte = max(now - began, 1e-7) / len(piece)
            self._slice = int(min(max(DECODE_BUDGET_S / 4 / per_byte, SLICE_BYTES[0]), SLICE_BYTES[1]))
            if now >= deadline:
                break
        rest = data[done:]
        self._gathered = [rest] if rest else []
        self._gathered_bytes = len(rest)
        if len(rest) > FLOOD_BACKLOG_BYTES and self._error is None:
            stats = self._monitor.stats
            self._error = PortFlooding(
                f"{self.port}: sends faster than the station can decode ({len(rest) // 1024} KiB waiting "
                f"after {stats.bytes // 1024} KiB decoded, {stats.samples} samples and {stats.garbage_bytes} "
                f"bytes of no frame in it); dropped so that the other units go on, every sample decoded "
                f"before was kept; check the unit's protocol and baud rate, and that it sends frames, "
                f"not noise", self.port)
            self._gathered, self._gathered_bytes = [], 0

    def _receive(self) -> None:
        """Read and decode every byte waiting at the port (and those gathered before), without blocking."""
        self._read_port()
        self._decode_gathered()

    def _ingest(self, data: bytes) -> None:
        decoded = self._decoder.feed(data)
        mon = self._monitor
        mon.add_bytes(len(data))
        mon.update_decoder(self._decoder.stats)
        if len(decoded.samples):
            mon.add_samples(decoded.samples)
            self._pending.append(decoded.samples)
        for message in decoded.messages:
            self._log.add(message)

    def read_now(self) -> np.ndarray:
        """Every sample received since the last read, reading what the port has without waiting.

        Raises the link's error once everything received before it was delivered.
        """
        self._receive()
        return self._take()

    def read_gathered(self) -> np.ndarray:
        """As :meth:`read_now`, without reading the port: the samples of the bytes :meth:`gather` read."""
        self._decode_gathered()
        return self._take()

    def _take(self) -> np.ndarray:
        if self._pending:
            batch = self._pending[0] if len(self._pending) == 1 else join_samples(self._pending)
            self._pending = []
            return batch
        if self._error is not None:
            raise type(self._error)(str(self._error), self._error.port)
        return EMPTY_SAMPLES

    def _wait_readable(self, timeout: float | None) -> None:
        if self._error is None and not self._closed:
            select.select([self._fd], [], [], timeout)

    def read(self, timeout: float | None = None) -> np.ndarray:
        """Every sample received since the last read, waiting up to ``timeout`` for the first bytes."""
        if not self._pending:
            self._wait_readable(timeout)
        return self.read_now()

    # -- commands ------------------------------------------------------------------------------

    def send(self, command_id: int, payload: bytes = b"") -> None:
        """Write a native command and return at once; its answer arrives with later reads
        (:meth:`answer_since`). A write that fails breaks the link (:attr:`failed`)."""
        if self.protocol != "native":
            raise unsupported(self.port, self.protocol, command_id)
        if self._error is not None or self._closed:
            return
        frame = native.encode_frame(command_id, payload)
        try:
            # A command frame is far smaller than a port's output buffer, so it goes whole or, on a
            # port still sending, not at all: then no answer comes, and the caller sends it again.
            os.write(self._fd, frame)
        except BlockingIOError:
            pass
        except OSError as exc:
            self._error = PortLost(f"{self.port}: writing to the port failed ({exc}); check the cable or "
                                   f"the simulator", self.port)

    def answer_since(self, command_id: int, mark: int) -> Message | None:
        """The answer to ``command_id`` among the messages after ``mark`` (:attr:`message_count`
        when it was sent), or None; an ACK with an error status raises ``CommandRejected``."""
        return self._log.answer_since(command_id, mark, self.port)

    def command(self, command_id: int, payload: bytes = b"", timeout: float = 1.0,
                retries: int = 2) -> Message:
        """Send a native command and wait for its answer (resent on timeout); samples that arrive
        meanwhile wait for the next read."""
        for _ in range(retries + 1):
            mark = self._log.count
            self.send(command_id, payload)
            deadline = time.monotonic() + timeout
            while True:
                self._receive()
                answer = self.answer_since(command_id, mark)
                if answer is not None:
                    return answer
                if self._error is not None:
                    raise type(self._error)(str(self._error), self._error.port)
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._wait_readable(left)
        raise no_answer(self.port, self.protocol, command_id, retries + 1, timeout)

    def get_info(self, timeout: float = 1.0, retries: int = 2) -> dict[str, Any]:
        """Ask the unit who it is (GET_INFO): serial, model, firmware, rate_hz."""
        return native.parse_device_info(self.command(native.GET_INFO, b"", timeout, retries).payload)

    def restart(self, timeout: float = 1.0) -> None:
        """Restart the unit as at power-up (RESTART), sent once, never resent (see
        :meth:`SerialDevice.restart <drivers.serial_device.SerialDevice.restart>`)."""
        self.command(native.RESTART, b"", timeout, retries=0)

    def set_rate(self, rate_hz: int, timeout: float = 1.0) -> None:
        """Set the output data rate (SET_RATE); raises ``CommandRejected`` if the unit refuses it or the
        rate does not fit the command."""
        self.command(native.SET_RATE, set_rate_payload(self.port, rate_hz), timeout)

    def start(self, timeout: float = 1.0) -> None:
        """Start streaming samples (START_STREAM)."""
        self.command(native.START_STREAM, b"", timeout)

    def stop(self, timeout: float = 1.0) -> None:
        """Stop streaming samples (STOP_STREAM)."""
        self.command(native.STOP_STREAM, b"", timeout)

    # -- state ---------------------------------------------------------------------------------

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link statistics (a copy: later samples do not change it)."""
        return LinkStats(**vars(self._monitor.stats))

    @property
    def info(self) -> dict[str, Any]:
        """The last DEVICE_INFO the unit sent (empty until it sent one)."""
        return dict(self._log.info)

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    def close(self) -> None:
        """Release the port; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._serial.close()
        except (serial.SerialException, OSError):
            pass
