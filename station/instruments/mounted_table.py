"""The station's turntable sequence on any rate table: a generic table plus a mount description.

The factory runner's table operator asks for poses (``pose("+x")``) and turns about sensor axes
(``rotate("+z", 360, 90)``), as ``drivers.turntable.Turntable`` answers them in sensor axes. A lab
rate table (``drivers.instruments.Table``: ACUTROL, Aerosmith) only knows its own axis in its
own degrees; :class:`MountedTable` translates, given which unit axis lies along the table axis
(``mount="+z"``: the unit's +z along the table's axis, which is vertical).

A single-axis table keeps the mount axis up, so it reaches one pose (the mount's) and turns about
one sensor axis; any other step is refused with one line naming the step and the mount, before
anything moves. Two-axis tables (an outer axis tilting the inner one) are driven on the inner
axis only, with the same refusals.

Like the turntable driver, :meth:`MountedTable.pose` and :meth:`MountedTable.rotate` return as
soon as the motion has started (the runner integrates the unit's gyro while the table turns); a
turn runs in a worker thread: rate mode at the step's rate, then, one stopping distance before the
end, a position demand to the exact end angle, so the step's rate is kept and the angle is the
table's encoder's. The next call waits for it; :meth:`MountedTable.stop` ends it at once.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable
from typing import Protocol, TypeVar

from drivers.errors import DriverError
from drivers.instruments import Table
from drivers.instruments.errors import InstrumentError, InstrumentTimeout

_AXIS = re.compile(r"^[+-][xyz]$")
T = TypeVar("T")


class PoseTable(Protocol):
    """What the runner's table operator needs: ``drivers.turntable.Turntable`` and
    :class:`MountedTable` both give it."""

    def pose(self, up: str, timeout_s: float = 30.0) -> None:
        """Start putting the unit's ``up`` direction up (returns once started)."""
        ...

    def rotate(self, axis: str, angle_deg: float, rate_dps: float, timeout_s: float = 30.0) -> None:
        """Start a turn of ``angle_deg`` about the sensor ``axis`` held up (returns once started)."""
        ...

    def stop(self) -> None:
        """Stop any motion at once."""
        ...


class MountRefused(InstrumentError):
    """A step the table cannot do with the unit mounted as it is."""


class MountedTable:
    """A :class:`~drivers.instruments.Table` carrying the unit, spoken to in sensor axes.

    Parameters
    ----------
    table : Table
        The open (and limited) table.
    mount : str
        The unit's signed axis along the table axis (``+z``, ``-x``).
    accel_dps2 : float
        The acceleration limit set on the table before the first motion (within the plan's).
    tolerance_deg : float
        How close to a demanded position counts as there.
    poll_s : float
        Pause between two reads while a turn runs.
    """

    def __init__(self, table: Table, mount: str = "+z", accel_dps2: float = 100.0,
                 tolerance_deg: float = 0.05, poll_s: float = 0.005):
        if not _AXIS.match(mount):
            raise ValueError(f"mount {mount!r} is not a signed axis such as +z or -x")
        self.table = table
        self.mount = mount
        self.accel_dps2 = accel_dps2
        self.tolerance_deg = tolerance_deg
        self.poll_s = poll_s
        self.error: DriverError | None = None  # what the last turn's worker failed with
        self._lock = threading.Lock()  # one exchange at a time: the worker, the runner, an abort
        self._abort = threading.Event()
        self._worker: threading.Thread | None = None
        self._accel_set = False

    def _do(self, what: Callable[[], T]) -> T:
        with self._lock:
            return what()

    def _refuse(self, step: str, needs: str) -> MountRefused:
        return MountRefused(f"{self.table.url}: step '{step}' needs {needs}, but the unit is mounted with "
                            f"{self.mount} along the single table axis (turns about {self.mount[1]} only); "
                            "remount the unit or leave the step out of the plan", self.table.url, step)

    def wait(self, timeout_s: float = 30.0) -> None:
        """Wait for the running turn to end; raises what it failed with."""
        worker = self._worker
        if worker is not None:
            worker.join(timeout_s)
            if worker.is_alive():
                raise InstrumentTimeout(f"{self.table.url}: the table is still turning after {timeout_s:g} s",
                                        self.table.url)
            self._worker = None
        if self.error is not None:
            error, self.error = self.error, None
            raise error

    def pose(self, up: str, timeout_s: float = 30.0) -> None:
        """The mount's pose (or a turn about it): the table stops; any other pose is refused."""
        if up != self.mount:
            raise self._refuse(f"pose {up}", f"the unit's {up} up")
        self.wait(timeout_s)
        self._do(lambda: self.table.stop(1))

    def rotate(self, axis: str, angle_deg: float, rate_dps: float, timeout_s: float = 30.0) -> None:
        """Start turning ``angle_deg`` about the sensor ``axis`` at ``rate_dps``; returns at once."""
        if not _AXIS.match(axis) or axis[1] != self.mount[1]:
            raise self._refuse(f"rotate {axis} {angle_deg:g}", f"a turn about {axis}")
        self.wait(timeout_s)
        if not self._accel_set and self.table.speaker.has("set_acceleration"):
            self._do(lambda: self.table.set_acceleration(self.accel_dps2, 1))
            self._accel_set = True
        # about -z by +a is about +z by -a: the table's angle has the mount's sign
        table_angle = angle_deg * (1.0 if axis[0] == self.mount[0] else -1.0)
        start = self._do(lambda: self.table.position_deg(1))
        target = start + table_angle
        rate = math.copysign(abs(rate_dps), table_angle)
        self._abort.clear()
        self._do(lambda: self.table.turn(rate, 1))
        deadline = time.monotonic() + timeout_s
        self._worker = threading.Thread(target=self._finish, args=(target, abs(rate), deadline),
                                        name="mounted-table", daemon=True)
        self._worker.start()

    def _finish(self, target: float, rate: float, deadline: float) -> None:
        sign = 1.0 if target >= self._do(lambda: self.table.position_deg(1)) else -1.0
        stopping = rate * rate / (2.0 * self.accel_dps2)
        try:
            while not self._abort.is_set():
                began = time.monotonic()
                position = self._do(lambda: self.table.position_deg(1))
                latency = time.monotonic() - began
                # two reads' worth of travel in hand, so the position demand never comes late
                if (target - position) * sign <= stopping + rate * (2 * latency + self.poll_s):
                    self._do(lambda: self.table.move_to(target, 1))
                    break
                if time.monotonic() > deadline:
                    raise InstrumentTimeout(f"{self.table.url}: the turn to {target:g} deg did not end in "
                                            "time", self.table.url)
                self._abort.wait(self.poll_s)
            while not self._abort.is_set():
                position = self._do(lambda: self.table.position_deg(1))
                rate_now = self._do(lambda: self.table.rate_dps(1))
                if abs(position - target) <= self.tolerance_deg and abs(rate_now) < 1e-3:
                    return
                if time.monotonic() > deadline:
                    raise InstrumentTimeout(f"{self.table.url}: the table did not settle at {target:g} deg "
                                            f"(at {position:g})", self.table.url)
                self._abort.wait(self.poll_s)
        except DriverError as exc:
            self.error = exc

    def stop(self) -> None:
        """Stop at once (Ctrl-C, abort): the running turn ends and every axis is brought to rest."""
        self._abort.set()
        self._do(self.table.stop)

    def wait_stopped(self, timeout_s: float = 10.0) -> float:
        """Wait until the table reports rate 0 (position steady where it reports no rate); returns
        the seconds waited."""
        began = time.monotonic()
        last = self._do(lambda: self.table.position_deg(1))
        while True:
            if self.table.speaker.has("rate"):
                if abs(self._do(lambda: self.table.rate_dps(1))) < 1e-6:
                    return time.monotonic() - began
            else:
                position = self._do(lambda: self.table.position_deg(1))
                if abs(position - last) < 1e-6:
                    return time.monotonic() - began
                last = position
            if time.monotonic() - began > timeout_s:
                raise InstrumentTimeout(f"{self.table.url}: still turning {timeout_s:g} s after stop",
                                        self.table.url)
            time.sleep(self.poll_s)
