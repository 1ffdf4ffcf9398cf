"""A simulated motorized turntable on its own pseudo-terminal, carrying a simulated unit.

It speaks the table protocol of ``drivers/turntable.py`` and moves the :class:`~mocks.device.SimDevice`
mounted on it: ``POSE +x`` becomes a smooth move of the unit to +x up, ``ROT +z 360 90`` a turn
about the unit's z axis held vertical, with the rig's trapezoidal rate profile, ``SPIN +z 90 10`` a
constant-rate step (``mocks.rig.ConstantRate``: spin-up, ``rate_settle_s`` settling, 10 s labelled
``rate+z:90``, spin-down). The table is
MOVING until the unit's device clock passes the end of the commanded motion, so a host that waits
for IDLE and a host that watches the unit's samples see the same motion.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import re
import select
import threading
import time
from typing import NamedTuple

import numpy as np

from mocks.device import SimDevice
from mocks.raw_pty import PtyService, open_serving_pty
from mocks.rig import ConstantRate

_POSE_RE = re.compile(r"^(?:[+-][xyz]){1,3}$")
_AXIS_RE = re.compile(r"^[+-][xyz]$")
MAX_TURN_DEG = 3600.0
MAX_RATE_DPS = 720.0
MAX_SPIN_S = 3600.0


def _up_vector(label: str) -> np.ndarray:
    v = np.zeros(3)
    for sign, axis in re.findall(r"([+-])([xyz])", label):
        v["xyz".index(axis)] = 1.0 if sign == "+" else -1.0
    return v / np.linalg.norm(v)


class _Number(NamedTuple):
    """A number a command takes after its axis: finite, non-zero, at most ``limit`` in size (and
    positive unless ``signed``: a negative value turns the other way)."""

    name: str
    placeholder: str
    limit: float
    unit: str
    signed: bool

    def refusal(self, command: str, value: float) -> str | None:
        """The ``ERR 2`` reply when ``value`` is out of range, else None."""
        if math.isfinite(value) and 0 < (abs(value) if self.signed else value) <= self.limit:
            return None
        span = f"non-zero and within +-{self.limit:g}" if self.signed else f"within 0..{self.limit:g}"
        return f"ERR 2 {command}: the {self.name} must be {span}{self.unit}"


_ANGLE = _Number("angle", "<deg>", MAX_TURN_DEG, " deg", signed=True)
_TURN_RATE = _Number("rate", "<dps>", MAX_RATE_DPS, " deg/s", signed=False)  # ROT's angle has the sign
_SPIN_RATE = _Number("rate", "<dps>", MAX_RATE_DPS, " deg/s", signed=True)
_SECONDS = _Number("seconds", "<seconds>", MAX_SPIN_S, "", signed=False)


def _axis_and_numbers(args: list[str], command: str, example: str, first: _Number,
                      second: _Number) -> tuple[float, float] | str:
    """The two numbers after a signed axis (``ROT +z 360 90``), or the ``ERR 2`` reply saying why not."""
    if len(args) != 3 or not _AXIS_RE.match(args[0]):
        return f"ERR 2 {command} takes <axis> {first.placeholder} {second.placeholder}, e.g. {example}"
    try:
        values = float(args[1]), float(args[2])
    except ValueError:
        return f"ERR 2 {command}: {first.placeholder} and {second.placeholder} must be numbers"
    return first.refusal(command, values[0]) or second.refusal(command, values[1]) or values


def _signed(axis: str, value: float) -> str:
    """The axis a negative angle or rate turns about positively: ``+z`` with -90 is ``-z``."""
    return axis if value > 0 else ("-" if axis[0] == "+" else "+") + axis[1]


class TurntableSim(PtyService):
    """``with TurntableSim(server.device) as table: Turntable(table.port_path)``.

    Parameters
    ----------
    device : the simulated unit mounted on the table (the one a ``PtyServer`` serves).
    slew_dps : speed of positioning moves; a move takes the angle between poses at this speed.
    settle_s : still time the table adds after a turn before it reports IDLE.
    serial : the table's own serial number (``ID?``).
    turn_error : fault injection: the table turns (1 + turn_error) times the asked angle (a wrong
        gear ratio, a slipping belt) and still reports the asked one, as a table whose encoder sits
        on the motor would.
    rate_settle_s : seconds at the asked rate before a SPIN step's samples are labelled steady.
    """

    THREAD_NAME = "turntable-sim"
    FAILED = "the turntable simulator failed"
    model = "imu-sim-table"
    firmware = "1.0.0"

    def __init__(self, device: SimDevice, slew_dps: float = 180.0, settle_s: float = 0.2,
                 serial: str = "TT-SIM-0001", turn_error: float = 0.0, rate_settle_s: float = 1.0):
        super().__init__()
        self.device = device
        self.slew_dps = slew_dps
        self.settle_s = settle_s
        self.serial = serial
        self.turn_error = turn_error
        self.rate_settle_s = rate_settle_s
        self.up = "+z"
        self.commands: list[str] = []
        self._lock = threading.Lock()
        self._move_start = 0.0
        self._move_end = 0.0  # device time at which the commanded motion (and its settle) ends
        self._turn_deg = 0.0

    # ---- life cycle -------------------------------------------------------------------------------

    def start(self) -> TurntableSim:
        """Open the pty and start serving the turntable protocol in a thread; returns self."""
        self._master, self.port_path = open_serving_pty()
        self._start_thread()
        return self

    # ---- serving ----------------------------------------------------------------------------------

    def _run(self) -> None:
        buffer = b""
        try:
            while not self._stop.is_set():
                readable, _, _ = select.select([self._master], [], [], 0.05)
                if not readable:
                    continue
                try:
                    data = os.read(self._master, 4096)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    if exc.errno != errno.EIO:  # EIO: nobody has the port open yet, or any more
                        raise
                    time.sleep(0.05)
                    continue
                buffer += data
                while b"\n" in buffer:
                    line, _, buffer = buffer.partition(b"\n")
                    reply = self.handle(line.decode("ascii", "replace").strip())
                    with contextlib.suppress(OSError):
                        os.write(self._master, reply.encode("ascii") + b"\n")
        except BaseException as exc:  # surfaced by stop()
            self._error = exc

    # ---- the controller ---------------------------------------------------------------------------

    def _now(self) -> float:
        return self.device.next_due_s()

    def moving(self) -> bool:
        """True while a commanded move is under way."""
        return self._now() < self._move_end

    def handle(self, line: str) -> str:
        """One command line in, its reply line out (the protocol of ``drivers/turntable.py``)."""
        with self._lock:
            self.commands.append(line)
            parts = line.split()
            if not parts:
                return "ERR 1 empty command"
            name, args = parts[0].upper(), parts[1:]
            if name == "ID?":
                return f"ID {self.model},{self.serial},{self.firmware}"
            if name == "STATE?":
                return f"STATE {'MOVING' if self.moving() else 'IDLE'} {self.up} {self._turned():.3f}"
            if name == "STOP":
                self._move_end = self._now()
                self.device.set_pose(self.up, move_s=0.2)
                return "OK"
            if name in ("HOME", "POSE", "ROT", "SPIN") and self.moving():
                return "ERR 3 busy: the table is moving; wait for STATE? IDLE"
            if name == "HOME":
                return self._pose("+z") if not args else "ERR 2 HOME takes no argument"
            if name == "POSE":
                repeated = len(args) == 1 and len(set(args[0][1::2])) != len(args[0]) // 2
                if len(args) != 1 or not _POSE_RE.match(args[0]) or repeated:
                    return "ERR 2 POSE takes signed axes like +z, -x or +x+y"
                return self._pose(args[0])
            if name == "ROT":
                return self._rotate(args)
            if name == "SPIN":
                return self._spin(args)
            return f"ERR 1 unknown command {parts[0]!r}"

    def _turned(self) -> float:
        span = self._move_end - self._move_start
        if span <= 0:
            return self._turn_deg
        return self._turn_deg * min(1.0, max(0.0, (self._now() - self._move_start) / span))

    def _pose(self, up: str) -> str:
        angle = math.degrees(math.acos(float(np.clip(_up_vector(self.up) @ _up_vector(up), -1.0, 1.0))))
        move_s = max(0.3, angle / self.slew_dps)
        self._move_start = self._now()
        self._move_end = self.device.set_pose(up, move_s=move_s)
        self.up, self._turn_deg = up, 0.0
        return "OK"

    def _rotate(self, args: list[str]) -> str:
        parsed = _axis_and_numbers(args, "ROT", "ROT +z 360 90", _ANGLE, _TURN_RATE)
        if isinstance(parsed, str):
            return parsed
        angle, rate = parsed
        self._move_start = self._now()
        kept = 1.0 + self.turn_error
        self._move_end = self.device.rotate(_signed(args[0], angle), abs(angle) * kept, rate * kept,
                                            self.settle_s)
        self.up, self._turn_deg = "+" + args[0][1], angle if args[0][0] == "+" else -angle
        return "OK"

    def _spin(self, args: list[str]) -> str:
        parsed = _axis_and_numbers(args, "SPIN", "SPIN +z 90 10", _SPIN_RATE, _SECONDS)
        if isinstance(parsed, str):
            return parsed
        rate, seconds = parsed
        kept = 1.0 + self.turn_error
        self._move_start = self._now()
        self._move_end = self.device.command([ConstantRate(_signed(args[0], rate), abs(rate) * kept, seconds,
                                                           settle_s=self.rate_settle_s)]) + self.settle_s
        self.up, self._turn_deg = "+" + args[0][1], 0.0
        return "OK"
