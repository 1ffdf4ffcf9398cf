"""Scale factor and misalignment as functions of temperature: the ``thermal.scale`` and
``thermal.misalignment`` entries of the parameter file.

At temperature T a triad's matrix is

    M(T) = diag(K + k(t)) (I + S + s(t)),     t = clip(T, t_min, t_max) - T_ref          (1)

with K and S those of the ``accel``/``gyro`` section (their values at T_ref, the thermal section's
reference temperature) and k, s polynomials in t without a constant term, so that M(T_ref) is the
section's matrix:

    k_i(t)  = sum_p c_ip t^p,      i = x, y, z                                             (2)
    s_ij(t) = sum_p c_(ij)p t^p,   ij = xy, xz, yx, yz, zx, zy (the off-diagonal of S, row by row)

over the powers p the fit kept (1 to 3). T outside the calibrated range is clamped to it, as the
thermal bias's T is. The corrected sample is then M(T)^-1 (raw - b - B(T, dT)), equation (1) of
``station.engines.shared.correction``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

OFF_DIAGONAL = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
"""The (row, column) of S's six off-diagonal entries in the order of ``s`` in equation (2)."""

OFF_DIAGONAL_NAMES = ("xy", "xz", "yx", "yz", "zx", "zy")


SLOPE_POINTS = 101  # temperatures over the range that the temperature sensitivity is the slope through


def slope_weights(t_min: float, t_max: float) -> tuple[np.ndarray, np.ndarray]:
    """The temperatures and weights of a temperature sensitivity: the least-squares slope of a quantity
    (the thermal bias at dT = 0, a scale factor, a misalignment) through ``SLOPE_POINTS`` evenly spaced
    temperatures over [t_min, t_max],

        S = sum_i w_i B(T_i, 0),    w_i = (T_i - mean T) / sum_k (T_k - mean T)^2              (3)

    Parameters
    ----------
    t_min, t_max : float
        The model's temperature range, degC.

    Returns
    -------
    tuple of ndarray, (SLOPE_POINTS,)
        T_i (degC) and w_i (1/degC; they sum to zero, so a constant bias has no slope).
    """
    temp = np.linspace(t_min, t_max, SLOPE_POINTS)
    centred = temp - temp.mean()
    denom = float(np.sum(centred**2))
    return temp, centred / denom if denom > 0 else np.zeros_like(temp)


@dataclass
class TempPolynomial:
    """Per-component polynomials in t = clip(T) - T_ref without a constant term (equation (2)).

    ``coeffs[c, j]`` multiplies t ** ``powers[j]`` for component c (3 for a scale factor, 6 for a
    misalignment); ``stddev`` is their 1-sigma (same shape) where the fit gave it.
    """

    t_min: float
    t_max: float
    powers: tuple[int, ...]
    coeffs: np.ndarray
    stddev: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.powers = tuple(int(p) for p in self.powers)
        if any(p < 1 or p > 3 for p in self.powers):
            raise ValueError(f"powers {list(self.powers)} must each be 1, 2 or 3 (the constant is the "
                             "section's own value)")
        self.coeffs = np.asarray(self.coeffs, float).reshape(-1, len(self.powers))
        if self.stddev is not None:
            self.stddev = np.asarray(self.stddev, float).reshape(self.coeffs.shape)
        if not self.t_min < self.t_max:
            raise ValueError(f"clamp [{self.t_min:g}, {self.t_max:g}] degC is empty")

    @property
    def components(self) -> int:
        """3 for a scale factor, 6 for a misalignment."""
        return int(self.coeffs.shape[0])

    def evaluate(self, temp: np.ndarray, reference_temp: float) -> np.ndarray:
        """k(t) or s(t) of equation (2) at each temperature, T clamped to [t_min, t_max].

        Parameters
        ----------
        temp : ndarray, (N,)
            Temperature, degC (finite).
        reference_temp : float
            T_ref, degC.

        Returns
        -------
        ndarray, (N, C)
        """
        t = np.clip(np.asarray(temp, float), self.t_min, self.t_max) - reference_temp
        basis = np.stack([t**p for p in self.powers], axis=-1) if self.powers else np.zeros((len(t), 0))
        return basis @ self.coeffs.T

    def temperature_coefficient(self, reference_temp: float) -> np.ndarray:
        """Per component, the least-squares slope of k(t) or s(t) over [t_min, t_max] (equation (3)), per
        degC: a scale factor's temperature coefficient (divide by K for ppm/degC), a misalignment's drift.

        Parameters
        ----------
        reference_temp : float
            T_ref, degC.

        Returns
        -------
        ndarray, (C,)
        """
        temp, w = slope_weights(self.t_min, self.t_max)
        return np.asarray(w @ self.evaluate(temp, reference_temp))

    def change_over_range(self, reference_temp: float) -> np.ndarray:
        """Per component, max - min of k(t) or s(t) over [t_min, t_max] (the datasheets' "change over the
        operating range").

        Parameters
        ----------
        reference_temp : float
            T_ref, degC.

        Returns
        -------
        ndarray, (C,)
        """
        values = self.evaluate(np.linspace(self.t_min, self.t_max, SLOPE_POINTS), reference_temp)
        return np.asarray(values.max(axis=0) - values.min(axis=0))

    def to_dict(self) -> dict[str, Any]:
        """The entry of ``thermal.scale``/``thermal.misalignment`` for one triad."""
        out: dict[str, Any] = {
            "clamp": [self.t_min, self.t_max],
            "powers": list(self.powers),
            "coeffs": self.coeffs.tolist(),
        }
        if self.stddev is not None:
            out["stddev"] = self.stddev.tolist()
        out.update(self.extra)
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any], components: int) -> TempPolynomial:
        """Read an entry written by :meth:`to_dict` (ValueError where its shape is not ``components``
        rows of one coefficient per power).

        Parameters
        ----------
        d : dict
        components : int
            3 (scale) or 6 (misalignment).

        Returns
        -------
        TempPolynomial
        """
        t_min, t_max = (float(v) for v in d["clamp"])
        powers = tuple(int(p) for p in d["powers"])
        coeffs = np.asarray(d["coeffs"], float)
        if coeffs.shape != (components, len(powers)):
            raise ValueError(f"coeffs has shape {list(coeffs.shape)}; expected {components} rows of "
                             f"{len(powers)} (one per power {list(powers)})")
        stddev = d.get("stddev")
        known = {"clamp", "powers", "coeffs", "stddev"}
        return cls(t_min, t_max, powers, coeffs, None if stddev is None else np.asarray(stddev, float),
                   {k: v for k, v in d.items() if k not in known})


def matrices_at(matrix: np.ndarray, temp: np.ndarray, reference_temp: float,
                scale: TempPolynomial | None, misalignment: TempPolynomial | None) -> np.ndarray:
    """M(T) of equation (1) at each temperature, from the section's matrix M(T_ref) = K (I + S).

    Parameters
    ----------
    matrix : ndarray, (3, 3)
        The ``accel``/``gyro`` section's matrix.
    temp : ndarray, (N,)
        Temperature, degC (finite).
    reference_temp : float
        T_ref, degC.
    scale, misalignment : TempPolynomial, optional
        k and s of equation (2); absent ones add nothing.

    Returns
    -------
    ndarray, (N, 3, 3)
    """
    matrix = np.asarray(matrix, float)
    k0 = np.diag(matrix).copy()
    s0 = matrix / k0[:, None]
    temp = np.asarray(temp, float)
    n = len(temp)
    k = np.broadcast_to(k0, (n, 3)).copy()
    unit_s = np.broadcast_to(s0, (n, 3, 3)).copy()
    if scale is not None:
        k += scale.evaluate(temp, reference_temp)
    if misalignment is not None:
        drift = misalignment.evaluate(temp, reference_temp)
        for c, (i, j) in enumerate(OFF_DIAGONAL):
            unit_s[:, i, j] += drift[:, c]
    return k[:, :, None] * unit_s


def correct_at(raw: np.ndarray, bias: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    """true = M(T)^-1 (raw - bias), one matrix per sample.

    Parameters
    ----------
    raw : ndarray, (N, 3)
    bias : ndarray, (3,) or (N, 3)
        Everything subtracted before the matrix: b + B(T, dT) (+ G f for the gyro).
    matrices : ndarray, (N, 3, 3)
        M(T) from :func:`matrices_at`.

    Returns
    -------
    ndarray, (N, 3)
    """
    return np.linalg.solve(matrices, (np.asarray(raw, float) - bias)[:, :, None])[:, :, 0]
