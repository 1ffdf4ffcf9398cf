"""Raw pseudo-terminals: the serial ports the simulators serve and the tests write into."""

from __future__ import annotations

import fcntl
import os
import tty


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
