"""Motions for calibrating a magnetometer, and simulated captures of them with their truth.

- :func:`sphere_session`: the unit turned around by hand through attitudes uniform on SO(3),
  held still a moment at each, so the field directions cover the whole sphere.
- :func:`desk_session`: the unit turned on a desk: its z axis never more than ``max_tilt_deg``
  from up (tilts uniform over that cap), any heading; still at each pose. Between poses it is
  tilted back level, turned about the vertical and tilted again, so the z axis stays inside the
  cap during the moves too. The field directions cover only a band of the sphere: the partial
  coverage a calibration has to stay well-conditioned on.

Holds are unlabelled (such sessions carry no step labels); a calibration finds the still poses
itself. :func:`mag_capture` samples either session with a nine-axis simulated unit.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mocks.attitude import axis_angle_matrix, random_attitude
from mocks.magnetometer import EarthField, MagTruth
from mocks.rig import Move, Segment, Static, simulate
from mocks.truth import UnitTruth

SESSIONS = ("sphere", "desk")
_SEED_SALT = 0x3A65


def _hold(attitude: np.ndarray, hold_s: float) -> Static:
    return Static("", hold_s, label="", attitude=attitude)


def sphere_session(n_poses: int = 30, seed: int = 0, hold_s: float = 2.0, move_s: float = 2.0,
                   initial_still_s: float = 2.0) -> list[Segment]:
    """Hand-held turns through ``n_poses`` attitudes uniform on SO(3), each held ``hold_s``.

    Parameters
    ----------
    n_poses : int
    seed : int
    hold_s, move_s, initial_still_s : float
        Seconds per hold, per move, and lying flat at the start.

    Returns
    -------
    list of Segment
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), _SEED_SALT, 1]))
    segments: list[Segment] = [Static("+z", initial_still_s, label="")]
    for _ in range(n_poses):
        segments += [Move(move_s), _hold(random_attitude(rng), hold_s)]
    return segments


def _tilted(yaw: float, tilt_axis_azimuth: float, tilt: float) -> np.ndarray:
    """Body to world: turned ``yaw`` about the vertical, then tilted ``tilt`` about a body axis
    that is horizontal at azimuth ``tilt_axis_azimuth`` (radians); the z axis is ``tilt`` from up."""
    up = np.array([0.0, 0.0, 1.0])
    axis = np.array([np.cos(tilt_axis_azimuth), np.sin(tilt_axis_azimuth), 0.0])
    return axis_angle_matrix(up, np.array([yaw]))[0] @ axis_angle_matrix(axis, np.array([tilt]))[0]


def desk_session(n_poses: int = 30, seed: int = 0, max_tilt_deg: float = 45.0, hold_s: float = 2.0,
                 move_s: float = 1.0, initial_still_s: float = 2.0) -> list[Segment]:
    """Turns on a desk: ``n_poses`` still poses with the z axis within ``max_tilt_deg`` of up.

    Tilts are uniform over the spherical cap (cos of the tilt uniform), headings uniform. Each
    pose is reached level-turn-tilt (three moves of ``move_s``), so no move leaves the cap.

    Parameters
    ----------
    n_poses : int
    seed : int
    max_tilt_deg : float
    hold_s, move_s, initial_still_s : float
        Seconds per hold, per move, and lying flat at the start.

    Returns
    -------
    list of Segment

    Raises
    ------
    ValueError
        ``max_tilt_deg`` outside 0..90.
    """
    if not 0.0 <= max_tilt_deg <= 90.0:
        raise ValueError(f"max_tilt_deg {max_tilt_deg} is outside 0..90")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), _SEED_SALT, 2]))
    cos_max = np.cos(np.radians(max_tilt_deg))
    segments: list[Segment] = [Static("+z", initial_still_s, label="")]
    yaw = 0.0
    for _ in range(n_poses):
        new_yaw = rng.uniform(0.0, 2.0 * np.pi)
        tilt = np.arccos(rng.uniform(cos_max, 1.0))
        azimuth = rng.uniform(0.0, 2.0 * np.pi)
        segments += [Move(move_s), _hold(_tilted(yaw, 0.0, 0.0), 0.2),  # level again
                     Move(move_s), _hold(_tilted(new_yaw, 0.0, 0.0), 0.2),  # turned about the vertical
                     Move(move_s), _hold(_tilted(new_yaw, azimuth, tilt), hold_s)]
        yaw = new_yaw
    return segments


def mag_session(kind: str, seed: int = 0, **options: Any) -> list[Segment]:
    """The session ``kind`` (``SESSIONS``): :func:`sphere_session` or :func:`desk_session`.

    Parameters
    ----------
    kind : str
    seed : int
    **options
        Passed to the session function (``n_poses``, ``hold_s``, ...).

    Returns
    -------
    list of Segment

    Raises
    ------
    ValueError
        An unknown kind.
    """
    if kind == "sphere":
        return sphere_session(seed=seed, **options)
    if kind == "desk":
        return desk_session(seed=seed, **options)
    raise ValueError(f"unknown magnetometer session {kind!r}; known: {', '.join(SESSIONS)}")


def nine_axis_unit(seed: int = 0, earth: EarthField | None = None, grade: str = "mems") -> UnitTruth:
    """A random simulated unit (``UnitTruth.random``) with a random magnetometer (``MagTruth.random``).

    Parameters
    ----------
    seed : int
    earth : EarthField, optional
    grade : str

    Returns
    -------
    UnitTruth
    """
    truth = UnitTruth.random(seed, grade=grade)
    truth.mag = MagTruth.random(seed, earth)
    return truth


def mag_capture(kind: str = "sphere", seed: int = 0, rate_hz: float = 100.0, truth: UnitTruth | None = None,
                **options: Any) -> tuple[Any, UnitTruth]:
    """A simulated capture of a magnetometer session, and the unit's truth.

    Parameters
    ----------
    kind : str
        ``"sphere"`` (turned around by hand) or ``"desk"`` (z axis within 45 deg of up).
    seed : int
        Seeds the unit (when ``truth`` is None), the poses and the noise.
    rate_hz : float
    truth : UnitTruth, optional
        Default :func:`nine_axis_unit` of ``seed``; it must have a magnetometer.
    **options
        Passed to the session (``n_poses``, ``max_tilt_deg``, ``hold_s``, ...).

    Returns
    -------
    tuple
        (``station.acquisition.capture.Capture`` with ``mag``, ``UnitTruth``); the truth's
        ``mag.correct`` maps the capture's raw field to the field in body axes.

    Raises
    ------
    ValueError
        A truth without a magnetometer, or an unknown kind.
    """
    truth = truth if truth is not None else nine_axis_unit(seed)
    if truth.mag is None:
        raise ValueError("the unit has no magnetometer: give a UnitTruth with mag set")
    rec = simulate(truth, mag_session(kind, seed, **options), rate_hz=rate_hz, seed=seed)
    return rec.to_capture(), truth
