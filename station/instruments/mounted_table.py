"""The station's turntable sequence on any rate table: a generic table plus a mount description.

The factory runner's table operator asks for poses (``pose("+x")``) and turns about sensor axes
(``rotate("+z", 360, 90)``), as ``drivers.turntable.Turntable`` answers them in sensor axes. A lab
rate table (``drivers.instruments.Table``: ACUTROL, Aerosmith) only knows its own axes in its
own degrees; :class:`MountedTable` translates, given which unit axis lies along the table axis
(``mount="+z"``: the unit's +z along the table's axis, which is vertical).

A single-axis table keeps the mount axis up, so it reaches one pose (the mount's) and turns about
one sensor axis; any other step is refused with one line naming the step and the mount, before
anything moves. Two-axis tables (an outer axis tilting the inner one) are driven on the inner
axis only, with the same refusals.

A three-axis table (``?axes=3``, Acutronic's three-axis tables) reaches every pose. Axis 1 is the
outer axis, vertical (the rate axis); axis 2 the middle one, horizontal, carried by the outer;
axis 3 the inner one, carried by the middle and carrying the unit, vertical at zero angles. The
mount is described once: ``mount`` is the unit axis along the inner axis, ``middle`` the unit
axis along the middle axis at zero angles (default: the next axis, ``+z`` -> ``+x``, ``+x`` ->
``+y``, ``+y`` -> ``+z``). The unit's attitude in the world (z up) is::

    R = Rz(a1) . Rx(a2) . Rz(a3) . M        M: unit axes -> inner frame (middle -> x, mount -> z)

so a unit direction d is up when Rx(a2) Rz(a3) M d = z, whatever a1: :func:`tilt_angles` solves
that in closed form (a multiple of 45 deg for every station pose), choosing of the two solutions
the one with the least travel. A pose moves the middle and inner axes there; a turn about the
unit axis ``a`` puts ``a`` up (when it is not already) and turns the outer axis by the angle at
the rate, as on a single-axis table.

Like the turntable driver, :meth:`MountedTable.pose` and :meth:`MountedTable.rotate` return as
soon as the motion has started (the runner integrates the unit's gyro while the table turns and
waits for the unit to be still in the pose it asked for); a turn runs in a worker thread: rate
mode at the step's rate, then, one stopping distance before the end, a position demand to the
exact end angle, so the step's rate is kept and the angle is the table's encoder's. The next call
waits for it; :meth:`MountedTable.stop` ends it at once. A three-axis tilt is a position demand on
the middle and inner axes (the controller's own profile, its acceleration lowered for the move so
that its peak rate stays within the plan's ``max_rate_dps``); a turn asked while the tilt is not
there waits for the tilt before it starts.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable
from functools import partial
from typing import Protocol, TypeVar

from drivers.errors import DriverError
from drivers.instruments import Table
from drivers.instruments.errors import InstrumentError, InstrumentTimeout
from station.instruments.limits import LimitedTable

_AXIS = re.compile(r"^[+-][xyz]$")
_POSE = re.compile(r"^(?:[+-][xyz]){1,3}$")
T = TypeVar("T")
Vector = tuple[float, float, float]
Matrix = tuple[Vector, Vector, Vector]  # rows
NEXT_AXIS = {"x": "y", "y": "z", "z": "x"}


# --- three-axis kinematics (pure Python: this layer has no numpy) --------------------------------

def axis_vector(label: str) -> Vector:
    """The unit vector of signed axes: ``+x`` -> (1, 0, 0), ``+x+y`` -> (1, 1, 0)/sqrt 2."""
    if not _POSE.match(label):
        raise ValueError(f"{label!r} is not signed axes such as +z, -x or +x+y")
    v = [0.0, 0.0, 0.0]
    for sign, name in re.findall(r"([+-])([xyz])", label):
        i = "xyz".index(name)
        if v[i]:
            raise ValueError(f"{label!r} names axis {name} twice")
        v[i] = 1.0 if sign == "+" else -1.0
    n = math.sqrt(sum(c * c for c in v))
    return v[0] / n, v[1] / n, v[2] / n


def _cross(a: Vector, b: Vector) -> Vector:
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


def _dot(a: Vector, b: Vector) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _apply(m: Matrix, v: Vector) -> Vector:
    return _dot(m[0], v), _dot(m[1], v), _dot(m[2], v)


def mount_matrix(mount: str, middle: str) -> Matrix:
    """M: unit axes to the inner axis's frame (``middle`` -> x, ``mount`` -> z), rows."""
    u, v = axis_vector(mount), axis_vector(middle)
    return v, _cross(u, v), u


def _rx(deg: float, v: Vector) -> Vector:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return v[0], c * v[1] - s * v[2], s * v[1] + c * v[2]


def _rz(deg: float, v: Vector) -> Vector:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]


def up_direction(m: Matrix, middle_deg: float, inner_deg: float, unit: Vector) -> Vector:
    """Where the unit direction ``unit`` points in the outer axis's frame (z vertical)."""
    return _rx(middle_deg, _rz(inner_deg, _apply(m, unit)))


def _wrap(deg: float) -> float:
    """``deg`` in (-180, 180]."""
    wrapped = math.fmod(deg, 360.0)
    if wrapped > 180.0:
        wrapped -= 360.0
    elif wrapped <= -180.0:
        wrapped += 360.0
    return wrapped


def tilt_angles(m: Matrix, up: Vector, middle_deg: float = 0.0,
                inner_deg: float = 0.0) -> tuple[float, float]:
    """Middle and inner angles (deg, in (-180, 180]) that put the unit direction ``up`` vertical:
    of the two solutions, the one nearest the current ``middle_deg``, ``inner_deg``.

    With w = M up, Rz(a3) turns w into the y-z plane (a3 = atan2(wx, wy)) and Rx(a2) lifts it
    to z (a2 = atan2(r, wz), r the length of w's x-y part); a3 + 180 with -a2 is the other
    solution. Along the inner axis (r = 0) the inner angle stays where it is.
    """
    wx, wy, wz = _apply(m, up)
    r = math.hypot(wx, wy)
    if r < 1e-9:
        candidates = [(0.0 if wz > 0 else 180.0, _wrap(inner_deg))]
    else:
        a2, a3 = math.degrees(math.atan2(r, wz)), math.degrees(math.atan2(wx, wy))
        candidates = [(_wrap(a2), _wrap(a3)), (_wrap(-a2), _wrap(a3 + 180.0))]
    return min(candidates, key=lambda c: abs(c[0] - middle_deg) + abs(c[1] - inner_deg))


# --- the table as the runner's operator sees it -------------------------------------------------

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
        The unit's signed axis along the table axis (``+z``, ``-x``); on a three-axis table, along
        the inner axis.
    accel_dps2 : float
        The acceleration limit set on the table (every axis it moves) before the first motion
        (within the plan's).
    tolerance_deg : float
        How close to a demanded position counts as there.
    poll_s : float
        Pause between two reads while a turn runs.
    middle : str, optional
        Three-axis tables: the unit's signed axis along the middle axis at zero angles,
        perpendicular to ``mount`` (default: the next axis, ``+z`` -> ``+x``).
    max_rate_dps : float, optional
        The highest rate a tilt may reach (default: the plan's ``max_rate_dps`` of a
        :class:`~station.instruments.limits.LimitedTable`). A tilt is a position demand, whose
        peak rate from rest is sqrt(acceleration x distance): its axis's acceleration is lowered
        for the move so that the peak stays within this rate.
    """

    def __init__(self, table: Table, mount: str = "+z", accel_dps2: float = 100.0,
                 tolerance_deg: float = 0.05, poll_s: float = 0.005, middle: str | None = None,
                 max_rate_dps: float | None = None):
        if not _AXIS.match(mount):
            raise ValueError(f"mount {mount!r} is not a signed axis such as +z or -x")
        middle = middle if middle is not None else "+" + NEXT_AXIS[mount[1]]
        if not _AXIS.match(middle) or middle[1] == mount[1]:
            raise ValueError(f"middle {middle!r} is not a signed axis perpendicular to the mount {mount}")
        self.table = table
        self.mount = mount
        self.middle = middle
        self.accel_dps2 = accel_dps2
        self.tolerance_deg = tolerance_deg
        self.poll_s = poll_s
        if max_rate_dps is None and isinstance(table, LimitedTable):
            max_rate_dps = table.limits.max_rate_dps
        self.max_rate_dps = max_rate_dps
        self.error: DriverError | None = None  # what the last turn's worker failed with
        self._matrix = mount_matrix(mount, middle)
        self._lock = threading.Lock()  # one exchange at a time: the worker, the runner, an abort
        self._abort = threading.Event()
        self._worker: threading.Thread | None = None
        self._accel: dict[int, float] = {}  # the acceleration last set on each axis

    @property
    def gimballed(self) -> bool:
        """True on a table of three axes or more: every pose reachable."""
        return self.table.axes >= 3

    def _do(self, what: Callable[[], T]) -> T:
        with self._lock:
            return what()

    def _refuse(self, step: str, needs: str) -> MountRefused:
        return MountRefused(f"{self.table.url}: step '{step}' needs {needs}, but the unit is mounted with "
                            f"{self.mount} along the single table axis (turns about {self.mount[1]} only); "
                            "remount the unit or leave the step out of the plan", self.table.url, step)

    def _set_acceleration(self, axis: int, dps2: float | None = None) -> None:
        dps2 = self.accel_dps2 if dps2 is None else dps2
        if self._accel.get(axis) != dps2 and self.table.speaker.has("set_acceleration"):
            self._do(partial(self.table.set_acceleration, dps2, axis))
            self._accel[axis] = dps2

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
        """Single axis: the mount's pose (or a turn about it): the table stops; any other pose is
        refused. Three axes: the middle and inner axes start toward the pose; returns at once."""
        if self.gimballed:
            direction = axis_vector(up)  # a label that is not a pose is a ValueError, as for the turntable
            self.wait(timeout_s)
            self._do(lambda: self.table.stop(1))
            self._tilt(direction)
            return
        if up != self.mount:
            raise self._refuse(f"pose {up}", f"the unit's {up} up")
        self.wait(timeout_s)
        self._do(lambda: self.table.stop(1))

    def tilt_targets(self, up: str) -> tuple[float, float]:
        """Three axes: the middle and inner angles (deg) that put ``up`` up from where they are."""
        middle, inner = self._do(lambda: (self.table.position_deg(2), self.table.position_deg(3)))
        return tilt_angles(self._matrix, axis_vector(up), _wrap(middle), _wrap(inner))

    def _tilt(self, direction: Vector) -> tuple[float, float] | None:
        """Start the middle and inner axes toward ``direction`` up; their targets, or None when
        they are there already (nothing sent)."""
        middle, inner = self._do(lambda: (self.table.position_deg(2), self.table.position_deg(3)))
        vertical = up_direction(self._matrix, middle, inner, direction)[2]
        if vertical >= math.cos(math.radians(self.tolerance_deg)):
            return None
        targets = tilt_angles(self._matrix, direction, _wrap(middle), _wrap(inner))
        for axis, now, target in ((2, middle, targets[0]), (3, inner, targets[1])):
            distance = abs(now - target)
            if abs(_wrap(now - target)) > self.tolerance_deg:
                accel = self.accel_dps2
                if self.max_rate_dps is not None:  # the triangle's peak sqrt(a d) within the rate
                    accel = min(accel, self.max_rate_dps ** 2 / distance)
                self._set_acceleration(axis, accel)
                self._do(partial(self.table.move_to, target, axis))
        return targets

    def _wait_tilt(self, targets: tuple[float, float], timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            middle, inner, rates = self._do(lambda: (self.table.position_deg(2), self.table.position_deg(3),
                                                     (self.table.rate_dps(2), self.table.rate_dps(3))))
            if (abs(_wrap(middle - targets[0])) <= self.tolerance_deg
                    and abs(_wrap(inner - targets[1])) <= self.tolerance_deg
                    and max(abs(r) for r in rates) < 1e-3):
                return
            if self._abort.is_set():
                raise InstrumentError(f"{self.table.url}: stopped while tilting the unit for a turn",
                                      self.table.url)
            if time.monotonic() > deadline:
                raise InstrumentTimeout(f"{self.table.url}: the middle and inner axes did not reach "
                                        f"{targets[0]:g}, {targets[1]:g} deg (at {middle:g}, {inner:g})",
                                        self.table.url)
            self._abort.wait(self.poll_s)

    def rotate(self, axis: str, angle_deg: float, rate_dps: float, timeout_s: float = 30.0) -> None:
        """Start turning ``angle_deg`` about the sensor ``axis`` at ``rate_dps``; returns once the turn
        has started (on a three-axis table, after putting ``axis`` up if it is not)."""
        # A new command: a stop() from here on ends it, the tilt's wait included.
        self._abort.clear()
        if self.gimballed:
            if not _AXIS.match(axis):
                raise ValueError(f"rotation axis {axis!r} is not a signed axis such as +z or -x")
            self.wait(timeout_s)
            targets = self._tilt(axis_vector(axis))
            if targets is not None:
                self._wait_tilt(targets, timeout_s)
            # with the axis up, the outer (vertical) axis turns about it: the same angle
            self._turn(angle_deg, rate_dps, timeout_s)
            return
        if not _AXIS.match(axis) or axis[1] != self.mount[1]:
            raise self._refuse(f"rotate {axis} {angle_deg:g}", f"a turn about {axis}")
        self.wait(timeout_s)
        # about -z by +a is about +z by -a: the table's angle has the mount's sign
        self._turn(angle_deg * (1.0 if axis[0] == self.mount[0] else -1.0), rate_dps, timeout_s)

    def _turn(self, table_angle: float, rate_dps: float, timeout_s: float) -> None:
        """Start the worker turning axis 1 by ``table_angle`` at ``rate_dps``."""
        self._set_acceleration(1)
        start = self._do(lambda: self.table.position_deg(1))
        target = start + table_angle
        rate = math.copysign(abs(rate_dps), table_angle)
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
        """Wait until the table reports rate 0 on every axis it drives (axis 1's position steady
        where it reports no rate); returns the seconds waited."""
        began = time.monotonic()
        last = self._do(lambda: self.table.position_deg(1))
        axes = range(1, min(self.table.axes, 3) + 1) if self.gimballed else (1,)
        while True:
            if self.table.speaker.has("rate"):
                if max(abs(self._do(partial(self.table.rate_dps, a))) for a in axes) < 1e-6:
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
