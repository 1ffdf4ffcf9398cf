"""Serving an instrument emulator on a raw pseudo-terminal or a loopback TCP port.

An emulator is anything with ``feed(data: bytes) -> bytes``: the bytes a host sent in, its answer
out (it frames its own protocol, as :class:`mocks.device.SimDevice` does). :class:`ByteServer`
pumps bytes between one link and the emulator in a thread, and injects the faults a driver must
survive: a silent instrument (nothing answered), garbage (the answer's bytes scrambled), a link
lost mid-run (the pty or the connection closed).

Emulators that use a library's own server (pymodbus for Modbus) serve themselves; they still take
``host`` and ``port`` 0 (a free port on loopback) and report their URL the same way.
"""

from __future__ import annotations

import contextlib
import os
import random
import select
import socket
import threading
from typing import Protocol, Self

from mocks.raw_pty import open_serving_pty


class Emulator(Protocol):
    """What a :class:`ByteServer` serves."""

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host in; the emulator's answer out (b'' when it has none yet)."""
        ...


class ByteServer:
    """One emulator on a pty (``transport="pty"``) or a loopback TCP port (``"tcp"``), in a thread.

    Parameters
    ----------
    emulator : Emulator
        What answers.
    transport : str
        ``pty`` or ``tcp``.
    host : str
        The loopback address a TCP server listens on (never another).

    Attributes
    ----------
    address : str
        The pty's path, or ``127.0.0.1:PORT``.
    silent, garbage : bool
        Faults: answer nothing, or scramble every answer.
    """

    def __init__(self, emulator: Emulator, transport: str = "pty", host: str = "127.0.0.1"):
        if transport not in ("pty", "tcp"):
            raise ValueError(f"transport is pty or tcp, not {transport!r}")
        if not host.startswith("127.") and host != "::1":
            raise ValueError("an emulator listens on loopback only")
        self.emulator = emulator
        self.transport = transport
        self.host = host
        self.address = ""
        self.silent = False
        self.garbage = False
        self.received = 0
        self._random = random.Random(0)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._listener: socket.socket | None = None
        self._conns: list[socket.socket] = []
        self._lock = threading.Lock()
        self.error: BaseException | None = None

    def start(self) -> Self:
        """Open the pty or the listening socket and serve it; returns self."""
        if self.transport == "pty":
            self._master, self.address = open_serving_pty()
        else:
            self._listener = socket.create_server((self.host, 0))
            self._listener.setblocking(False)
            self.address = f"{self.host}:{self._listener.getsockname()[1]}"
        self._thread = threading.Thread(target=self._run, name=f"emulator-{self.transport}", daemon=True)
        self._thread.start()
        return self

    def _answer(self, data: bytes) -> bytes:
        with self._lock:
            self.received += len(data)
            reply = self.emulator.feed(data)
        if self.silent:
            return b""
        if self.garbage and reply:
            return bytes(self._random.randrange(256) for _ in reply)
        return reply

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._master is not None:
                    self._serve_pty()
                else:
                    self._serve_tcp()
        except BaseException as exc:  # noqa: BLE001 - kept for stop() to raise in the test's thread
            self.error = exc

    def _serve_pty(self) -> None:
        master = self._master
        assert master is not None
        ready, _, _ = select.select([master], [], [], 0.05)
        if not ready:
            return
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            return
        except OSError:  # EIO: nobody has the port open now; wait for the next host
            self._stop.wait(0.02)
            return
        reply = self._answer(data)
        if reply:
            with contextlib.suppress(OSError):
                os.write(master, reply)

    def _serve_tcp(self) -> None:
        listener = self._listener
        assert listener is not None
        ready, _, _ = select.select([listener, *self._conns], [], [], 0.05)
        for sock in ready:
            if sock is listener:
                with contextlib.suppress(BlockingIOError):
                    conn, _ = listener.accept()
                    conn.setblocking(False)
                    self._conns.append(conn)
                continue
            try:
                data = sock.recv(4096)
            except BlockingIOError:
                continue
            except OSError:
                data = b""
            if not data:
                self._conns.remove(sock)
                sock.close()
                continue
            reply = self._answer(data)
            if reply:
                with contextlib.suppress(OSError):
                    sock.setblocking(True)
                    sock.sendall(reply)
                    sock.setblocking(False)

    def drop_link(self) -> None:
        """A link lost mid-run: close the pty or every connection (the server stops answering)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._close()

    def _close(self) -> None:
        if self._master is not None:
            with contextlib.suppress(OSError):
                os.close(self._master)
            self._master = None
        for conn in self._conns:
            with contextlib.suppress(OSError):
                conn.close()
        self._conns.clear()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
            self._listener = None

    def stop(self) -> None:
        """Stop serving and close everything; raises what the serving thread failed with."""
        self.drop_link()
        if self.error is not None:
            raise RuntimeError("the emulator's server failed") from self.error

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
