"""Truth and error measures for the magnetometer tests and benchmark (simulated unit of mocks.magnetometer).

The simulated magnetometer reads raw = W C b + h (W symmetric soft iron, C the rotation from the
accelerometer's axes, h the hard iron), so the forward model's matrix is A = W C. A fit is judged by

- hard iron: |b - h| (uT);
- soft-iron shape: max |P - W| over the entries, both scaled to unit determinant (%), P of the
  fit's left polar decomposition A = P R (the field magnitude only scales A);
- alignment: the angle of R C^T (deg).
"""

from __future__ import annotations

import numpy as np

from mocks.truth import UnitTruth
from station.engines.calibration.common import triangular_correction


def polar(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A = P R: P symmetric positive, R a rotation (by the SVD, independent of the engine's)."""
    u, s, vt = np.linalg.svd(np.asarray(matrix, float))
    return (u * s) @ u.T, u @ vt


def angle_deg(rot: np.ndarray) -> float:
    """The angle of a rotation matrix, deg."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0))))


def unit_det(matrix: np.ndarray) -> np.ndarray:
    """The matrix scaled to unit determinant."""
    return matrix / np.linalg.det(matrix) ** (1 / 3)


def errors(matrix: np.ndarray, bias: np.ndarray, truth: UnitTruth,
           frame: np.ndarray | None = None) -> dict[str, float]:
    """Hard iron (uT), shape (%) and alignment (deg) errors of a fit against the unit's magnetometer;
    ``frame`` (Q, body vectors v = Q v') when the fit's field is in other axes than the body's
    (:func:`lower_frame`): the true rotation is then C Q."""
    mag = truth.mag
    assert mag is not None
    p, r = polar(matrix)
    w = mag.soft_iron
    rotation = mag.rotation if frame is None else mag.rotation @ frame
    return {
        "hard_ut": float(np.linalg.norm(np.asarray(bias) - mag.hard_iron)),
        "shape_pct": float(100 * np.max(np.abs(unit_det(p) - unit_det(w)))),
        "align_deg": angle_deg(r @ rotation.T),
    }


def lower_frame(truth: UnitTruth) -> np.ndarray:
    """Q of the accelerometer's lower-triangular frame (``calibrate --method free``'s default: x along
    its x axis, xy its xy plane): its true correction M^-1 = Q C' with C' lower triangular, so body
    vectors are Q times that frame's (``calibration_common.triangular_correction``)."""
    q, _ = triangular_correction(np.linalg.inv(truth.accel.matrix), "lower")
    return q


def calibrated_acc(acc: np.ndarray, truth: UnitTruth) -> np.ndarray:
    """The accelerometer corrected with the unit's true intrinsics (what a prior calibration gives)."""
    return (np.asarray(acc, float) - truth.accel.bias) @ np.linalg.inv(truth.accel.matrix).T


def magneto(m: np.ndarray, field: float) -> tuple[np.ndarray, np.ndarray]:
    """Li & Griffiths' ellipsoid-specific least squares (IEEE GMP 2004), as Magneto 1.2 applies it:
    the quadric a x^2 + b y^2 + c z^2 + 2f yz + 2g xz + 2h xy + 2p x + 2q y + 2r z + d = 0 whose
    first six coefficients are the eigenvector of C^-1 (S11 - S12 S22^-1 S21) with the positive
    eigenvalue (C the constraint 4J - I^2 > 0 with k = 4); the calibration matrix is
    F / sqrt(U^T Q^-1 U - d) sqrt(Q). Returns (hard iron, correction)."""
    x, y, z = m.T
    design = np.array([x * x, y * y, z * z, 2 * y * z, 2 * x * z, 2 * x * y, 2 * x, 2 * y, 2 * z,
                       np.ones_like(x)])
    s = design @ design.T
    s11, s12, s22 = s[:6, :6], s[:6, 6:], s[6:, 6:]
    constraint = np.zeros((6, 6))
    constraint[:3, :3] = [[-1, 1, 1], [1, -1, 1], [1, 1, -1]]
    constraint[3:, 3:] = -4 * np.eye(3)
    w, v = np.linalg.eig(np.linalg.inv(constraint) @ (s11 - s12 @ np.linalg.solve(s22, s12.T)))
    v1 = np.real(v[:, np.argmax(np.real(w))])
    v2 = -np.linalg.solve(s22, s12.T @ v1)
    a, b, c, f, g, h = v1
    q = np.array([[a, h, g], [h, b, f], [g, f, c]])
    u = v2[:3]
    if a < 0:                                     # the eigenvector's sign is free: Q positive definite
        q, u, d = -q, -u, -v2[3]
    else:
        d = v2[3]
    centre = -np.linalg.solve(q, u)
    wq, vq = np.linalg.eigh(q)
    root = (vq * np.sqrt(wq)) @ vq.T
    return centre, field / np.sqrt(u @ np.linalg.solve(q, u) - d) * root
