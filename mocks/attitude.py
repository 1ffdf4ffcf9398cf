"""Rotation helpers of the rig: named poses, Rodrigues' formula vectorised, axis-angle.

Attitudes are rotation matrices R from the body (sensor) frame to the world frame (z up):
a vector v_b in the body frame is R v_b in the world frame. With a body-frame angular
rate w_b, dR/dt = R [w_b]x.
"""

from __future__ import annotations

import re

import numpy as np

AXES = {"x": 0, "y": 1, "z": 2}
_POSE_RE = re.compile(r"^(?:[+-][xyz])+$")


def parse_signed_axes(text: str) -> np.ndarray:
    """``"+x+y"`` -> the unit vector (1, 1, 0)/sqrt(2) (capture-csv spec pose names).

    Parameters
    ----------
    text : str

    Returns
    -------
    ndarray, (3,)

    Raises
    ------
    ValueError
        Not signed axes, or an axis named twice.
    """
    if not _POSE_RE.match(text):
        raise ValueError(f"pose {text!r} is not a list of signed axes such as '+z', '-x' or '+x+y'")
    v = np.zeros(3)
    for sign, axis in re.findall(r"([+-])([xyz])", text):
        if v[AXES[axis]] != 0:
            raise ValueError(f"pose {text!r} names axis {axis} twice")
        v[AXES[axis]] = 1.0 if sign == "+" else -1.0
    return v / np.linalg.norm(v)


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix [v]x of v (3,): [v]x w = v x w.

    Parameters
    ----------
    v : ndarray, (3,)

    Returns
    -------
    ndarray, (3, 3)
    """
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def axis_angle_matrix(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: exp(angle [axis]x) for a unit ``axis`` (3,) and angles (N,) -> (N, 3, 3).

    Parameters
    ----------
    axis : ndarray, (3,)
        Unit axis.
    angle : ndarray, (N,)
        rad.

    Returns
    -------
    ndarray, (N, 3, 3)
    """
    angle = np.asarray(angle, float)
    k = skew(np.asarray(axis, float))
    k2 = k @ k
    s = np.sin(angle)[..., None, None]
    c = (1.0 - np.cos(angle))[..., None, None]
    return np.eye(3) + s * k + c * k2


def rotate_vectors(axis: np.ndarray, angle: np.ndarray, v: np.ndarray) -> np.ndarray:
    """exp(angle [axis]x) v for angles (N,) and one vector or vectors (N, 3) -> (N, 3).

    Parameters
    ----------
    axis : ndarray, (3,)
        Unit axis.
    angle : ndarray, (N,)
        rad.
    v : ndarray, (3,) or (N, 3)

    Returns
    -------
    ndarray, (N, 3)
    """
    angle = np.asarray(angle, float)[:, None]
    axis = np.asarray(axis, float)
    v = np.broadcast_to(np.asarray(v, float), (angle.shape[0], 3))
    cross = np.cross(axis, v)
    dot = np.einsum("nk,k->n", v, axis)
    return v * np.cos(angle) + cross * np.sin(angle) + np.outer(dot, axis) * (1.0 - np.cos(angle))


def matrix_axis_angle(r: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit axis and angle in [0, pi] of a rotation matrix (axis +x for the identity).

    Parameters
    ----------
    r : ndarray, (3, 3)

    Returns
    -------
    tuple
        Unit axis (3,) and angle, rad.
    """
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    sin2 = float(np.linalg.norm(v))  # 2 sin(angle)
    cos = (np.trace(r) - 1.0) / 2.0
    angle = float(np.arctan2(sin2 / 2.0, cos))
    if cos > 0 or sin2 > 1e-6:
        if sin2 < 1e-15:
            return np.array([1.0, 0.0, 0.0]), 0.0
        return v / sin2, angle
    # Near pi the antisymmetric part vanishes: take the axis from (R + I) / 2 ~ a a^T.
    m = (r + np.eye(3)) / 2.0
    col = int(np.argmax(np.diag(m)))
    axis = m[:, col] / np.linalg.norm(m[:, col])
    if np.dot(axis, v) < 0:
        axis = -axis
    return axis, angle


def minimal_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation of least angle taking unit vector ``a`` to unit vector ``b`` (3, 3).

    Parameters
    ----------
    a, b : ndarray, (3,)
        Unit vectors.

    Returns
    -------
    ndarray, (3, 3)
    """
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    cross = np.cross(a, b)
    sin = np.linalg.norm(cross)
    cos = float(np.dot(a, b))
    if sin < 1e-12:
        if cos > 0:
            return np.eye(3)
        # Opposite vectors: half a turn about any axis perpendicular to a.
        helper = np.eye(3)[int(np.argmin(np.abs(a)))]
        axis = np.cross(a, helper)
        return axis_angle_matrix(axis / np.linalg.norm(axis), np.array([np.pi]))[0]
    return axis_angle_matrix(cross / sin, np.array([np.arctan2(sin, cos)]))[0]


def pose_attitude(pose: str, current: np.ndarray | None = None) -> np.ndarray:
    """Attitude with the body direction ``pose`` pointing up, reached from ``current``.

    The rig turns the unit the least angle that brings the pose's body direction up, as a
    hand would: R' = Q R with Q the minimal world rotation from (R u) to z. From the
    identity this gives each named pose a fixed attitude.

    Parameters
    ----------
    pose : str
        Signed axes, e.g. ``+x-y``.
    current : ndarray, (3, 3), optional
        Attitude to turn from (body to world); default the identity.

    Returns
    -------
    ndarray, (3, 3)
    """
    current = np.eye(3) if current is None else current
    up_body = parse_signed_axes(pose)
    return minimal_rotation(current @ up_body, np.array([0.0, 0.0, 1.0])) @ current


def random_attitude(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix uniformly distributed on SO(3) (normalised Gaussian quaternion).

    Parameters
    ----------
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, (3, 3)
    """
    w, x, y, z = rng.standard_normal(4)
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])
