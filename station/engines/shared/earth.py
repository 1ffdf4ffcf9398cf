"""The Earth's gravity and rotation where the unit stands (WGS-84)."""

from __future__ import annotations

import math

import numpy as np

# Defined once for every layer in protocols.units; the calibration engines import it from here.
from protocols.units import STANDARD_GRAVITY as STANDARD_GRAVITY

# WGS-84 defining and derived constants (NIMA TR8350.2, 3rd ed., tables 3.1 and 3.3).
WGS84_A = 6378137.0                    # semi-major axis, m
WGS84_F = 1.0 / 298.257223563          # flattening
WGS84_GAMMA_E = 9.7803253359           # normal gravity at the equator, m/s^2
WGS84_K = 0.00193185265241             # Somigliana's constant k = (b gamma_p)/(a gamma_e) - 1
WGS84_E2 = 0.00669437999013            # first eccentricity squared
WGS84_M = 0.00344978650684             # m = omega^2 a^2 b / GM
EARTH_RATE = 7.292115e-5               # rad/s


def normal_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """Normal gravity on the WGS-84 ellipsoid with the free-air height correction.

    Somigliana's closed formula (TR8350.2 eq. 4-1):

        gamma_0 = gamma_e (1 + k sin^2 phi) / sqrt(1 - e^2 sin^2 phi)

    and the second-order free-air correction above the ellipsoid (TR8350.2 eq. 4-3):

        gamma_h = gamma_0 [1 - 2/a (1 + f + m - 2 f sin^2 phi) h + 3 h^2 / a^2]

    Parameters
    ----------
    latitude_deg : float
        Geodetic latitude phi, deg.
    height_m : float
        Height h above the ellipsoid, m.

    Returns
    -------
    float
        gamma_h, m/s^2.
    """
    if not -90.0 <= latitude_deg <= 90.0:
        raise ValueError(f"latitude {latitude_deg} is outside -90..90 degrees")
    s2 = math.sin(math.radians(latitude_deg)) ** 2
    gamma0 = WGS84_GAMMA_E * (1 + WGS84_K * s2) / math.sqrt(1 - WGS84_E2 * s2)
    h = float(height_m)
    first_order = 2 / WGS84_A * (1 + WGS84_F + WGS84_M - 2 * WGS84_F * s2) * h
    return gamma0 * (1 - first_order + 3 * h * h / WGS84_A**2)


def earth_rate_vertical(latitude_deg: float) -> float:
    """The upward component of the Earth's rotation, Omega sin(phi).

    Parameters
    ----------
    latitude_deg : float
        Geodetic latitude phi, deg.

    Returns
    -------
    float
        rad/s.
    """
    return EARTH_RATE * math.sin(math.radians(latitude_deg))


def earth_rate_enu(latitude_deg: float) -> np.ndarray:
    """The Earth's rotation in the local east-north-up frame: (0, Omega cos phi, Omega sin phi).

    Parameters
    ----------
    latitude_deg : float
        Geodetic latitude phi, deg.

    Returns
    -------
    ndarray, (3,)
        rad/s.
    """
    phi = math.radians(latitude_deg)
    return np.array([0.0, EARTH_RATE * math.cos(phi), EARTH_RATE * math.sin(phi)])
