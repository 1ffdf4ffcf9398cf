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
    """Omega(w) of eq. (1) for rates ``w`` (..., 3): shape (..., 4, 4)."""
    return np.einsum("...i,ijk->...jk", np.asarray(w, float), _OMEGA_BASIS)


def omega_basis() -> np.ndarray:
    """The three constant matrices E_i with Omega(w) = sum_i w_i E_i (shape (3, 4, 4))."""
    return _OMEGA_BASIS.copy()


def rk4_step_matrices(w0: np.ndarray, w1: np.ndarray, dt: np.ndarray) -> tuple[np.ndarray, ...]:
    """The RK4 step q_{n+1} = A q_n (before normalisation) and its stage matrices.

    With H = Omega/2 at the step's start (H0), midpoint (Hm, from the mean rate) and end (H1),
    the classical RK4 stages of eq. (1) are k_i = B_i q with

        B1 = H0,  B2 = Hm (I + dt/2 B1),  B3 = Hm (I + dt/2 B2),  B4 = H1 (I + dt B3),
        A  = I + dt/6 (B1 + 2 B2 + 2 B3 + B4).                                         (2)

    This is imu_tk's ``quatIntegrationStepRK4`` written as a matrix; normalising after every
    step (as imu_tk does) only rescales q, so normalising once at the end gives the same
    rotation.

    Returns ``(A, H0, Hm, H1, B2, B3)``, each (..., 4, 4), for the derivative in
    :func:`rk4_adjoint`.
    """
    dt = np.asarray(dt, float)[..., None, None]
    h0 = 0.5 * omega_matrix(w0)
    h1 = 0.5 * omega_matrix(w1)
    hm = 0.5 * omega_matrix(0.5 * (np.asarray(w0) + np.asarray(w1)))
    eye = np.eye(4)
    b2 = hm + 0.5 * dt * hm @ h0
    b3 = hm + 0.5 * dt * hm @ b2
    b4 = h1 + dt * h1 @ b3
    a = eye + dt / 6.0 * (h0 + 2.0 * b2 + 2.0 * b3 + b4)
    return a, h0, hm, h1, b2, b3


# Each E_i is a signed permutation: (E_i r)_k = _SIGN[i, k] * r[_PERM[i, k]].
_PERM = np.argmax(np.abs(_OMEGA_BASIS), axis=2)
_SIGN = np.take_along_axis(_OMEGA_BASIS, _PERM[:, :, None], axis=2)[:, :, 0]


def _bilinear(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """l E_i r for the three basis matrices: left (..., R, 4), right (..., 4) -> (..., R, 3)."""
    er = right[..., _PERM] * _SIGN                               # (..., 3, 4): row i = E_i r
    return np.sum(left[..., :, None, :] * er[..., None, :, :], axis=-1)


def rk4_adjoint(lam: np.ndarray, s: np.ndarray, dt: np.ndarray, h0: np.ndarray, hm: np.ndarray,
                h1: np.ndarray, b2: np.ndarray, b3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """lambda (dA/dw0_i) s and lambda (dA/dw1_i) s for every step: the Jacobian's building block.

    For the chain q_N = A_{N-1} .. A_0 q_0, the derivative of a function of q_N with respect to
    the start rate w0 (end rate w1) of step n is lambda_n (dA_n/dw) s_n, with s_n = A_{n-1}..A_0 q_0
    and lambda_n = (d f/d q_N) A_{N-1} .. A_{n+1}. dA follows from eq. (2) by the product rule
    with dH0 = E_i/2, dHm = E_i/4 (w0) or dH1 = E_i/2, dHm = E_i/4 (w1); contracting with
    lambda and s first keeps every term a vector product.

    lam: (..., R, 4) row vectors, s: (..., 4); returns two arrays (..., R, 3).
    """
    h = np.asarray(dt, float)[..., None, None]
    r0 = (h0 @ s[..., None])[..., 0]
    r2 = (b2 @ s[..., None])[..., 0]
    r3 = (b3 @ s[..., None])[..., 0]
    lm = lam @ hm
    l1 = lam @ h1
    lmm = lm @ hm
    l1m = l1 @ hm
    l1mm = l1m @ hm
    t_ls, t_l0, t_l2, t_l3 = (_bilinear(lam, r) for r in (s, r0, r2, r3))
    t_ms, t_m0, t_mms = _bilinear(lm, s), _bilinear(lm, r0), _bilinear(lmm, s)
    t_1s, t_12 = _bilinear(l1, s), _bilinear(l1, r2)
    t_1ms, t_1m0, t_1mms = _bilinear(l1m, s), _bilinear(l1m, r0), _bilinear(l1mm, s)

    def contract(alpha: float, beta: float, gamma: float) -> np.ndarray:
        d_h0 = alpha * t_ls
        d_b2 = beta * t_ls + 0.5 * h * (beta * t_l0 + alpha * t_ms)
        m_b2 = beta * t_ms + 0.5 * h * (beta * t_m0 + alpha * t_mms)
        d_b3 = beta * t_ls + 0.5 * h * (beta * t_l2 + m_b2)
        m1_b2 = beta * t_1ms + 0.5 * h * (beta * t_1m0 + alpha * t_1mms)
        m1_b3 = beta * t_1s + 0.5 * h * (beta * t_12 + m1_b2)
        d_b4 = gamma * t_ls + h * (gamma * t_l3 + m1_b3)
        return h / 6.0 * (d_h0 + 2.0 * d_b2 + 2.0 * d_b3 + d_b4)

    return contract(0.5, 0.25, 0.0), contract(0.0, 0.25, 0.5)


def to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4), normalised first."""
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

    Returns ``(r, dr_dq)`` with shapes (..., 3) and (..., 3, 4).
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
