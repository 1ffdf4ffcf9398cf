"""The rig that moves the simulated unit, and ``simulate``: truth + motion -> sampled arrays.

World frame: z up, gravity -g z. Attitude R maps body to world. The rig turns the unit about
its own origin (no linear acceleration), so the true specific force in the body frame is
``f_b = R^T (0, 0, g)`` and the true rate is the body-frame angular rate ``w_b`` with
``dR/dt = R [w_b]x``, plus the Earth rate ``R^T w_E`` when the truth enables it.

Every motion piece turns about one body axis e fixed during the piece:
``R(t) = R0 exp(phi(t) [e]x)`` and ``w_b(t) = phi'(t) e``, in closed form, so the true rate is
the exact derivative of the attitude (integrating it recovers the attitude change) and a
whole recording is evaluated with vectorised Rodrigues formulas.

Segments (labels as in ``shared/specs/capture-csv.md``):

- :class:`Static`: hold a pose (``"+z"``, ``"-x"``, ``"+x+y"``: that body direction up).
- :class:`Rotation`: with the axis vertical, turn about it by the signed angle with a
  trapezoidal rate profile (ramps of ``ramp_s``), ``settle_s`` still before and after.
- :class:`ConstantRate`: with the axis vertical, spin up to a constant rate, hold it, spin down;
  labelled (``rate+z:90``) only while the rate is steady, after ``settle_s`` at the rate.
- :class:`RateProfile`: with the signed axis up (a rate table's mount), follow linear rate ramps
  from whatever rate the table had: the profile a table emulator plans (``mocks.instruments``);
  with a ``vector``, about that body direction from wherever the unit is (a gimbal's axis).
- :class:`Move`: a hand-held move to the attitude of the next segment: rotation about the
  fixed axis of the relative attitude with a quintic smooth-step angle
  ``phi = theta (10 u^3 - 15 u^4 + 6 u^5)``, ``u = t / duration`` (rate and angular
  acceleration zero at both ends).

A segment whose attitude differs from the current one without a ``Move`` before it gets an
implicit ``Move(DEFAULT_MOVE_S)``, so the attitude is always continuous.

Why this module is long: the timeline of poses and turns, the temperature profile and the
sampler that turns both into a recording are the simulated unit's one truth path; its pieces share
the attitude integration and are tested together as one rig.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mocks.attitude import (
    AXES,
    axis_angle_matrix,
    matrix_axis_angle,
    pose_attitude,
    random_attitude,
    rotate_vectors,
)
from mocks.truth import NoiseGenerator, UnitTruth, earth_rate_world

DEFAULT_MOVE_S = 2.0
SIX_POSITION = ["+x", "-x", "+y", "-y", "+z", "-z"]
TWELVE_POSITION = SIX_POSITION + ["+x+y", "-x-y", "+y+z", "-y-z", "+z+x", "-z-x"]
SEQUENCE_ROTATIONS = ["+x", "-x", "+y", "-y", "+z", "-z"]
_UP = np.array([0.0, 0.0, 1.0])


@dataclass
class Static:
    """Hold ``pose`` for ``duration_s``. ``attitude`` (3x3, body to world) overrides the pose
    for poses that have no name (hand-held sessions); label None: the pose name."""

    pose: str
    duration_s: float
    label: str | None = None
    attitude: np.ndarray | None = None


@dataclass
class Rotation:
    """Turn ``angle_deg`` about the body ``axis`` held vertical, peak rate ``rate_dps``."""

    axis: str
    angle_deg: float = 360.0
    rate_dps: float = 90.0
    settle_s: float = 1.0
    label: str | None = None
    ramp_s: float = 0.5

    def signed(self) -> tuple[int, float]:
        """(index of the axis, signed angle in radians about the positive axis)."""
        if len(self.axis) != 2 or self.axis[0] not in "+-" or self.axis[1] not in AXES:
            raise ValueError(f"rotation axis {self.axis!r} is not a signed axis such as '+z' or '-x'")
        sign = 1.0 if self.axis[0] == "+" else -1.0
        return AXES[self.axis[1]], sign * math.radians(self.angle_deg)

    def default_label(self) -> str:
        """The capture-csv label of this turn: ``rot+z``, or ``rot-x:90`` when not a full turn."""
        index, angle = self.signed()
        sign = "+" if angle >= 0 else "-"
        degrees = abs(math.degrees(angle))
        suffix = "" if math.isclose(degrees, 360.0) else f":{degrees:g}"
        return f"rot{sign}{'xyz'[index]}{suffix}"


@dataclass
class ConstantRate:
    """Turn about the body ``axis`` held vertical at ``rate_dps`` (signed: ``rate-z:90`` is -90 deg/s
    about +z): a linear spin-up over ``ramp_s``, ``settle_s`` at the rate (unlabelled), ``duration_s``
    at the rate under the step's label, a linear spin-down over ``ramp_s``."""

    axis: str
    rate_dps: float
    duration_s: float = 5.0
    settle_s: float = 1.0
    ramp_s: float = 0.5
    label: str | None = None

    def signed(self) -> tuple[int, float]:
        """(index of the axis, signed rate in rad/s about the positive axis)."""
        index, sign = Rotation(self.axis).signed()
        return index, math.copysign(1.0, sign) * math.radians(self.rate_dps)

    def default_label(self) -> str:
        """The capture-csv label of this step: ``rate+z:90`` (the sign is the rate's about +axis)."""
        index, rate = self.signed()
        return f"rate{'+' if rate >= 0 else '-'}{'xyz'[index]}:{abs(math.degrees(rate)):g}"


@dataclass
class RateProfile:
    """Turn about the signed body ``axis`` held up through ``ramps``: ``(rate0_dps, rate1_dps,
    duration_s)`` each, the rate going linearly within each (a table's trapezoidal profile, which
    may start at a rate, unlike :class:`Rotation`). With ``vector`` (body axes, any length), turn
    about that body direction from the attitude the unit has, without putting anything up first
    (a multi-axis table's gimbal, whose axis is fixed in the unit while the others hold)."""

    axis: str
    ramps: tuple[tuple[float, float, float], ...]
    label: str = ""
    vector: tuple[float, float, float] | None = None


@dataclass
class Move:
    """A smooth hand-held move to the next segment's attitude (unlabelled)."""

    duration_s: float = DEFAULT_MOVE_S


Segment = Static | Rotation | ConstantRate | RateProfile | Move


# --- angle profiles phi(tau) over one piece, tau = time since the piece started -------------

class _Hold:
    total = 0.0

    def angle(self, tau: np.ndarray) -> np.ndarray:
        return np.zeros_like(tau)

    def rate(self, tau: np.ndarray) -> np.ndarray:
        return np.zeros_like(tau)


class _Trapezoid:
    """Signed angle A: accelerate at alpha to the peak rate, cruise, decelerate; still before/after."""

    def __init__(self, angle: float, peak_rate: float, ramp_s: float, settle_s: float):
        self.total = angle
        self.sign = 1.0 if angle >= 0 else -1.0
        magnitude = abs(angle)
        alpha = peak_rate / ramp_s
        if magnitude < peak_rate * ramp_s:  # triangle: never reaches the peak rate
            ramp_s = math.sqrt(magnitude / alpha)
            peak_rate = alpha * ramp_s
        self.alpha, self.peak, self.ramp = alpha, peak_rate, ramp_s
        self.cruise = magnitude / peak_rate - ramp_s if peak_rate > 0 else 0.0
        self.settle = settle_s
        self.turn = 2.0 * ramp_s + self.cruise
        self.duration = self.turn + 2.0 * settle_s

    def angle(self, tau: np.ndarray) -> np.ndarray:
        u = np.clip(tau - self.settle, 0.0, self.turn)
        a, r, c = self.alpha, self.ramp, self.cruise
        up = 0.5 * a * u**2
        cruise = 0.5 * a * r**2 + self.peak * (u - r)
        down = abs(self.total) - 0.5 * a * (self.turn - u) ** 2
        return self.sign * np.where(u < r, up, np.where(u < r + c, cruise, down))

    def rate(self, tau: np.ndarray) -> np.ndarray:
        u = tau - self.settle
        ramp_up = self.alpha * u
        ramp_down = self.alpha * (self.turn - u)
        rate = np.minimum(np.minimum(ramp_up, ramp_down), self.peak)
        return self.sign * np.where((u > 0) & (u < self.turn), rate, 0.0)


class _Ramp:
    """Rate going linearly from w0 to w1 over T: phi = w0 tau + (w1 - w0) tau^2 / (2 T)."""

    def __init__(self, w0: float, w1: float, duration: float):
        self.w0, self.w1, self.duration = w0, w1, duration
        self.total = 0.5 * (w0 + w1) * duration

    def angle(self, tau: np.ndarray) -> np.ndarray:
        u = np.clip(tau, 0.0, self.duration)
        return self.w0 * u + (self.w1 - self.w0) * u**2 / (2.0 * self.duration)

    def rate(self, tau: np.ndarray) -> np.ndarray:
        u = np.clip(tau, 0.0, self.duration)
        return self.w0 + (self.w1 - self.w0) * u / self.duration


class _SmoothStep:
    """phi = theta s(u), s = 10u^3 - 15u^4 + 6u^5, u = tau / T; phi' = theta 30u^2 (1-u)^2 / T."""

    def __init__(self, angle: float, duration: float):
        self.total = angle
        self.duration = duration

    def angle(self, tau: np.ndarray) -> np.ndarray:
        u = np.clip(tau / self.duration, 0.0, 1.0)
        return self.total * u**3 * (10.0 - 15.0 * u + 6.0 * u**2)

    def rate(self, tau: np.ndarray) -> np.ndarray:
        u = np.clip(tau / self.duration, 0.0, 1.0)
        return self.total * 30.0 * u**2 * (1.0 - u) ** 2 / self.duration


@dataclass
class Piece:
    """One stretch of motion: R(t) = r0 exp(phi(t - t0) [axis]x) for t0 <= t < t1."""

    t0: float
    t1: float
    r0: np.ndarray
    axis: np.ndarray
    profile: Any
    label: str

    def attitude_at(self, t: float) -> np.ndarray:
        """Attitude (3, 3) at time ``t`` (s), held at the end attitude after ``t1``."""
        phi = self.profile.angle(np.array([min(t, self.t1) - self.t0]))
        return self.r0 @ axis_angle_matrix(self.axis, phi)[0]

    @property
    def r1(self) -> np.ndarray:
        """Attitude (3, 3) at the end of the piece."""
        return self.r0 @ axis_angle_matrix(self.axis, np.array([self.profile.total]))[0]


def _target(segment: Segment, current: np.ndarray) -> np.ndarray:
    if isinstance(segment, Static):
        if segment.attitude is not None:
            return np.asarray(segment.attitude, float)
        return pose_attitude(segment.pose, current)
    if isinstance(segment, Rotation | ConstantRate):
        index, _ = segment.signed()
        return pose_attitude("+" + "xyz"[index], current)
    if isinstance(segment, RateProfile):
        if segment.vector is not None:
            return current
        return pose_attitude(segment.axis, current)  # the mount's signed axis along the table's
    return current


def _move_piece(t0: float, duration: float, r0: np.ndarray, target: np.ndarray) -> Piece:
    axis, angle = matrix_axis_angle(r0.T @ target)
    profile: Any = _SmoothStep(angle, duration) if angle > 1e-12 else _Hold()
    return Piece(t0, t0 + duration, r0, axis, profile, "")


def build_pieces(segments: Sequence[Segment], r_start: np.ndarray, t_start: float,
                 after_last: Segment | None = None) -> tuple[list[Piece], np.ndarray, float]:
    """Pieces of ``segments`` from attitude ``r_start`` at ``t_start``; returns (pieces, r_end, t_end).

    ``after_last`` is the segment that follows the list (a trailing Move turns toward it).

    Parameters
    ----------
    segments : sequence of Segment
    r_start : ndarray, (3, 3)
        Attitude at ``t_start``.
    t_start : float
        s.
    after_last : Segment, optional

    Returns
    -------
    tuple
        The pieces, the end attitude (3, 3) and the end time (s).
    """
    pieces: list[Piece] = []
    r, t = np.asarray(r_start, float), float(t_start)
    segs = list(segments)
    for i, seg in enumerate(segs):
        nxt = segs[i + 1] if i + 1 < len(segs) else after_last
        if isinstance(seg, Move):
            target = _target(nxt, r) if nxt is not None else r
            piece = _move_piece(t, seg.duration_s, r, target)
            pieces.append(piece)
            r, t = target if nxt is not None else r, piece.t1
            continue
        target = _target(seg, r)
        if matrix_axis_angle(r.T @ target)[1] > 1e-9:
            piece = _move_piece(t, DEFAULT_MOVE_S, r, target)
            pieces.append(piece)
            t = piece.t1
        r = target
        if isinstance(seg, Static):
            if seg.duration_s <= 0:
                raise ValueError(f"static segment {seg.pose!r} has a non-positive duration {seg.duration_s}")
            label = seg.pose if seg.label is None else seg.label
            pieces.append(Piece(t, t + seg.duration_s, r, np.array([1.0, 0.0, 0.0]), _Hold(), label))
            t += seg.duration_s
        elif isinstance(seg, ConstantRate):
            index, w = seg.signed()
            label = seg.default_label() if seg.label is None else seg.label
            # spin-up and settling unlabelled, the steady rate labelled, spin-down unlabelled
            parts = ((_Ramp(0.0, w, seg.ramp_s), ""), (_Ramp(w, w, seg.settle_s), ""),
                     (_Ramp(w, w, seg.duration_s), label), (_Ramp(w, 0.0, seg.ramp_s), ""))
            for ramp, piece_label in parts:
                if ramp.duration <= 0:
                    continue
                piece = Piece(t, t + ramp.duration, r, np.eye(3)[index], ramp, piece_label)
                pieces.append(piece)
                r, t = piece.r1, piece.t1
        elif isinstance(seg, RateProfile):
            if seg.vector is not None:
                about, sign = np.asarray(seg.vector, float) / np.linalg.norm(seg.vector), 1.0
            else:
                index, turn = Rotation(seg.axis).signed()
                about, sign = np.eye(3)[index], (1.0 if turn > 0 else -1.0)  # about -z at w is about +z at -w
            for w0, w1, duration in seg.ramps:
                if duration <= 0:
                    continue
                ramp = _Ramp(sign * math.radians(w0), sign * math.radians(w1), duration)
                piece = Piece(t, t + duration, r, about, ramp, seg.label)
                pieces.append(piece)
                r, t = piece.r1, piece.t1
        else:
            index, angle = seg.signed()
            profile = _Trapezoid(angle, math.radians(seg.rate_dps), seg.ramp_s, seg.settle_s)
            label = seg.default_label() if seg.label is None else seg.label
            piece = Piece(t, t + profile.duration, r, np.eye(3)[index], profile, label)
            pieces.append(piece)
            r, t = piece.r1, piece.t1
    return pieces, r, t


class Timeline:
    """Motion of the unit over time: a list of pieces, held at the end, looped, or commanded live.

    ``loop=True`` repeats ``segments`` forever (with a move back to the first attitude);
    otherwise the unit holds its last attitude. ``command(segments, t)`` replaces whatever
    follows time t with new segments started from the attitude at t, then a hold: the hook
    a simulated operator or turntable uses to move the unit as a sequence asks.
    """

    def __init__(self, segments: Sequence[Segment], loop: bool = False, r_start: np.ndarray | None = None):
        self.loop = loop
        self._cycle = list(segments)
        r0 = np.eye(3) if r_start is None else np.asarray(r_start, float)
        after = (Move(DEFAULT_MOVE_S) if loop else None)
        pieces, r, t = build_pieces(self._cycle, r0, 0.0, after_last=after)
        self.pieces = pieces
        self.duration_s = t  # of the first pass through the segments
        self._end_r, self._end_t = r, t
        if not loop:
            self._append_hold()

    def _append_hold(self) -> None:
        self.pieces.append(Piece(self._end_t, math.inf, self._end_r, np.array([1.0, 0.0, 0.0]), _Hold(), ""))
        self._end_t = math.inf

    def _extend(self, t: float) -> None:
        while self.loop and self._end_t <= t:
            segs = [Move(DEFAULT_MOVE_S), *self._cycle]
            pieces, self._end_r, self._end_t = build_pieces(segs, self._end_r, self._end_t,
                                                            after_last=Move(DEFAULT_MOVE_S))
            self.pieces.extend(pieces)

    def prune(self, t: float) -> None:
        """Forget pieces that ended before ``t`` (a long-running device keeps memory bounded)."""
        keep = next((i for i, p in enumerate(self.pieces) if p.t1 > t), len(self.pieces) - 1)
        del self.pieces[:keep]

    def attitude_at(self, t: float) -> np.ndarray:
        """Attitude (3, 3) of the unit at time ``t`` (s), extending the timeline as needed."""
        self._extend(t)
        for p in self.pieces:
            if p.t0 <= t < p.t1:
                return p.attitude_at(t)
        return self.pieces[-1].attitude_at(t)

    def command(self, segments: Sequence[Segment], t: float) -> float:
        """Drive the unit from time ``t`` with ``segments``, then hold; returns the time they end."""
        r = self.attitude_at(t)
        kept = [p for p in self.pieces if p.t0 < t]
        if kept:
            kept[-1].t1 = t
        pieces, self._end_r, end = build_pieces(segments, r, t)
        self.pieces = kept + pieces
        self._end_t = end
        self.loop = False
        self._append_hold()
        return end

    def evaluate(self, t: np.ndarray,
                 world_vectors: Sequence[np.ndarray]) -> tuple[np.ndarray, list, np.ndarray]:
        """Body rate (N, 3), each world vector seen in the body frame [(N, 3)], labels (N,)."""
        t = np.asarray(t, float)
        if len(t):
            self._extend(float(t[-1]))
        rate = np.zeros((len(t), 3))
        seen = [np.zeros((len(t), 3)) for _ in world_vectors]
        labels = np.empty(len(t), dtype=object)
        starts = np.array([p.t0 for p in self.pieces])
        index = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        for i in np.unique(index):
            piece = self.pieces[i]
            sel = index == i
            labels[sel] = piece.label
            if isinstance(piece.profile, _Hold):
                for out, w in zip(seen, world_vectors, strict=True):
                    out[sel] = piece.r0.T @ w
                continue
            tau = t[sel] - piece.t0
            phi = piece.profile.angle(tau)
            rate[sel] = np.outer(piece.profile.rate(tau), piece.axis)
            for out, w in zip(seen, world_vectors, strict=True):
                # R^T w = exp(-phi [e]x) (r0^T w)
                out[sel] = rotate_vectors(piece.axis, -phi, piece.r0.T @ w)
        return rate, seen, labels

    def attitudes(self, t: np.ndarray) -> np.ndarray:
        """Attitude matrices (N, 3, 3) at times ``t`` (body to world)."""
        t = np.asarray(t, float)
        if len(t):
            self._extend(float(t[-1]))
        out = np.empty((len(t), 3, 3))
        starts = np.array([p.t0 for p in self.pieces])
        index = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        for i in np.unique(index):
            piece = self.pieces[i]
            sel = index == i
            out[sel] = piece.r0 @ axis_angle_matrix(piece.axis, piece.profile.angle(t[sel] - piece.t0))
        return out


def sequence_segments(name: str = "six-position", rotations: bool = True, hold_s: float = 5.0,
                      rotation_rate_dps: float = 90.0, move_s: float = DEFAULT_MOVE_S) -> list[Segment]:
    """The built-in sequences of the capture-csv spec, a move before every step.

    Parameters
    ----------
    name : str
        ``six-position`` or ``twelve-position``.
    rotations : bool
        Add the six rotations.
    hold_s : float
        Seconds per pose.
    rotation_rate_dps : float
    move_s : float
        Seconds per move between steps.

    Returns
    -------
    list of Segment

    Raises
    ------
    ValueError
        An unknown name.
    """
    poses = {"six-position": SIX_POSITION, "twelve-position": TWELVE_POSITION}.get(name)
    if poses is None:
        raise ValueError(f"unknown sequence {name!r}; known: six-position, twelve-position")
    segments: list[Segment] = []
    for pose in poses:
        segments += [Move(move_s), Static(pose, hold_s)]
    if rotations:
        for axis in SEQUENCE_ROTATIONS:
            segments += [Move(move_s), Rotation(axis, 360.0, rotation_rate_dps)]
    return segments


def handheld_session(n_poses: int = 12, seed: int = 0, hold_s: float = 2.0, initial_still_s: float = 10.0,
                     move_s: float = DEFAULT_MOVE_S) -> list[Segment]:
    """imu_tk-style session: lying flat still, then random attitudes (uniform on SO(3)) held
    ``hold_s`` each, joined by smooth moves. Unlabelled: such sessions carry no step labels.

    Parameters
    ----------
    n_poses : int
    seed : int
    hold_s : float
        Seconds per attitude.
    initial_still_s : float
    move_s : float

    Returns
    -------
    list of Segment
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x4A4D]))
    segments: list[Segment] = [Static("+z", initial_still_s, label="")]
    for _ in range(n_poses):
        segments += [Move(move_s), Static("", hold_s, label="", attitude=random_attitude(rng))]
    return segments


# --- temperature --------------------------------------------------------------------------

class TemperatureProfile:
    """True temperature (degC) as a piecewise-linear function of time (s), held beyond the ends."""

    def __init__(self, times_s: Sequence[float], temps_degc: Sequence[float]):
        self.times = np.asarray(times_s, float)
        self.temps = np.asarray(temps_degc, float)
        if len(self.times) == 0 or len(self.times) != len(self.temps) or np.any(np.diff(self.times) <= 0):
            raise ValueError("temperature points need increasing times and one temperature each")

    def __call__(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.times, self.temps)

    def rate(self, t: np.ndarray) -> np.ndarray:
        """dT/dt (degC/s): the slope of the linear piece holding t (zero outside the points)."""
        t = np.asarray(t, float)
        if len(self.times) < 2:
            return np.zeros_like(t)
        slopes = np.diff(self.temps) / np.diff(self.times)
        index = np.searchsorted(self.times, t, side="right") - 1
        inside = (index >= 0) & (index < len(slopes))
        return np.where(inside, slopes[np.clip(index, 0, len(slopes) - 1)], 0.0)

    @staticmethod
    def constant(temp_degc: float = 25.0) -> TemperatureProfile:
        """A constant temperature ``temp_degc``: :func:`constant`."""
        return constant(temp_degc)

    @staticmethod
    def ramp(points: Sequence[tuple[float, float]]) -> TemperatureProfile:
        """Piecewise-linear through ``points``: :func:`ramp`."""
        return ramp(points)


def constant(temp_degc: float = 25.0) -> TemperatureProfile:
    """A profile that holds ``temp_degc`` throughout.

    Parameters
    ----------
    temp_degc : float

    Returns
    -------
    TemperatureProfile
    """
    return TemperatureProfile([0.0], [temp_degc])


def ramp(points: Sequence[tuple[float, float]]) -> TemperatureProfile:
    """Piecewise-linear through ``points`` [(t_s, degC), ...].

    Parameters
    ----------
    points : sequence of (float, float)

    Returns
    -------
    TemperatureProfile
    """
    times, temps = zip(*points, strict=True)
    return TemperatureProfile(times, temps)


def temperature_rate(profile: Callable[[np.ndarray], np.ndarray], t: np.ndarray) -> np.ndarray:
    """dT/dt of any profile: its own ``rate`` if it has one, else a central difference (h = 1 ms).

    Parameters
    ----------
    profile : callable
        Temperature (degC) of times (s).
    t : ndarray, (N,)

    Returns
    -------
    ndarray, (N,)
        degC/s.
    """
    if hasattr(profile, "rate"):
        return np.asarray(profile.rate(t), float)
    h = 1e-3
    return (np.asarray(profile(t + h), float) - np.asarray(profile(t - h), float)) / (2 * h)


# --- sampling -----------------------------------------------------------------------------

@dataclass
class Recording:
    """Sampled output of the simulated unit with its truth, SI units.

    ``acc``/``gyro`` are raw (what the unit reports, float64 before the wire's float32);
    ``true_rate`` is the inertial rate in the body frame (rig rate + Earth rate if enabled).
    ``acc_bias``/``gyro_bias`` (N, 3) are the biases each triad really carried at each sample
    (``SensorTruth.realized_bias``: static bias + thermal bias + bias instability + random walk),
    so that a bias estimated from some samples can be compared with the mean bias over those samples
    as well as with the static ``truth.accel.bias``; None where the maker did not know them.
    """

    t: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    temp: np.ndarray
    temp_true: np.ndarray
    dtemp_true: np.ndarray
    step: np.ndarray
    true_specific_force: np.ndarray
    true_rate: np.ndarray
    truth: UnitTruth
    rate_hz: float = 200.0
    first_seq: int = 0
    timeline: Timeline | None = field(default=None, repr=False)
    acc_bias: np.ndarray | None = field(default=None, repr=False)
    gyro_bias: np.ndarray | None = field(default=None, repr=False)
    # A unit with a magnetometer (truth.mag): the raw field (N, 3) and the true one in body axes, uT.
    mag: np.ndarray | None = field(default=None, repr=False)
    true_field: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.t)

    def samples(self) -> np.ndarray:
        """The samples as the wire carries them (``SAMPLE_DTYPE``: seq, t_us, float32 values;
        ``MAG_SAMPLE_DTYPE`` with the field for a unit with a magnetometer)."""
        from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE

        out = np.zeros(len(self.t), dtype=SAMPLE_DTYPE if self.mag is None else MAG_SAMPLE_DTYPE)
        out["seq"] = (self.first_seq + np.arange(len(self.t))) % (1 << 32)
        out["t_us"] = np.round(self.t * 1e6).astype(np.uint64)
        out["acc"] = self.acc
        out["gyro"] = self.gyro
        out["temp"] = self.temp
        if self.mag is not None:
            out["mag"] = self.mag
        return out

    def attitude(self) -> np.ndarray:
        """True attitude (N, 3, 3), body to world."""
        if self.timeline is None:
            raise ValueError("this recording was made without its timeline")
        return self.timeline.attitudes(self.t)

    def to_capture(self, true_dtemp: bool = False) -> Any:
        """A ``station.acquisition.capture.Capture`` as a capture of this unit would hold it
        (float32 values as on the wire); ``true_dtemp`` adds the true dT column."""
        from station.acquisition.capture import Capture

        s = self.samples()
        return Capture(
            t=s["t_us"] / 1e6,
            acc=s["acc"].astype(float),
            gyro=s["gyro"].astype(float),
            temp=s["temp"].astype(float),
            dtemp=self.dtemp_true.copy() if true_dtemp else None,
            step=np.array([str(x) for x in self.step], dtype=object),
            device=self.truth.device_info(self.rate_hz),
            source=f"simulated unit {self.truth.serial}",
            mag=None if self.mag is None else s["mag"].astype(float),
        )


class UnitSampler:
    """Samples a unit moved by a timeline, block after block, with the same numbers whatever
    the block sizes: ``next(n)`` returns the next n samples as a :class:`Recording`.

    Sample k is taken at ``t_base + (k - k_base) / rate_hz`` on the device clock; ``set_rate``
    starts a new base at the next sample's time.
    """

    def __init__(self, truth: UnitTruth, timeline: Timeline, rate_hz: float = 200.0, seed: int = 0,
                 temperature: Callable[[np.ndarray], np.ndarray] | None = None,
                 temp_noise_degc: float = 0.01):
        if rate_hz <= 0:
            raise ValueError(f"rate {rate_hz} Hz must be positive")
        self.truth = truth
        self.timeline = timeline
        self.temperature = temperature if temperature is not None else constant(25.0)
        self.temp_noise_degc = temp_noise_degc
        acc_seed, gyro_seed, temp_seed = np.random.SeedSequence(int(seed)).spawn(3)
        self._acc_noise = NoiseGenerator(truth.accel.noise, rate_hz, acc_seed)
        self._gyro_noise = NoiseGenerator(truth.gyro.noise, rate_hz, gyro_seed)
        self._temp_rng = np.random.default_rng(temp_seed)
        self._gravity_world = np.array([0.0, 0.0, truth.gravity])
        self._earth_world = (earth_rate_world(truth.latitude_deg, truth.heading_deg) if truth.earth_rate
                             else None)
        self._mag_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x3A7]))
        self.rate_hz = float(rate_hz)
        self.count = 0  # samples produced so far
        self._k_base = 0
        self._t_base = 0.0

    def time_of(self, k: int) -> float:
        """Device-clock time (s) of sample number ``k`` under the current rate."""
        return self._t_base + (k - self._k_base) / self.rate_hz

    def due_count(self, t_s: float) -> int:
        """How many samples fall due at or before time ``t_s`` and are not produced yet."""
        last = self._k_base + math.floor((t_s - self._t_base) * self.rate_hz + 1e-9)
        return max(0, last + 1 - self.count)

    def set_rate(self, rate_hz: float) -> None:
        """Change the sample rate from the next sample on (time stays continuous)."""
        self._t_base = self.time_of(self.count)
        self._k_base = self.count
        self.rate_hz = float(rate_hz)
        self._acc_noise.set_rate(rate_hz)
        self._gyro_noise.set_rate(rate_hz)

    def next(self, n: int) -> Recording:
        """The next ``n`` samples of the unit as a :class:`Recording` (labels, truth and noise included)."""
        k = np.arange(self.count, self.count + n)
        t = self._t_base + (k - self._k_base) / self.rate_hz
        worlds = [self._gravity_world] + ([self._earth_world] if self._earth_world is not None else [])
        mag = self.truth.mag
        if mag is not None:
            worlds.append(mag.field.world(self.truth.heading_deg))
        rig_rate, seen, labels = self.timeline.evaluate(t, worlds)
        force = seen[0]
        rate = rig_rate + seen[1] if self._earth_world is not None else rig_rate
        temp_true = np.asarray(self.temperature(t), float) * np.ones(n)
        dtemp_true = temperature_rate(self.temperature, t) * np.ones(n)
        acc_noise, acc_drift = self._acc_noise.next_with_drift(n)
        gyro_noise, gyro_drift = self._gyro_noise.next_with_drift(n)
        acc = self.truth.accel.measure(force, temp_true, dtemp_true, acc_noise)
        if np.any(self.truth.g_sensitivity):
            gyro_noise = gyro_noise + force @ self.truth.g_sensitivity.T  # raw += G f
        gyro = self.truth.gyro.measure(rate, temp_true, dtemp_true, gyro_noise)
        temp = temp_true + self._temp_rng.standard_normal(n) * self.temp_noise_degc
        rec = Recording(t=t, acc=acc, gyro=gyro, temp=temp, temp_true=temp_true, dtemp_true=dtemp_true,
                        step=labels, true_specific_force=force, true_rate=rate, truth=self.truth,
                        rate_hz=self.rate_hz, first_seq=self.count, timeline=self.timeline,
                        acc_bias=self.truth.accel.realized_bias(temp_true, dtemp_true, acc_drift),
                        gyro_bias=self.truth.gyro.realized_bias(temp_true, dtemp_true, gyro_drift))
        if mag is not None:
            rec.true_field = seen[-1]
            rec.mag = mag.measure(seen[-1], self._mag_rng)
        self.count += n
        return rec


def simulate(truth: UnitTruth, segments: Sequence[Segment], rate_hz: float = 200.0, seed: int = 0,
             temperature: Callable[[np.ndarray], np.ndarray] | None = None,
             temp_noise_degc: float = 0.01) -> Recording:
    """Sample ``truth`` moved through ``segments`` at ``rate_hz`` (samples at k / rate_hz, s).

    The recording covers the segments (plus implicit moves), ``round(duration * rate_hz)``
    samples, starting lying flat (+z up, attitude I). Same arguments, same arrays.

    Parameters
    ----------
    truth : UnitTruth
    segments : sequence of Segment
    rate_hz : float
    seed : int
        Seed of the noise.
    temperature : callable, optional
        Temperature profile; default a constant 25 degC.
    temp_noise_degc : float
        Noise of the temperature reading.

    Returns
    -------
    Recording
    """
    timeline = Timeline(segments, loop=False)
    n = int(round(timeline.duration_s * rate_hz))
    return UnitSampler(truth, timeline, rate_hz, seed, temperature, temp_noise_degc).next(n)
