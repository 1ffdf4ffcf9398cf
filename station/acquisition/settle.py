"""Waiting for a unit to settle at a chamber's temperature, judged on the unit's own sensor.

The chamber's air reaches its setpoint long before the unit inside does (its case and board lag
the air by minutes), and the bias of a MEMS gyro follows the die, not the air. So a soak ends when
the unit's own temperature stops moving: the least-squares slope of its readings over the last
``hold_s`` seconds of device time is within ``rate_c_per_min``. A soak that does not get there
within ``timeout_s`` wall seconds is a :class:`SettleTimeout` (exit 5), naming the slope it had.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers import Device
from station.errors import ExitCode, StationError

MAX_SAMPLES_KEPT = 20_000  # the window is decimated past this: a slope needs hundreds, not millions


class SettleTimeout(StationError):
    """The unit's temperature did not settle within the soak's time limit."""

    exit_code = ExitCode.TIMEOUT


@dataclass(frozen=True)
class Settle:
    """When a soak has settled: the unit's temperature moves less than ``rate_c_per_min`` over the
    last ``hold_s`` seconds (device time); give up after ``timeout_s`` wall seconds."""

    rate_c_per_min: float = 0.05
    hold_s: float = 300.0
    timeout_s: float = 3600.0


def temperature_slope(t: np.ndarray, temp: np.ndarray) -> float:
    """The least-squares slope of ``temp`` (degC) against ``t`` (s), in degC/min.

    Parameters
    ----------
    t, temp : ndarray
        Times (s) and temperatures (degC), at least two distinct times.

    Returns
    -------
    float
        ``60 * sum((t - t_mean)(T - T_mean)) / sum((t - t_mean)^2)``.
    """
    dt = t - t.mean()
    return float(60.0 * np.dot(dt, temp - temp.mean()) / np.dot(dt, dt))


class SettleWatch:
    """The trailing window of a unit's temperature, fed batch by batch.

    Parameters
    ----------
    settle : Settle
        The criterion.
    """

    def __init__(self, settle: Settle):
        self.settle = settle
        self._t = np.zeros(0)
        self._temp = np.zeros(0)

    def feed(self, t: np.ndarray, temp: np.ndarray) -> None:
        """Add readings (device time, s; degC); keep the last ``hold_s`` of them."""
        keep = np.isfinite(temp)
        t_all = np.concatenate([self._t, np.asarray(t, float)[keep]])
        temp_all = np.concatenate([self._temp, np.asarray(temp, float)[keep]])
        if len(t_all):
            recent = t_all >= t_all[-1] - self.settle.hold_s
            t_all, temp_all = t_all[recent], temp_all[recent]
        if len(t_all) > MAX_SAMPLES_KEPT:
            step = len(t_all) // (MAX_SAMPLES_KEPT // 2)
            t_all, temp_all = t_all[::step], temp_all[::step]
        self._t, self._temp = t_all, temp_all

    @property
    def span_s(self) -> float:
        """Device seconds the window covers."""
        return float(self._t[-1] - self._t[0]) if len(self._t) > 1 else 0.0

    @property
    def temperature_c(self) -> float | None:
        """The latest reading, or None before any."""
        return float(self._temp[-1]) if len(self._temp) else None

    def slope(self) -> float | None:
        """The window's slope, degC/min (None before two readings)."""
        if len(self._t) < 2 or self.span_s <= 0:
            return None
        return temperature_slope(self._t, self._temp)

    def settled(self) -> bool:
        """True once the window covers ``hold_s`` and its slope is within the rate."""
        slope = self.slope()
        return (slope is not None and self.span_s >= 0.98 * self.settle.hold_s
                and abs(slope) <= self.settle.rate_c_per_min)


def wait_settled(device: Device, settle: Settle, on_progress: Callable[[SettleWatch], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> SettleWatch:
    """Read the unit until its temperature has settled.

    Parameters
    ----------
    device : Device
        The unit, streaming.
    settle : Settle
        The criterion and the wall-time limit.
    on_progress : callable, optional
        Called with the watch after every batch (a progress line).
    clock : callable
        Wall seconds.

    Returns
    -------
    SettleWatch
        The window at the moment it settled.

    Raises
    ------
    SettleTimeout
        Not settled within ``settle.timeout_s`` wall seconds.
    """
    watch = SettleWatch(settle)
    deadline = clock() + settle.timeout_s
    while not watch.settled():
        if clock() > deadline:
            slope = watch.slope()
            moving = f"still moving {slope:+.3f} degC/min" if slope is not None else "no temperature read"
            raise SettleTimeout(f"{device.port}: the unit's temperature did not settle within "
                                f"{settle.timeout_s:g} s ({moving}; the soak asks at most "
                                f"{settle.rate_c_per_min:g} degC/min over {settle.hold_s:g} s); lengthen the "
                                "soak's settle_timeout_s or check the chamber")
        batch = device.read(0.2)
        if len(batch):
            watch.feed(batch["t_us"] * 1e-6, batch["temp"])
            if on_progress is not None:
                on_progress(watch)
    return watch
