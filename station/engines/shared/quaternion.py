"""Quaternion helpers for gyro integration: the RK4 step as a matrix, rotations and their derivatives.

Quaternions are ``[w, x, y, z]`` (scalar first), Hamilton product, body-frame rates:

    dq/dt = 1/2 Omega(omega) q,     Omega(w) = [[0, -wx, -wy, -wz],
                                                [wx,  0,  wz, -wy],
                                                [wy, -wz,  0,  wx],
                                                [wz,  wy, -wx,  0]]        (1)

so that q(t) maps vectors of the body frame at t to the frame at the start (R(q) v = q v q*).
"""

from __future__ import annotations

import numpy as np

# Omega(w) = sum_i w_i * _OMEGA_BASIS[i]  (eq. 1), linear in w.
_OMEGA_BASIS = np.zeros((3, 4, 4))
_OMEGA_BASIS[0][[1, 0, 2, 3], [0, 1, 3, 2]] = [1, -1, 1, -1]
_OMEGA_BASIS[1][[2, 0, 3, 1], [0, 2, 1, 3]] = [1, -1, 1, -1]
_OMEGA_BASIS[2][[3, 0, 1, 2], [0, 3, 2, 1]] = [1, -1, 1, -1]


def omega_matrix(w: np.ndarray) -> np.ndarray:
    """Omega(w) of eq. (1).

    Parameters
    ----------
    w : ndarray, (..., 3)
        Rates, rad/s.

    Returns
    -------
    ndarray, (..., 4, 4)
    """
    return np.einsum("...i,ijk->...jk", np.asarray(w, float), _OMEGA_BASIS)


def qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p (x) q.

    Parameters
    ----------
    p, q : ndarray, (..., 4)
        Quaternions (w, x, y, z).

    Returns
    -------
    ndarray, (..., 4)
    """
    p = np.asarray(p, float)
    q = np.asarray(q, float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = pw * qw - px * qx - py * qy - pz * qz
    out[..., 1] = pw * qx + px * qw + py * qz - pz * qy
    out[..., 2] = pw * qy - px * qz + py * qw + pz * qx
    out[..., 3] = pw * qz + px * qy - py * qx + pz * qw
    return out


# R(p) and L(p) entry (j, k) is sign[j, k] * p[_INDEX[j, k]].
_INDEX = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_RIGHT_SIGN = np.array([[1, -1, -1, -1], [1, 1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1]], float)
_LEFT_SIGN = np.array([[1, -1, -1, -1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, 1, 1]], float)


def conjugate(p: np.ndarray) -> np.ndarray:
    """p* = (w, -x, -y, -z). Row vectors times the product matrices are products again, as
    R(p)^T = R(p*) and L(p)^T = L(p*): u R(p) = u (x) p* and u L(p) = p* (x) u, 16 products per row
    where a stack of 4 x 4 matrix products costs a BLAS call each.

    Parameters
    ----------
    p : ndarray, (..., 4)

    Returns
    -------
    ndarray, (..., 4)
    """
    return np.asarray(p, float) * _CONJUGATE


_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


def right_matrix(p: np.ndarray) -> np.ndarray:
    """R(p) with R(p) q = q (x) p; Omega(w) of eq. (1) is R((0, w)).

    Parameters
    ----------
    p : ndarray, (..., 4)

    Returns
    -------
    ndarray, (..., 4, 4)
    """
    return np.asarray(p, float)[..., _INDEX] * _RIGHT_SIGN


def left_matrix(p: np.ndarray) -> np.ndarray:
    """L(p) with L(p) q = p (x) q.

    Parameters
    ----------
    p : ndarray, (..., 4)

    Returns
    -------
    ndarray, (..., 4, 4)
    """
    return np.asarray(p, float)[..., _INDEX] * _LEFT_SIGN


def _pure(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    out = np.zeros(v.shape[:-1] + (4,))
    out[..., 1:] = v
    return out


def _times_pure(p: np.ndarray, v: np.ndarray) -> np.ndarray:
    """p (x) (0, v): ``qmul`` with the second factor's scalar part zero (12 products, not 16)."""
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    out = np.empty(np.broadcast_shapes(p.shape, v.shape[:-1] + (4,)))
    out[..., 0] = -(px * vx + py * vy + pz * vz)
    out[..., 1] = pw * vx + py * vz - pz * vy
    out[..., 2] = pw * vy - px * vz + pz * vx
    out[..., 3] = pw * vz + px * vy - py * vx
    return out


def _pure_times(v: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(0, v) (x) q: ``qmul`` with the first factor's scalar part zero."""
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(v.shape[:-1] + (4,), q.shape))
    out[..., 0] = -(vx * qx + vy * qy + vz * qz)
    out[..., 1] = vx * qw + vy * qz - vz * qy
    out[..., 2] = vy * qw - vx * qz + vz * qx
    out[..., 3] = vz * qw + vx * qy - vy * qx
    return out


def rk4_step(w0: np.ndarray, w1: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """One RK4 step of eq. (1) as a quaternion: q_{n+1} = q_n (x) a (before normalisation).

    With H = Omega/2 at the step's start (H0), midpoint (Hm, from the mean rate) and end (H1),
    the classical RK4 stages are k_i = B_i q with

        B1 = H0,  B2 = Hm (I + dt/2 B1),  B3 = Hm (I + dt/2 B2),  B4 = H1 (I + dt B3),
        A  = I + dt/6 (B1 + 2 B2 + 2 B3 + B4).                                         (2)

    Every H is a right multiplication, H = R(h) with h = (0, w/2), and R(x) R(y) = R(y (x) x),
    so A = R(a) with the quaternion

        b2 = hm + dt/2 h0 (x) hm,  b3 = hm + dt/2 b2 (x) hm,  b4 = h1 + dt b3 (x) h1,
        a  = 1 + dt/6 (h0 + 2 b2 + 2 b3 + b4).                                         (3)

    This is imu_tk's ``quatIntegrationStepRK4``; normalising after every step (as imu_tk does)
    only rescales q, so normalising once at the end gives the same rotation.

    Parameters
    ----------
    w0, w1 : ndarray, (..., 3)
        Rates at the step's start and end, rad/s.
    dt : ndarray, (...)
        Step, s.

    Returns
    -------
    tuple
        ``a`` (..., 4) and the stages (h0, hm, h1, b2, b3) for :func:`rk4_step_gradients`.
    """
    w0 = np.asarray(w0, float)
    w1 = np.asarray(w1, float)
    dt = np.asarray(dt, float)[..., None]
    # h0, hm, h1 are pure: their products skip the zero scalar part
    v0, vm, v1 = 0.5 * w0, 0.25 * (w0 + w1), 0.5 * w1
    h0, hm, h1 = _pure(v0), _pure(vm), _pure(v1)
    b2 = hm + 0.5 * dt * _pure_times(v0, hm)
    b3 = hm + 0.5 * dt * _times_pure(b2, vm)
    b4 = h1 + dt * _times_pure(b3, v1)
    a = dt / 6.0 * (h0 + 2.0 * b2 + 2.0 * b3 + b4)
    a[..., 0] += 1.0
    return a, (h0, hm, h1, b2, b3)


def rk4_step_matrices(w0: np.ndarray, w1: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """The step matrix A = R(a) of eq. (2).

    Parameters
    ----------
    w0, w1 : ndarray, (..., 3)
        Rates at the step's start and end, rad/s.
    dt : ndarray, (...)
        Step, s.

    Returns
    -------
    ndarray, (..., 4, 4)
    """
    return right_matrix(rk4_step(w0, w1, dt)[0])


def rk4_step_gradients(u: np.ndarray, dt: np.ndarray, stages: tuple[np.ndarray, ...]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Row vectors ``u`` (..., m, 4) times da/dw0 and da/dw1 of eq. (3): each (..., m, 3).

    With E = [e_x e_y e_z] (4 x 3, pure unit quaternions as columns), x (x) hm = R(hm) x and
    h0 (x) y = L(h0) y, the derivatives along the three rate components are the 4 x 3 matrices

        D2 = beta E + dt/2 (alpha R(hm) E + beta L(h0) E)
        D3 = beta E + dt/2 (R(hm) D2 + beta L(b2) E)
        D4 = gamma E + dt (R(h1) D3 + gamma L(b3) E)
        Da = dt/6 (alpha E + 2 D2 + 2 D3 + D4)                                           (4)

    with (alpha, beta, gamma) = (1/2, 1/4, 0) for w0 (dh0 = e/2, dhm = e/4) and (0, 1/4, 1/2) for w1.
    u Da is accumulated backwards (reverse mode), which shares the row vectors
    v3 = 2 u + dt u R(h1) and v2 = 2 u + dt/2 v3 R(hm) between w0 and w1:

        6/dt u Da = (alpha + gamma) u E + gamma dt u L(b3) E + beta (v3 + v2) E
                    + dt/2 (beta v3 L(b2) E + alpha v2 R(hm) E + beta v2 L(h0) E).

    Parameters
    ----------
    u : ndarray, (..., m, 4)
        Row vectors.
    dt : ndarray, (...)
        Step, s.
    stages : tuple of ndarray
        From :func:`rk4_step`.

    Returns
    -------
    tuple of ndarray
        u da/dw0 and u da/dw1, each (..., m, 3).
    """
    # each stage broadcast over the m rows; u R(p) = u (x) p*, u L(p) = p* (x) u (see conjugate); h0, hm
    # and h1 are pure, their conjugates the negated vector parts
    h0, hm, h1 = (-np.asarray(stage, float)[..., None, 1:] for stage in stages[:3])
    b2, b3 = (conjugate(stage)[..., None, :] for stage in stages[3:])
    u = np.asarray(u, float)
    dt = np.asarray(dt, float)[..., None, None]
    v3 = 2.0 * u + dt * _times_pure(u, h1)
    v2 = 2.0 * u + 0.5 * dt * _times_pure(v3, hm)
    common = (0.5 * u[..., 1:] + 0.25 * (v3[..., 1:] + v2[..., 1:])
              + 0.125 * dt * (qmul(b2, v3)[..., 1:] + _pure_times(h0, v2)[..., 1:]))
    g0 = dt / 6.0 * (common + 0.25 * dt * _times_pure(v2, hm)[..., 1:])
    g1 = dt / 6.0 * (common + 0.5 * dt * qmul(b3, u)[..., 1:])
    return g0, g1


def to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions, normalised first.

    Parameters
    ----------
    q : ndarray, (..., 4)

    Returns
    -------
    ndarray, (..., 3, 3)
    """
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _skew(v: np.ndarray) -> np.ndarray:
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    rows = [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)]
    return np.stack(rows, -2)


def rotate_inverse(q: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R(q)^T u and its derivative with respect to the (unnormalised) quaternion q.

    For a unit quaternion (w, v): R^T u = u - 2 w (v x u) + 2 v x (v x u). The derivative
    chains through the normalisation q / |q|, whose Jacobian is (I - q q^T) / |q|.

    Parameters
    ----------
    q : ndarray, (..., 4)
        Quaternions, any norm.
    u : ndarray, (..., 3)
        Vectors.

    Returns
    -------
    tuple of ndarray
        r (..., 3) and dr/dq (..., 3, 4).
    """
    q = np.asarray(q, float)
    u = np.asarray(u, float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    qn = q / norm
    w = qn[..., 0:1]
    v = qn[..., 1:]
    vxu = np.cross(v, u)
    r = u - 2 * w * vxu + 2 * np.cross(v, vxu)
    d_w = -2 * vxu
    vu = np.sum(v * u, axis=-1)[..., None, None]
    eye = np.eye(3)
    d_v = (2 * w[..., None] * _skew(u) + 2 * (vu * eye + v[..., :, None] * u[..., None, :]
                                             - 2 * u[..., :, None] * v[..., None, :]))
    d_qn = np.concatenate([d_w[..., None], d_v], axis=-1)
    proj = (np.eye(4) - qn[..., :, None] * qn[..., None, :]) / norm[..., None]
    return r, d_qn @ proj
