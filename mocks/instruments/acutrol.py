"""An ACUTROL rate table emulator, and the table axis every table emulator moves.

The ACUTROL (Acutronic) speaks LF-ended SCPI-like lines, one axis number per command
(``shared/specs/instruments.md``, "Rate tables"): ``:M:P n`` / ``:M:R n`` / ``:M:A n`` choose
position, rate or absolute-rate mode; ``:D:P n,deg``, ``:D:R n,dps`` demand a position or a rate,
``:D:A n,dps2`` the acceleration limit; ``:R:P n``, ``:R:R n``, ``:R:A n`` read position, rate and
acceleration, one number each. Setting commands are not answered, so a host learns of a command it
got wrong only by reading back; the emulator does the same (an unknown line is ignored).

:class:`TableAxis` is the motion both table emulators share (``mocks.instruments.aerosmith``
imports it): a demand becomes a trapezoidal profile (constant-acceleration phases under the
table's own rate and acceleration limits, starting from whatever rate the axis has), evaluated on
the simulated clock: the coupled :class:`~mocks.device.SimDevice`'s device time when there is one
(which already runs at the served speed), else ``time.monotonic()``. With a device, every new
profile is also commanded to the unit as a :class:`~mocks.rig.RateProfile` about the mount axis,
so the unit's gyro sees the table's rate and its accelerometer the mount's pose.

A three-axis table (``axes=3``) carries the unit on every axis, with the station's kinematics
(``station.instruments.mounted_table``): axis 1 outer and vertical, axis 2 middle and horizontal
(x of the outer frame), axis 3 inner (vertical at zero angles), the unit's ``mount`` axis along
the inner axis and its ``middle`` axis along the middle one at zero angles; the unit's attitude is
``Rz(a1) Rx(a2) Rz(a3) M``. Whenever an axis replans, the unit is commanded what the axes will do:
one axis moving (the others holding) turns the unit about that gimbal's axis, fixed in the unit
(:class:`~mocks.rig.RateProfile` with a vector: the outer axis about the body direction now up),
exactly; several at once move it smoothly (:class:`~mocks.rig.Move`, the gyro seeing a smooth
turn rather than the gimbals' own profiles) to the attitude they reach together. Once at rest,
the unit holds that attitude (:class:`~mocks.rig.Static`), labelled with the pose it is in
(``+x``, ``-y-z``; "" between named poses). The emulator holds the unit's lock while it replans,
so the unit's motion starts on the same sample time as the axes'.
"""

from __future__ import annotations

import contextlib
import math
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mocks.attitude import axis_angle_matrix, parse_signed_axes
from mocks.device import SimDevice
from mocks.instruments.serving import ByteServer
from mocks.rig import TWELVE_POSITION, Move, RateProfile, Segment, Static

MAX_RATE_DPS = 1000.0  # an AC1120-class table
MAX_ACCEL_DPS2 = 500.0
DEFAULT_ACCEL_DPS2 = 100.0
HOLD_S = 1e5  # how long the unit is told a constant rate lasts (the next demand replaces it)
NEXT_AXIS = {"x": "y", "y": "z", "z": "x"}  # the default middle axis of a mount
_EX, _EZ = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])


def _rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    return axis_angle_matrix(axis, np.array([math.radians(degrees)]))[0]


def mount_matrix(mount: str, middle: str) -> np.ndarray:
    """M (3, 3): unit axes to the inner axis's frame, ``middle`` -> x, ``mount`` -> z."""
    u, v = parse_signed_axes(mount), parse_signed_axes(middle)
    return np.array([v, np.cross(u, v), u])


def gimbal_attitude(m: np.ndarray, angles: list[float]) -> np.ndarray:
    """The unit's attitude (body to world) at the three axes' ``angles`` (deg)."""
    return _rotation(_EZ, angles[0]) @ _rotation(_EX, angles[1]) @ _rotation(_EZ, angles[2]) @ m


def pose_name(up: np.ndarray) -> str:
    """The station's label of the body direction ``up`` (``+x``, ``-y-z``), or "" when it has none."""
    station = next((name for name in TWELVE_POSITION
                    if np.allclose(parse_signed_axes(name), up, atol=1e-6)), None)
    if station is not None:
        return station  # "+z+x" as the station writes it, not "+x+z"
    named = np.abs(up) > 1e-6
    if np.ptp(np.abs(up[named])) > 1e-6:
        return ""
    return "".join(("+" if up[i] > 0 else "-") + "xyz"[i] for i in range(3) if named[i])


@dataclass(frozen=True)
class Phase:
    """Constant acceleration ``accel`` from ``t0`` for ``duration`` s, starting at ``p0``, ``v0``."""

    t0: float
    p0: float
    v0: float
    accel: float
    duration: float

    def at(self, t: float) -> tuple[float, float, float]:
        """(position deg, rate deg/s, acceleration deg/s^2) at ``t``, within the phase."""
        tau = min(max(t - self.t0, 0.0), self.duration)
        return self.p0 + self.v0 * tau + 0.5 * self.accel * tau * tau, self.v0 + self.accel * tau, self.accel

    @property
    def end(self) -> tuple[float, float]:
        """(position, rate) at the phase's end."""
        p, v, _ = self.at(self.t0 + self.duration)
        return p, v


def plan_rate(t: float, p: float, v: float, rate: float, accel: float) -> list[Phase]:
    """Phases from (p, v) at ``t`` to a constant ``rate``, at ``accel``."""
    ramp = abs(rate - v) / accel
    phases = [Phase(t, p, v, math.copysign(accel, rate - v), ramp)] if ramp > 0 else []
    p1 = p + 0.5 * (v + rate) * ramp
    return [*phases, Phase(t + ramp, p1, rate, 0.0, math.inf)]


def plan_position(t: float, p: float, v: float, target: float, max_rate: float, accel: float) -> list[Phase]:
    """Phases from (p, v) at ``t`` to rest at ``target``: the trapezoid (or triangle) under
    ``max_rate`` and ``accel``; a rate away from the target, or too high to stop in time, is first
    brought to rest."""
    phases: list[Phase] = []
    direction = 1.0 if target >= p else -1.0
    toward = direction * v
    if toward < 0 or toward * toward / (2 * accel) > abs(target - p) + 1e-9:
        stop = abs(v) / accel
        phases.append(Phase(t, p, v, -math.copysign(accel, v), stop))
        p, v = phases[-1].end
        v, t = 0.0, t + stop
        direction = 1.0 if target >= p else -1.0
        toward = 0.0
    distance = abs(target - p)
    peak = min(max_rate, math.sqrt(accel * distance + toward * toward / 2))
    up = abs(peak - toward) / accel
    up_dist = (peak * peak - toward * toward) / (2 * accel if peak >= toward else -2 * accel)
    down = peak / accel
    cruise = max(0.0, distance - up_dist - peak * peak / (2 * accel)) / peak if peak > 0 else 0.0
    for accel_sign, duration, speed in ((1.0 if peak >= toward else -1.0, up, toward), (0.0, cruise, peak),
                                        (-1.0, down, peak)):
        if duration > 0:
            phases.append(Phase(t, p, direction * speed, direction * accel_sign * accel, duration))
            p, _ = phases[-1].end
            t += duration
    return [*phases, Phase(t, target, 0.0, 0.0, math.inf)]


class TableAxis:
    """One table axis following position and rate demands with trapezoidal profiles.

    Parameters
    ----------
    clock : callable
        Seconds now on the simulated clock.
    max_rate_dps, max_accel_dps2 : float
        The table's own limits: a demand beyond them is clamped, as a controller's own limits do.
    on_plan : callable, optional
        Called with each new profile's phases (the coupling to the unit).
    """

    def __init__(self, clock: Callable[[], float], max_rate_dps: float = MAX_RATE_DPS,
                 max_accel_dps2: float = MAX_ACCEL_DPS2,
                 on_plan: Callable[[list[Phase]], None] | None = None):
        self.clock = clock
        self.max_rate_dps = max_rate_dps
        self.max_accel_dps2 = max_accel_dps2
        self.accel_dps2 = min(DEFAULT_ACCEL_DPS2, max_accel_dps2)
        self.on_plan = on_plan
        self.mode = "position"
        self.demand = 0.0  # the position (position mode) or rate (rate mode) asked for
        self.servo = True
        self._phases = [Phase(clock(), 0.0, 0.0, 0.0, math.inf)]

    def state(self) -> tuple[float, float, float]:
        """(position deg, rate deg/s, acceleration deg/s^2) now."""
        t = self.clock()
        while len(self._phases) > 1 and self._phases[1].t0 <= t:
            del self._phases[0]  # a bounded list however long the table runs
        return self._phases[0].at(t)

    def at(self, t: float) -> tuple[float, float, float]:
        """(position, rate, acceleration) at ``t`` (now or later) on the planned profile."""
        phase = next((p for p in reversed(self._phases) if p.t0 <= t), self._phases[0])
        return phase.at(t)

    def motion(self, t: float) -> tuple[list[tuple[float, float, float]], float]:
        """The planned motion from ``t`` on: the finite rate ramps ``(rate0, rate1, duration)``, and the
        rate the axis keeps after them (0: at rest)."""
        ramps: list[tuple[float, float, float]] = []
        for phase in self._phases:
            end = phase.t0 + phase.duration
            if end <= t:
                continue
            start = max(phase.t0, t)
            rate0 = phase.at(start)[1]
            if math.isinf(phase.duration):
                return ramps, rate0
            ramps.append((rate0, phase.at(end)[1], end - start))
        return ramps, 0.0

    def _replan(self) -> None:
        t = self.clock()
        p, v, _ = self.state()
        if not self.servo:
            phases = [Phase(t, p, 0.0, 0.0, math.inf)]  # servo off: the brake holds it where it is
        elif self.mode == "rate":
            phases = plan_rate(t, p, v, self.demand, self.accel_dps2)
        else:
            phases = plan_position(t, p, v, self.demand, self.max_rate_dps, self.accel_dps2)
        self._phases = phases
        if self.on_plan is not None:
            self.on_plan(phases)

    def move_to(self, degrees: float) -> None:
        """Position mode, to ``degrees``."""
        self.mode, self.demand = "position", degrees
        self._replan()

    def turn(self, rate_dps: float) -> None:
        """Rate mode at ``rate_dps`` (clamped to the table's maximum)."""
        self.mode, self.demand = "rate", max(-self.max_rate_dps, min(self.max_rate_dps, rate_dps))
        self._replan()

    def hold_mode(self, mode: str) -> None:
        """Enter ``mode`` without a new demand: rate mode keeps the rate, position mode stops where
        the axis can (a mode switch is bumpless)."""
        p, v, _ = self.state()
        if mode == "rate":
            self.mode, self.demand = "rate", v
        else:
            self.mode, self.demand = "position", p + v * abs(v) / (2 * self.accel_dps2)
        self._replan()

    def stop(self) -> None:
        """Bring the axis to rest at the acceleration limit."""
        self.turn(0.0)

    def set_acceleration(self, dps2: float) -> None:
        """The acceleration limit (clamped to the table's own; a non-positive one is ignored)."""
        if dps2 > 0 and math.isfinite(dps2):
            self.accel_dps2 = min(dps2, self.max_accel_dps2)
            self._replan()

    def set_servo(self, on: bool) -> None:
        """Servo on or off (off: the axis stops at once and ignores demands)."""
        self.servo = on
        if not on:
            self.mode, self.demand = "position", self.state()[0]
        self._replan()


class TableEmulator:
    """What both table emulators share: axes, the clock, the coupling to the unit, a lock.

    Parameters
    ----------
    axes : int
        How many axes (one or two: only axis 1 is coupled to the unit; three: every axis, see
        the module's docstring).
    device : SimDevice, optional
        The unit mounted on the table.
    mount : str
        The unit's signed axis along the table axis (held up), e.g. ``+z``; on a three-axis table,
        along the inner axis.
    max_rate_dps, max_accel_dps2 : float
        The table's own limits.
    clock : callable, optional
        Seconds now (default: the device's time, else ``time.monotonic``).
    middle : str, optional
        Three axes: the unit's signed axis along the middle axis at zero angles (default: the
        next axis, ``+z`` -> ``+x``).

    Attributes
    ----------
    garble : bool
        Fault: every reply's text is noise but keeps its line end (a noisy line, a wrong baud
        rate), so the host reads a whole reply that is not a number. ``ByteServer.garbage``
        scrambles the line end too, which a host sees as no reply.
    """

    END = b"\n"

    def __init__(self, axes: int = 1, device: SimDevice | None = None, mount: str = "+z",
                 max_rate_dps: float = MAX_RATE_DPS, max_accel_dps2: float = MAX_ACCEL_DPS2,
                 clock: Callable[[], float] | None = None, middle: str | None = None):
        self.device = device
        self.mount = mount
        self.middle = middle if middle is not None else "+" + NEXT_AXIS[mount[-1]]
        self.clock = clock or (device.next_due_s if device is not None else time.monotonic)
        self.lines: list[str] = []
        self.garble = False
        self._buffer = b""
        self._lock = threading.RLock()
        # The unit's own lock too while a line is handled: an axis's plan and the unit's motion start
        # on the same sample (the unit's server could otherwise produce samples between the two).
        self._device_lock: contextlib.AbstractContextManager[Any] = (
            device._lock if device is not None else contextlib.nullcontext())
        self.gimballed = axes >= 3
        self.matrix = mount_matrix(mount, self.middle) if self.gimballed else np.eye(3)
        self.axes = [TableAxis(self.clock, max_rate_dps, max_accel_dps2) for _ in range(axes)]
        if device is not None and self.gimballed:
            device.command([self._held([0.0, 0.0, 0.0])])  # every axis at zero: the mount axis up
            for axis in self.axes[:3]:
                axis.on_plan = self._couple_axes
        elif device is not None:
            device.command([Static(mount, 1.0)])  # mounted: the mount axis along the (vertical) table axis
            self.axes[0].on_plan = self._couple

    def _couple(self, phases: list[Phase]) -> None:
        assert self.device is not None
        ramps = []
        for phase in phases:
            if math.isinf(phase.duration):
                if phase.v0 != 0:
                    ramps.append((phase.v0, phase.v0, HOLD_S))
                break
            ramps.append((phase.v0, phase.v0 + phase.accel * phase.duration, phase.duration))
        self.device.command([RateProfile(self.mount, tuple(ramps))])

    def _held(self, angles: list[float], duration_s: float = HOLD_S) -> Static:
        """The unit held at the axes' ``angles``, labelled with its pose."""
        attitude = gimbal_attitude(self.matrix, angles)
        label = pose_name(attitude.T @ _EZ)
        return Static(label, duration_s, label=label, attitude=attitude)

    def _gimbal_axis(self, index: int, angles: list[float]) -> tuple[float, float, float]:
        """Axis ``index`` (0 outer, 1 middle, 2 inner) in the unit's axes at ``angles``."""
        carried = gimbal_attitude(self.matrix, [0.0, 0.0, angles[2]])  # Rz(a3) M
        if index == 0:
            axis = (_rotation(_EX, angles[1]) @ carried).T @ _EZ  # the body direction up
        else:
            axis = carried.T @ _EX if index == 1 else self.matrix.T @ _EZ
        return float(axis[0]), float(axis[1]), float(axis[2])

    def _couple_axes(self, _phases: list[Phase] | None = None) -> None:
        """Command the unit what the three axes will do from now (see the module's docstring)."""
        assert self.device is not None
        now = self.clock()
        axes = self.axes[:3]
        motions = [axis.motion(now) for axis in axes]
        moving = [i for i, (ramps, rate) in enumerate(motions)
                  if rate or any(r0 or r1 for r0, r1, _ in ramps)]
        angles = [axis.at(now)[0] for axis in axes]
        segments: list[Segment] = []
        if len(moving) == 1:
            index = moving[0]
            ramps, rate = motions[index]
            held = [(rate, rate, HOLD_S)] if rate else []
            segments.append(RateProfile(self.mount, tuple(ramps + held),
                                        vector=self._gimbal_axis(index, angles)))
            if not rate:
                span = sum(d for _, _, d in ramps)
                segments.append(self._held([axis.at(now + span)[0] for axis in axes]))
        elif moving:
            span = max(sum(d for _, _, d in motions[i][0]) for i in moving)
            end = [axis.at(now + span)[0] for axis in axes]
            turning = [i for i in moving if motions[i][1]]
            segments += [Move(max(span, 1e-3)), self._held(end, 1e-3 if len(turning) == 1 else HOLD_S)]
            if len(turning) == 1:  # one axis goes on turning: about its gimbal axis, as above
                rate = motions[turning[0]][1]
                segments.append(RateProfile(self.mount, ((rate, rate, HOLD_S),),
                                            vector=self._gimbal_axis(turning[0], end)))
        else:
            segments.append(self._held(angles))
        self.device.command(segments)

    def axis(self, number: int) -> TableAxis | None:
        """Axis ``number`` (1-based), or None."""
        return self.axes[number - 1] if 1 <= number <= len(self.axes) else None

    def position_deg(self, axis: int = 1) -> float:
        """The axis's position now (for tests)."""
        with self._lock:
            return self.axes[axis - 1].state()[0]

    def rate_dps(self, axis: int = 1) -> float:
        """The axis's rate now (for tests)."""
        with self._lock:
            return self.axes[axis - 1].state()[1]

    def accel_dps2(self, axis: int = 1) -> float:
        """The axis's acceleration now (for tests)."""
        with self._lock:
            return self.axes[axis - 1].state()[2]

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host in; the replies to every complete line out."""
        with self._lock, self._device_lock:
            self._buffer += data
            out = []
            while self.END in self._buffer:
                raw, _, self._buffer = self._buffer.partition(self.END)
                line = raw.decode("latin-1").strip()
                if not line:
                    continue
                self.lines.append(line)
                reply = self.handle(line)
                if reply is not None:
                    text = reply.encode("latin-1")
                    out.append((bytes(0x21 + (b * 7) % 90 for b in text) if self.garble else text) + self.END)
            return b"".join(out)

    def handle(self, line: str) -> str | None:
        """One command line; its reply, or None when it has none."""
        raise NotImplementedError

    def serve(self, transport: str = "pty") -> ByteServer:
        """A started :class:`ByteServer` serving this table on a pty or a loopback TCP port."""
        return ByteServer(self, transport).start()


_COMMAND = re.compile(r"^:([MDR]):([PRAO])\s+(\d+)\s*(?:,\s*(.*))?$", re.IGNORECASE)


class AcutrolEmulator(TableEmulator):
    """An ACUTROL controller: ``AcutrolEmulator(device=sim, mount="+z").serve("tcp")``."""

    def handle(self, line: str) -> str | None:
        """One ACUTROL line; a read's number, else None (setting commands are not answered)."""
        match = _COMMAND.match(line)
        if match is None:
            return None
        group, item, number, argument = match.group(1).upper(), match.group(2).upper(), int(match.group(3)), \
            match.group(4)
        axis = self.axis(number)
        if axis is None:
            return None
        if group == "R":
            position, rate, accel = axis.state()
            return {"P": f"{position:.6f}", "R": f"{rate:.6f}", "A": f"{accel:.6f}"}.get(item)
        if group == "M":
            if item in "RA":
                axis.hold_mode("rate")
            elif item == "P":
                axis.hold_mode("position")
            return None
        try:
            value = float((argument or "").split(",")[0])
        except ValueError:
            return None
        if not math.isfinite(value):
            return None
        if item == "P" and axis.mode == "position":
            axis.move_to(value)
        elif item == "R" and axis.mode == "rate":
            axis.turn(value)
        elif item == "A":
            axis.set_acceleration(value)
        return None  # a demand for the other mode is kept by a real controller; here it is dropped
