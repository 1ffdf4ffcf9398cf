"""A motorized turntable / two-axis rate table on a serial port, over its own line protocol.

The protocol (ASCII, one command per line ending in ``\\n``, 115200 8N1; every command gets
exactly one reply line)::

    ID?                      -> ID <model>,<serial>,<firmware>
    HOME                     -> OK                 move to +z up, azimuth 0
    POSE <up>                -> OK                 move so sensor axes <up> point up (+z, -x, +x+y)
    ROT <axis> <deg> <dps>   -> OK                 turn <deg> (signed, up to 3600) at <dps> about the
                                                   sensor axis <axis> (+x ... -z), held vertical
    SPIN <axis> <dps> <s>    -> OK                 turn at <dps> (signed) about the sensor axis <axis> held
                                                   vertical for <s> seconds once the rate is steady, then stop
    STATE?                   -> STATE <IDLE|MOVING|FAULT> <up> <turned_deg>
    STOP                     -> OK                 stop at once (decelerating)
    anything refused         -> ERR <code> <text>  1 unknown command, 2 bad argument,
                                                   3 busy (moving), 4 fault (limit, drive)

The table's controller knows how the unit is mounted on it and does its own kinematics, so
the station speaks in sensor axes. Motion commands return at once; ``STATE?`` says when the
table is still again. A motion command sent while the table moves is refused with ``ERR 3``:
:meth:`Turntable.pose` and :meth:`Turntable.rotate` wait for IDLE first.
"""

from __future__ import annotations

import re
import termios
import time
from dataclasses import dataclass

import serial

from drivers.errors import CommandRejected, CommandTimeout, DriverError, PortLost
from drivers.serial_device import open_serial

BAUDRATE = 115_200
REPLY_TIMEOUT_S = 1.0
_POSE_RE = re.compile(r"^(?:[+-][xyz]){1,3}$")
_AXIS_RE = re.compile(r"^[+-][xyz]$")
ERR_UNKNOWN, ERR_ARGUMENT, ERR_BUSY, ERR_FAULT = 1, 2, 3, 4


@dataclass(frozen=True)
class TableState:
    """The table's answer to STATE?: its state, the sensor axis pointing up, the angle turned.

    Parameters
    ----------
    state : IDLE, MOVING or FAULT.
    up : the signed axes pointing up, e.g. ``+z`` or ``+x+y``.
    turned_deg : the angle of the current (or last) turn, degrees.
    """

    state: str
    up: str
    turned_deg: float

    @property
    def idle(self) -> bool:
        """True when the table is still and takes a new move."""
        return self.state == "IDLE"


class TableFault(DriverError):
    """The table reports a fault (limit switch, drive error): someone must look at it."""

    def __init__(self, message: str, port: str = "", status: int = 0):
        super().__init__(message, port)
        self.status = status


class Turntable:
    """The table at ``port`` (device path, pty or pyserial URL). Use as a context manager."""

    def __init__(self, port: str, baudrate: int = BAUDRATE, reply_timeout_s: float = REPLY_TIMEOUT_S):
        self.port = port
        self.reply_timeout_s = reply_timeout_s
        self._serial = open_serial(port, baudrate)
        self._buffer = b""

    def close(self) -> None:
        """Release the port."""
        self._serial.close()

    def __enter__(self) -> Turntable:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- the wire ---------------------------------------------------------------------------------

    def command(self, line: str) -> str:
        """Send one command line, return its reply line; ``ERR`` replies raise ``CommandRejected``."""
        try:
            self._serial.reset_input_buffer()
            self._buffer = b""
            self._serial.write(line.encode("ascii") + b"\n")
            reply = self._readline()
        except (serial.SerialException, OSError, termios.error) as exc:
            raise PortLost(f"{self.port}: turntable link lost ({exc}); check its cable and power",
                           self.port) from None
        if reply.startswith("ERR"):
            parts = reply.split(" ", 2)
            code = int(parts[1]) if len(parts) > 1 and parts[1].isdigit() else 0
            text = parts[2] if len(parts) > 2 else reply
            cls = TableFault if code == ERR_FAULT else CommandRejected
            raise cls(f"{self.port}: turntable refused {line!r}: {text}", self.port, status=code)
        return reply

    def _readline(self) -> str:
        deadline = time.monotonic() + self.reply_timeout_s
        while b"\n" not in self._buffer:
            if time.monotonic() > deadline:
                raise CommandTimeout(f"{self.port}: the turntable did not answer in "
                                     f"{self.reply_timeout_s:g} s; check that it is powered, its port and "
                                     f"its baud rate ({BAUDRATE})", self.port)
            chunk = self._serial.read(self._serial.in_waiting or 1)
            self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b"\n")
        return line.decode("ascii", "replace").strip()

    # ---- commands ------------------------------------------------------------------------------------

    def identify(self) -> dict[str, str]:
        """Ask the table who it is (ID?): ``model``, ``serial`` and ``firmware``."""
        reply = self.command("ID?")
        if not reply.startswith("ID "):
            raise CommandRejected(f"{self.port}: unexpected answer to ID?: {reply!r}; is this a turntable "
                                  "speaking the imu-station table protocol?", self.port)
        fields = (reply[3:].split(",") + ["", "", ""])[:3]
        return dict(zip(("model", "serial", "firmware"), fields, strict=True))

    def state(self) -> TableState:
        """Ask where the table is (STATE?); a table in FAULT raises :class:`TableFault`."""
        reply = self.command("STATE?")
        parts = reply.split()
        if len(parts) != 4 or parts[0] != "STATE":
            raise CommandRejected(f"{self.port}: unexpected answer to STATE?: {reply!r}", self.port)
        state = TableState(parts[1], parts[2], float(parts[3]))
        if state.state == "FAULT":
            raise TableFault(f"{self.port}: the turntable is in FAULT; clear it at the table, then rerun",
                             self.port)
        return state

    def wait_idle(self, timeout_s: float = 30.0, poll_s: float = 0.05) -> TableState:
        """Poll STATE? every ``poll_s`` until the table is idle; ``CommandTimeout`` after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while True:
            state = self.state()
            if state.idle:
                return state
            if time.monotonic() > deadline:
                raise CommandTimeout(f"{self.port}: the turntable is still moving after {timeout_s:g} s",
                                     self.port)
            time.sleep(poll_s)

    def home(self, timeout_s: float = 30.0) -> None:
        """Start the move to the home pose, once the table is idle (returns at once)."""
        self.wait_idle(timeout_s)
        self.command("HOME")

    def pose(self, up: str, timeout_s: float = 30.0) -> None:
        """Start the move to pose ``up`` (returns at once, once the table accepted it)."""
        if not _POSE_RE.match(up):
            raise ValueError(f"pose {up!r} is not signed axes like '+z' or '+x+y'")
        self.wait_idle(timeout_s)
        self.command(f"POSE {up}")

    def rotate(self, axis: str, angle_deg: float, rate_dps: float, timeout_s: float = 30.0) -> None:
        """Start a turn of ``angle_deg`` about sensor ``axis`` held vertical (returns at once)."""
        if not _AXIS_RE.match(axis):
            raise ValueError(f"axis {axis!r} is not one of +x, -x, +y, -y, +z, -z")
        self.wait_idle(timeout_s)
        self.command(f"ROT {axis} {angle_deg:g} {rate_dps:g}")

    def spin(self, axis: str, rate_dps: float, duration_s: float, timeout_s: float = 30.0) -> None:
        """Start a constant-rate step: ``rate_dps`` (signed) about sensor ``axis`` held vertical for
        ``duration_s`` once steady (returns at once; the capture labels it ``rate+z:90``)."""
        if not _AXIS_RE.match(axis):
            raise ValueError(f"axis {axis!r} is not one of +x, -x, +y, -y, +z, -z")
        self.wait_idle(timeout_s)
        self.command(f"SPIN {axis} {rate_dps:g} {duration_s:g}")

    def stop(self) -> None:
        """Stop any move at once."""
        self.command("STOP")
