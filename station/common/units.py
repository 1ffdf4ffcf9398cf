"""The units people read, as factors from the SI units the station computes in.

Inside the station everything is SI (m/s^2, rad/s, rad, a ratio); certificates, datasheets and plots
show mg, deg/h, deg, ppm and %.
"""

from __future__ import annotations

import math

from protocols.units import STANDARD_GRAVITY

DEG = 180.0 / math.pi
"""Degrees per radian."""

PEOPLE: dict[str, float] = {
    "mg": 1e3 / STANDARD_GRAVITY,  # from m/s^2
    "deg/h": DEG * 3600.0,  # from rad/s
    "deg": DEG,  # from rad
    "ppm": 1e6,  # from a ratio
    "%": 1e2,  # from a fraction
    "uT": 1.0,  # the magnetometer's section is in microtesla already
}
"""Unit name -> factor from SI: ``value_si * PEOPLE[unit]`` is the value in ``unit``."""
