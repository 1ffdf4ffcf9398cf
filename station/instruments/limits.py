"""The plan's limits on its instruments, checked before any command is sent.

A plan names, beside each instrument's URL, what the station may ask of it (``chamber: {min_c,
max_c, max_gradient}``, ``table: {max_rate_dps, max_accel_dps2}``, ``supply: {max_v, max_a}``).
:func:`limited` wraps an open instrument so that a setpoint, a rate, an acceleration, a voltage or
a current beyond them is refused with a :class:`~drivers.instruments.errors.LimitRefused` naming
the limit and where it was set, and nothing reaches the instrument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.instruments import Chamber, Instrument, Supply, Table
from drivers.instruments.errors import LimitRefused


@dataclass(frozen=True)
class Limits:
    """What the station may ask of its instruments; None = the instrument's own limit only."""

    min_c: float | None = None
    max_c: float | None = None
    max_gradient: float | None = None  # K/min
    max_rate_dps: float | None = None
    max_accel_dps2: float | None = None
    max_v: float | None = None
    max_a: float | None = None
    source: str = "the plan"  # where the limits were set, named in a refusal


def _refuse(instrument: Instrument, what: str, value: float, limit: str, source: str) -> LimitRefused:
    return LimitRefused(f"{instrument.url}: {what} {value:g} is beyond {limit} of {source}; nothing was "
                        "sent. Change the step or the limit", instrument.url, what)


def _check(instrument: Instrument, what: str, value: float, low: float | None, high: float | None,
           name: str, source: str) -> None:
    if not math.isfinite(value):
        raise _refuse(instrument, what, value, f"the finite values {name} allows", source)
    if low is not None and value < low:
        raise _refuse(instrument, what, value, f"{name.split('..')[0]} = {low:g}", source)
    if high is not None and value > high:
        raise _refuse(instrument, what, value, f"{name.split('..')[-1]} = {high:g}", source)


class LimitedChamber(Chamber):
    """A chamber whose setpoint stays in ``min_c..max_c`` and gradient under ``max_gradient``."""

    def __init__(self, inner: Chamber, limits: Limits):
        super().__init__(inner.url, inner.speaker)
        self.limits = limits

    def set_setpoint(self, celsius: float) -> None:
        """Set the setpoint, if within the plan's range."""
        _check(self, "setpoint (degC)", celsius, self.limits.min_c, self.limits.max_c, "chamber.min_c..max_c",
               self.limits.source)
        super().set_setpoint(celsius)

    def set_gradient(self, k_per_min: float) -> None:
        """Set the gradient, if within the plan's maximum."""
        _check(self, "gradient (K/min)", k_per_min, 0.0, self.limits.max_gradient, "0..chamber.max_gradient",
               self.limits.source)
        super().set_gradient(k_per_min)


class LimitedTable(Table):
    """A table whose rate and acceleration stay within the plan's maxima."""

    def __init__(self, inner: Table, limits: Limits):
        super().__init__(inner.url, inner.speaker)
        self.limits = limits

    def turn(self, rate_dps: float, axis: int = 1) -> None:
        """Turn at ``rate_dps``, if within ``max_rate_dps``."""
        high = self.limits.max_rate_dps
        _check(self, "rate (deg/s)", abs(rate_dps), None, high, "table.max_rate_dps", self.limits.source)
        super().turn(rate_dps, axis)

    def set_acceleration(self, dps2: float, axis: int = 1) -> None:
        """Set the acceleration, if within ``max_accel_dps2``."""
        _check(self, "acceleration (deg/s^2)", dps2, 0.0, self.limits.max_accel_dps2,
               "0..table.max_accel_dps2", self.limits.source)
        super().set_acceleration(dps2, axis)


class LimitedSupply(Supply):
    """A supply whose voltage and current limit stay within the plan's maxima."""

    def __init__(self, inner: Supply, limits: Limits):
        super().__init__(inner.url, inner.speaker, inner.channel)
        self.limits = limits

    def set_voltage(self, volts: float) -> None:
        """Set the voltage, if within ``max_v``."""
        _check(self, "voltage (V)", volts, 0.0, self.limits.max_v, "0..supply.max_v", self.limits.source)
        super().set_voltage(volts)

    def set_current(self, amps: float) -> None:
        """Set the current limit, if within ``max_a``."""
        _check(self, "current (A)", amps, 0.0, self.limits.max_a, "0..supply.max_a", self.limits.source)
        super().set_current(amps)


def limited(instrument: Instrument, limits: Limits) -> Instrument:
    """``instrument`` with the plan's limits checked before every setting command."""
    if isinstance(instrument, Chamber):
        return LimitedChamber(instrument, limits)
    if isinstance(instrument, Table):
        return LimitedTable(instrument, limits)
    if isinstance(instrument, Supply):
        return LimitedSupply(instrument, limits)
    return instrument
