"""The byte links instruments answer on: a TCP socket (plain sockets, as SCPI's raw port 5025 and
simserv's 2049 want) or a serial port (pyserial: a device path or a pyserial URL).

Plain sockets and pyserial rather than pyvisa: every instrument here speaks lines over one of
the two, a socket needs no VISA layer, and pyserial is already how the station opens the unit.

A link reads a reply up to its terminator, or, for controllers that end nothing (Korad), until the
line has been quiet a while; it never blocks past its timeout, and a link that went away is an
:class:`~drivers.instruments.errors.InstrumentLost` naming the instrument.
"""

from __future__ import annotations

import contextlib
import select
import socket
import time
from abc import ABC, abstractmethod

import serial

from drivers.errors import DriverError
from drivers.instruments.errors import InstrumentError, InstrumentLost, InstrumentTimeout
from drivers.serial_device import open_serial

MAX_REPLY_BYTES = 4096


class Link(ABC):
    """Bytes to and from one instrument."""

    def __init__(self, name: str):
        self.name = name
        self._pending = b""  # bytes read past the last reply's terminator

    @abstractmethod
    def write(self, data: bytes) -> None:
        """Send ``data`` whole."""

    @abstractmethod
    def _read_some(self, timeout_s: float) -> bytes:
        """What has arrived within ``timeout_s`` (b'' when nothing); raises InstrumentLost at EOF."""

    @abstractmethod
    def close(self) -> None:
        """Close the link (idempotent)."""

    def read_reply(self, end: bytes, timeout_s: float, quiet_s: float) -> bytes:
        """One reply, without its terminator ``end``; with ``end`` empty, what arrives until the line
        is quiet for ``quiet_s``.

        Raises
        ------
        InstrumentTimeout
            Nothing complete within ``timeout_s`` (what did arrive is in the message).
        """
        deadline = time.monotonic() + timeout_s
        data = bytearray(self._pending)
        self._pending = b""
        while True:
            if end:
                at = data.find(end)
                if at >= 0:
                    self._pending = bytes(data[at + len(end):])
                    return bytes(data[:at])
            left = deadline - time.monotonic()
            if left <= 0:
                if not end and data:
                    return bytes(data)
                raise InstrumentTimeout(f"{self.name}: no complete reply within {timeout_s:g} s"
                                        + (f" (got {bytes(data)!r})" if data else ""), self.name,
                                        reply=bytes(data).decode("latin-1"))
            chunk = self._read_some(min(left, quiet_s) if not end and data else left)
            if not chunk and not end and data:
                return bytes(data)
            data += chunk
            if len(data) > MAX_REPLY_BYTES:
                raise InstrumentError(f"{self.name}: a reply longer than {MAX_REPLY_BYTES} bytes without its "
                                      f"terminator {end!r}: check the description's read_end", self.name,
                                      reply=bytes(data[:80]).decode("latin-1"))

    def drain(self) -> bytes:
        """Discard whatever arrived and was not read (a late reply before a retry)."""
        data = self._pending + self._read_some(0.0)
        self._pending = b""
        return data


class SocketLink(Link):
    """A TCP connection (``HOST:PORT``)."""

    def __init__(self, host: str, port: int, name: str, connect_timeout_s: float = 3.0):
        super().__init__(name)
        try:
            self._sock = socket.create_connection((host, port), timeout=connect_timeout_s)
        except OSError as exc:
            raise InstrumentLost(f"{name}: cannot connect to {host}:{port} ({exc.strerror or exc}); check "
                                 "the address, that the instrument is on and its remote interface enabled",
                                 name) from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock.setblocking(False)

    def write(self, data: bytes) -> None:
        """Send ``data`` whole."""
        try:
            self._sock.setblocking(True)
            self._sock.settimeout(2.0)
            self._sock.sendall(data)
        except OSError as exc:
            raise InstrumentLost(f"{self.name}: the connection failed while sending ({exc})",
                                 self.name) from None
        finally:
            with contextlib.suppress(OSError):
                self._sock.setblocking(False)

    def _read_some(self, timeout_s: float) -> bytes:
        try:
            ready, _, _ = select.select([self._sock], [], [], max(timeout_s, 0.0))
            if not ready:
                return b""
            chunk = self._sock.recv(MAX_REPLY_BYTES)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise InstrumentLost(f"{self.name}: the connection failed ({exc})", self.name) from None
        if not chunk:
            raise InstrumentLost(f"{self.name}: the instrument closed the connection", self.name)
        return chunk

    def close(self) -> None:
        """Close the socket."""
        with contextlib.suppress(OSError):
            self._sock.close()


class SerialLink(Link):
    """A serial port: a device path or a pyserial URL."""

    def __init__(self, port: str, baud: int, name: str):
        super().__init__(name)
        try:
            self._port = open_serial(port, baud, exclusive=True)
        except DriverError as exc:
            raise InstrumentLost(f"{name}: {exc}", name) from None
        self._port.timeout = 0

    def write(self, data: bytes) -> None:
        """Send ``data`` whole."""
        try:
            self._port.write(data)
            self._port.flush()
        except (serial.SerialException, OSError) as exc:
            raise InstrumentLost(f"{self.name}: the port failed while sending ({exc})", self.name) from None

    def _read_some(self, timeout_s: float) -> bytes:
        deadline = time.monotonic() + max(timeout_s, 0.0)
        try:
            while True:
                chunk = self._port.read(self._port.in_waiting or 1)
                if chunk or time.monotonic() >= deadline:
                    return bytes(chunk)
                fileno = getattr(self._port, "fileno", None)
                if fileno is not None and getattr(self._port, "fd", None) is not None:
                    select.select([fileno()], [], [], max(0.0, min(0.05, deadline - time.monotonic())))
                else:
                    time.sleep(min(0.002, max(0.0, deadline - time.monotonic())))
        except (serial.SerialException, OSError) as exc:
            raise InstrumentLost(f"{self.name}: the port failed ({exc}); check the cable",
                                 self.name) from None

    def close(self) -> None:
        """Close the port."""
        with contextlib.suppress(serial.SerialException, OSError):
            self._port.close()


def is_network_target(target: str) -> bool:
    """True for ``HOST`` or ``HOST:PORT``, False for a device path or a pyserial URL."""
    return not (target.startswith("/") or "://" in target or target.upper().startswith("COM"))


def split_host(target: str, default_port: int | None, name: str) -> tuple[str, int]:
    """``HOST[:PORT]`` as (host, port), ``[v6]:PORT`` too."""
    single = target.count(":") == 1 or target.startswith("[")
    host, _, port = target.rpartition(":") if single else (target, "", "")
    if not host:
        host, port = target, ""
    host = host.strip("[]")
    if not port:
        if default_port is None:
            raise InstrumentError(f"{name}: give the port, HOST:PORT", name)
        return host, default_port
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise InstrumentError(f"{name}: port {port!r} is not a TCP port (1..65535)", name)
    return host, int(port)
