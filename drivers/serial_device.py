"""A device on a serial port, a pseudo-terminal or a pyserial URL (``sim://``, ``loop://``, ...).

A reader thread reads bytes as they come, feeds the protocol decoder and appends the decoded
sample batches to a buffer bounded in samples; the consumer takes everything buffered with
:meth:`SerialDevice.read`. When the consumer falls behind and the buffer is full, new batches
are dropped and counted (``overflow_drops``): the reader never waits for the consumer, so the
OS buffer of the port never overflows silently. Commands are written from the caller's thread
and wait for their answer, which the reader picks out of the stream between samples.
"""

from __future__ import annotations

import errno
import threading
import time
from collections import deque
from typing import Any

import numpy as np
import serial

from drivers.errors import (
    CommandRejected,
    DriverError,
    PortBusy,
    PortError,
    PortLost,
    PortNotFound,
    PortPermission,
)
from drivers.interface import Device
from drivers.link_stats import LinkMonitor, LinkStats
from drivers.message_log import MessageLog, no_answer, unsupported
from protocols import native
from protocols.base import EMPTY_SAMPLES, Message
from protocols.registry import make_decoder

DEFAULT_BAUDRATE = 921_600  # 1 kHz of 47-byte frames needs 470 kbit/s
DEFAULT_MAX_BUFFERED = 200_000  # samples (8 MB): minutes of data at 1 kHz before anything drops
READ_CHUNK = 65_536
READ_TIMEOUT_S = 0.05
LIST_PORTS_HINT = "list the ports with `imu-station ports`"


def open_serial(port: str, baudrate: int = DEFAULT_BAUDRATE, exclusive: bool = True) -> serial.SerialBase:
    """Open ``port`` (a device path or a pyserial URL) and turn pyserial's errors into ours."""
    is_url = "://" in port
    kwargs: dict[str, Any] = {"baudrate": baudrate, "timeout": READ_TIMEOUT_S, "write_timeout": 1.0}
    if exclusive and not is_url:
        kwargs["exclusive"] = True
    try:
        return serial.serial_for_url(port, **kwargs)
    except ValueError as exc:
        if is_url and "not known" in str(exc):
            scheme = port.split("://", 1)[0]
            raise PortNotFound(f"{port}: no handler for URL scheme '{scheme}://'; use a device path, "
                               f"a pyserial URL such as loop://, or sim:// (the simulated unit)",
                               port) from None
        raise PortError(f"{port}: cannot open: {exc}", port) from None
    except serial.SerialException as exc:
        code = exc.errno
        text = str(exc)
        if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
            raise PortNotFound(f"{port}: no such port; check the cable and the name ({LIST_PORTS_HINT})",
                               port) from None
        if code in (errno.EACCES, errno.EPERM):
            raise PortPermission(f"{port}: permission denied; add your user to the group owning the "
                                 f"port (e.g. `sudo usermod -aG dialout $USER`, then log in again)",
                                 port) from None
        if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK) or "exclusively lock" in text:
            raise PortBusy(f"{port}: busy, another program has it open; close that program "
                           f"(`fuser -v {port}` shows which) and try again", port) from None
        raise PortError(f"{port}: cannot open: {text}", port) from None


def set_rate_payload(port: str, rate_hz: int) -> bytes:
    """SET_RATE's payload for ``rate_hz``; ``CommandRejected`` (bad argument) for a rate its 16 bits
    cannot hold, before anything is sent."""
    if not 1 <= rate_hz <= 0xFFFF:
        raise CommandRejected(f"{port}: rate {rate_hz} Hz does not fit SET_RATE (1..65535 Hz)", port,
                              native.ACK_BAD_ARGUMENT)
    return rate_hz.to_bytes(2, "little")


class SerialDevice(Device):
    """An IMU on a serial link, read by a background thread.

    Parameters
    ----------
    port:
        Device path (``/dev/ttyUSB0``, a pty such as ``/dev/pts/5``) or pyserial URL (``sim://``).
    protocol:
        Decoder name from ``protocols.registry``. Commands exist for ``native`` only. The device's
        ``protocol`` is this name, but ``frame:<name>`` (the description's) for ``frame:FILE.yaml``.
    baudrate:
        Line speed; ignored by pseudo-terminals and most URLs.
    max_buffered_samples:
        Bound of the buffer between the reader and the consumer; beyond it batches are dropped
        and counted in ``stats.overflow_drops``.
    exclusive:
        Take an exclusive lock on the port where the OS supports it (a second opener gets PortBusy).
    instances:
        Decode every IMU instance of a board of several (``protocols.instances``): :meth:`read` gives
        instance 0, :meth:`take_instances` the others (buffered under the same bound). A protocol that
        carries one IMU raises ``DriverError`` before the port is opened.
    """

    def __init__(self, port: str, protocol: str = "native", baudrate: int = DEFAULT_BAUDRATE,
                 max_buffered_samples: int = DEFAULT_MAX_BUFFERED, exclusive: bool = True,
                 instances: bool = False):
        self.port = port
        self._decoder = make_decoder(protocol)
        # instance -> batches not yet taken; None: the decoder makes one stream (nothing else is kept)
        self._instances: dict[int, list[np.ndarray]] | None = None
        self._instances_count = 0
        if instances:
            enable = getattr(self._decoder, "decode_instances", None)
            if enable is None:
                raise DriverError(f"{port}: the {protocol} protocol carries one IMU; several IMU instances "
                                  f"come over mavlink or a frame description whose fields give imu: k", port)
            try:
                enable()
            except ValueError as exc:
                raise DriverError(f"{port}: {exc}", port) from None
            self._instances = {}
        # What captures record: ``frame:<description name>`` for a frame description, else as given.
        self.protocol = self._decoder.label or protocol
        self._max_buffered = max_buffered_samples
        self._serial = open_serial(port, baudrate, exclusive)
        self._cond = threading.Condition()
        self._pending: deque[np.ndarray] = deque()
        self._pending_count = 0
        self._log = MessageLog()
        self._monitor = LinkMonitor()
        self._error: DriverError | None = None
        self._closed = False
        self._stop = threading.Event()
        self._write_lock = threading.Lock()
        self._thread = threading.Thread(target=self._reader, name=f"imu-reader {port}", daemon=True)
        self._thread.start()

    # -- the reader thread ---------------------------------------------------------------------

    def _reader(self) -> None:
        ser = self._serial
        try:
            while not self._stop.is_set():
                data = ser.read(1)
                if not data:
                    continue
                waiting = ser.in_waiting
                if waiting:
                    data += ser.read(min(waiting, READ_CHUNK))
                self._ingest(data)
        except (serial.SerialException, OSError) as exc:
            if not self._stop.is_set():
                self._fail(PortLost(f"{self.port}: the port went away ({exc}); every sample received "
                                    f"before was kept; check the cable or the simulator and capture again",
                                    self.port))
        except Exception as exc:  # a bug must not leave the consumer waiting forever
            self._fail(DriverError(f"{self.port}: the reader stopped on an internal error: {exc!r}",
                                   self.port))
            raise

    def _ingest(self, data: bytes) -> None:
        decoded = self._decoder.feed(data)
        samples = decoded.samples
        with self._cond:
            mon = self._monitor
            mon.add_bytes(len(data))
            mon.update_decoder(self._decoder.stats)
            if len(samples):
                mon.add_samples(samples)
                if self._pending_count + len(samples) > self._max_buffered:
                    mon.add_overflow(len(samples))
                else:
                    self._pending.append(samples)
                    self._pending_count += len(samples)
            for message in decoded.messages:
                self._log.add(message)
            if self._instances is not None:
                self._keep_instances(decoded)
            if len(samples) or decoded.messages:
                self._cond.notify_all()

    def _keep_instances(self, decoded: Any) -> None:
        """Buffer the other instances' batches of ``decoded`` (under the lock), bounded as the samples are."""
        assert self._instances is not None
        for instance, batch in getattr(decoded, "instances", {}).items():
            if not len(batch):
                continue
            if self._instances_count + len(batch) > self._max_buffered:
                self._monitor.add_overflow(len(batch))
                continue
            self._instances.setdefault(instance, []).append(batch)
            self._instances_count += len(batch)

    def _fail(self, error: DriverError) -> None:
        with self._cond:
            if self._error is None:
                self._error = error
            self._cond.notify_all()

    def _raise_error(self) -> None:
        err = self._error
        assert err is not None
        # A fresh exception each time: the same error may reach several callers.
        raise type(err)(str(err), err.port)

    # -- the consumer side ---------------------------------------------------------------------

    def read(self, timeout: float | None = None) -> np.ndarray:
        """Every sample received since the last read, as one batch (empty on timeout).

        Raises the link's error once everything received before it was read (``Device.read``).
        """
        with self._cond:
            if not self._pending and self._error is None and not self._closed:
                self._cond.wait_for(lambda: self._pending or self._error is not None or self._closed, timeout)
            if self._pending:
                batch = self._pending[0] if len(self._pending) == 1 else np.concatenate(self._pending)
                self._pending.clear()
                self._pending_count = 0
                return batch
            if self._error is not None:
                self._raise_error()
            return EMPTY_SAMPLES

    def take_instances(self) -> dict[int, np.ndarray]:
        """The other IMU instances' samples received since the last call, by instance (``Device``)."""
        with self._cond:
            if not self._instances:
                return {}
            out = {k: b[0] if len(b) == 1 else np.concatenate(b) for k, b in self._instances.items()}
            self._instances = {}
            self._instances_count = 0
            return out

    @property
    def imu_instances(self) -> dict[int, int]:
        """The IMU instances the unit streams, with the samples seen of each (``Device``)."""
        seen = getattr(self._decoder, "instances_seen", None)
        return dict(seen) if seen is not None else {}

    @property
    def imu_instance(self) -> int | None:
        """The IMU instance :meth:`read` delivers, when the protocol tells instances apart (``Device``)."""
        return getattr(self._decoder, "instance", None)

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link statistics (a copy: later samples do not change it)."""
        with self._cond:
            return LinkStats(**vars(self._monitor.stats))

    @property
    def decoder_problem(self) -> str | None:
        """What the decoder found wrong with the stream as a whole, or None: a frame description whose
        checksum most frames fail (``protocols.frame.FrameDecoder.problem``; other decoders find none)."""
        return getattr(self._decoder, "problem", None)

    @property
    def info(self) -> dict[str, Any]:
        """The last DEVICE_INFO the unit sent (empty until it sent one)."""
        with self._cond:
            return dict(self._log.info)

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    @property
    def transport(self) -> serial.SerialBase:
        """The pyserial port underneath (for diagnostics; the reader thread owns its reads)."""
        return self._serial

    # -- commands ------------------------------------------------------------------------------

    def get_info(self, timeout: float = 1.0, retries: int = 2) -> dict[str, Any]:
        """Ask the unit who it is (GET_INFO): serial, model, firmware, rate_hz.

        Parameters
        ----------
        timeout : seconds to wait for the answer to each try.
        retries : tries after the first when no answer comes.
        """
        message = self.command(native.GET_INFO, b"", timeout, retries)
        return native.parse_device_info(message.payload)

    def set_rate(self, rate_hz: int, timeout: float = 1.0, retries: int = 2) -> None:
        """Set the output data rate (SET_RATE); raises ``CommandRejected`` if the unit refuses it."""
        self.command(native.SET_RATE, set_rate_payload(self.port, rate_hz), timeout, retries)

    def start(self, timeout: float = 1.0, retries: int = 2) -> None:
        """Start streaming samples (START_STREAM)."""
        self.command(native.START_STREAM, b"", timeout, retries)

    def stop(self, timeout: float = 1.0, retries: int = 2) -> None:
        """Stop streaming samples (STOP_STREAM)."""
        self.command(native.STOP_STREAM, b"", timeout, retries)

    def restart(self, timeout: float = 1.0) -> None:
        """Restart the unit as at power-up (RESTART): its ``seq`` and ``t_us`` start again from 0,
        its turn-on biases are new and it streams at its power-up rate. Sent once, never resent (a
        second RESTART would restart it again); a unit that cannot restart raises ``CommandRejected``
        with status ``ACK_UNKNOWN`` (power-cycle it by hand instead)."""
        self.command(native.RESTART, b"", timeout, retries=0)

    def command(self, command_id: int, payload: bytes = b"", timeout: float = 1.0,
                retries: int = 2) -> Message:
        """Send any native command and wait for its answer: DEVICE_INFO for GET_INFO, else the ACK
        that names ``command_id``. Resent on timeout (the spec's commands are idempotent); an ACK
        with an error status raises ``CommandRejected``."""
        if self.protocol != "native":
            raise unsupported(self.port, self.protocol, command_id)
        frame = native.encode_frame(command_id, payload)
        for _ in range(retries + 1):
            with self._cond:
                if self._closed:
                    raise DriverError(f"{self.port}: the device is closed", self.port)
                if self._error is not None:
                    self._raise_error()
                mark = self._log.count
            self._write(frame)
            answer = self._wait_answer(command_id, mark, time.monotonic() + timeout)
            if answer is not None:
                return answer
        raise no_answer(self.port, self.protocol, command_id, retries + 1, timeout)

    def _wait_answer(self, command_id: int, mark: int, deadline: float) -> Message | None:
        with self._cond:
            while True:
                found = self._log.answer_since(command_id, mark, self.port)
                if found is not None:
                    return found
                if self._error is not None:
                    self._raise_error()
                left = deadline - time.monotonic()
                if left <= 0 or self._closed:
                    return None
                self._cond.wait(left)

    def _write(self, frame: bytes) -> None:
        try:
            with self._write_lock:
                self._serial.write(frame)
                self._serial.flush()
        except (serial.SerialException, OSError) as exc:
            self._fail(PortLost(f"{self.port}: writing to the port failed ({exc}); check the cable or the "
                                f"simulator", self.port))
            self._raise_error()

    # -- closing -------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the reader thread and release the port; safe to call twice."""
        if self._closed:
            return
        self._stop.set()
        cancel = getattr(self._serial, "cancel_read", None)
        if cancel is not None:
            try:
                cancel()
            except (serial.SerialException, OSError, NotImplementedError):
                pass
        self._thread.join(timeout=2.0)
        try:
            self._serial.close()
        except (serial.SerialException, OSError):
            pass
        with self._cond:
            self._closed = True
            self._cond.notify_all()

