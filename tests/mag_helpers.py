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


def errors(matrix: np.ndarray, bias: np.ndarray, truth: UnitTruth) -> dict[str, float]:
    """Hard iron (uT), shape (%) and alignment (deg) errors of a fit against the unit's magnetometer."""
    mag = truth.mag
    assert mag is not None
    p, r = polar(matrix)
    w = mag.soft_iron
    return {
        "hard_ut": float(np.linalg.norm(np.asarray(bias) - mag.hard_iron)),
        "shape_pct": float(100 * np.max(np.abs(unit_det(p) - unit_det(w)))),
        "align_deg": angle_deg(r @ mag.rotation.T),
    }


def calibrated_acc(acc: np.ndarray, truth: UnitTruth) -> np.ndarray:
    """The accelerometer corrected with the unit's true intrinsics (what a prior calibration gives)."""
    return (np.asarray(acc, float) - truth.accel.bias) @ np.linalg.inv(truth.accel.matrix).T
