"""Physical constants shared by every layer, in SI units."""

from __future__ import annotations

STANDARD_GRAVITY = 9.80665
"""Standard acceleration of gravity g0, m/s^2 (CGPM 1901): the unit of 'g' and 'mg' readings."""
