"""The intrinsic model of one sensor triad: raw = M true + b, with M = K (I + S).

K is the diagonal of scale factors, S the misalignment (zero diagonal), b the bias. This is
the forward model of ``shared/specs/params-file.md``; its inverse gives the correction
true = M^-1 (raw - b).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class SensorCalibration:
    """Intrinsics of one triad (accelerometer or gyroscope), with how they were obtained.

    ``stddev`` maps a parameter name (``bias``, ``scale``, ``misalignment``, ``matrix``) to
    its 1-sigma uncertainty in the same shape; ``extra`` holds method-specific report keys
    that go into the parameter file beside the required ones.
    """

    matrix: np.ndarray
    bias: np.ndarray
    method: str = ""
    residual_rms: float | None = None
    stddev: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.matrix = np.asarray(self.matrix, dtype=float).reshape(3, 3)
        self.bias = np.asarray(self.bias, dtype=float).reshape(3)

    @classmethod
    def from_parts(cls, scale: np.ndarray, misalignment: np.ndarray, bias: np.ndarray,
                   **kw: Any) -> SensorCalibration:
        """Build from K, S and b: M = K (I + S).

        Parameters
        ----------
        scale : ndarray, (3,)
            Diagonal of K.
        misalignment : ndarray, (3, 3)
            S, zero diagonal.
        bias : ndarray, (3,)
        **kw
            The other fields (method, stddev, ...).

        Returns
        -------
        SensorCalibration
        """
        matrix = np.diag(np.asarray(scale, float)) @ (np.eye(3) + np.asarray(misalignment, float))
        return cls(matrix=matrix, bias=bias, **kw)

    @property
    def scale(self) -> np.ndarray:
        """K: the diagonal of M, since I + S has a unit diagonal."""
        return np.diag(self.matrix).copy()

    @property
    def misalignment(self) -> np.ndarray:
        """S = K^-1 M - I (zero diagonal)."""
        s = self.matrix / self.scale[:, None] - np.eye(3)
        np.fill_diagonal(s, 0.0)
        return s

    @property
    def correction(self) -> np.ndarray:
        """M^-1: true = M^-1 (raw - b)."""
        return np.linalg.inv(self.matrix)

    def correct(self, raw: np.ndarray, extra_bias: np.ndarray | float = 0.0) -> np.ndarray:
        """true = M^-1 (raw - b - extra_bias).

        Parameters
        ----------
        raw : ndarray, (N, 3)
        extra_bias : ndarray or float
            A bias added to b (the thermal bias, (N, 3)).

        Returns
        -------
        ndarray, (N, 3)
        """
        return (np.asarray(raw, float) - self.bias - extra_bias) @ self.correction.T

    def forward(self, true: np.ndarray) -> np.ndarray:
        """raw = M true + b.

        Parameters
        ----------
        true : ndarray, (N, 3)

        Returns
        -------
        ndarray, (N, 3)
        """
        return np.asarray(true, float) @ self.matrix.T + self.bias

    @staticmethod
    def identity() -> SensorCalibration:
        """M = I, b = 0: raw readings taken as they are."""
        return SensorCalibration(np.eye(3), np.zeros(3), method="identity")
