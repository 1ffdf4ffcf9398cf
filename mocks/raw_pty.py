"""Raw pseudo-terminals: the serial ports the simulators serve and the tests write into."""

from __future__ import annotations

import fcntl
import os
import threading
import tty
from typing import Self


def open_raw_pty() -> tuple[int, int, str]:
    """A pty with both ends raw (no echo, no line editing): ``(master, slave, slave path)``."""
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def open_serving_pty() -> tuple[int, str]:
    """A raw pty for a simulator: ``(non-blocking master, port path)``.

    The slave end is closed at once: the host opens the path; EIO on the master then says nobody
    has it open.
    """
    master, slave, path = open_raw_pty()
    os.close(slave)
    fcntl.fcntl(master, fcntl.F_SETFL, fcntl.fcntl(master, fcntl.F_GETFL) | os.O_NONBLOCK)
    return master, path


class PtyService:
    """A simulator that answers on a raw pty from its own thread; ``with`` starts and stops it.

    A subclass opens the pty in ``start`` (then calls :meth:`_start_thread`) and serves it in
    ``_run``, keeping in ``self._error`` what its thread failed with, for :meth:`stop` to raise.
    """

    THREAD_NAME = "pty-service"
    FAILED = "the pty service failed"

    def __init__(self) -> None:
        self.port_path = ""
        self._master = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: BaseException | None = None

    def start(self) -> Self:
        """Open the pty and start serving it in a thread; returns self (each subclass its own)."""
        raise NotImplementedError

    def _run(self) -> None:
        raise NotImplementedError

    def _start_thread(self) -> None:
        self._thread = threading.Thread(target=self._run, name=self.THREAD_NAME, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread, close the pty, and raise what the thread failed with, if anything."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._close_master()
        if self._error is not None:
            error, self._error = self._error, None
            raise RuntimeError(self.FAILED) from error

    def _close_master(self) -> None:
        if self._master >= 0:
            os.close(self._master)
            self._master = -1

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
