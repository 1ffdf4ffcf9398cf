"""A climatic chamber's air and the unit inside it, on the simulated unit's device clock.

The chamber emulators (``mocks.instruments.simserv``, ``espec``, ``modbus_chambers``) are only
protocols; what they report and what they change is this plant, so a setpoint sent by the real
driver moves the air, and the simulated unit (``mocks.device.SimDevice.follow_temperature``)
reads its temperature from the same plant. The model, per control regime::

    running:  dT_air/dt = clip((T_set - T_air) / tau_air, -g_down, +g_up)                (1)
    stopped:  dT_air/dt = (T_ambient - T_air) / tau_ambient                               (2)
    unit:     dT_unit/dt = (T_air - T_unit) / tau_unit                                    (3)

(1) is a ramp at the gradient (K/min, up and down) far from the setpoint and a first-order lag
near it; (2) is a stopped chamber drifting back to the room slowly. The plant is integrated
forward on demand in small steps (each exact for its regime) and kept as a history, so that it
is evaluable at any array of device times, as the unit's sampler asks: ``plant(t)`` is the
unit's temperature, :meth:`ChamberPlant.air_c` the air's. A command changes the regime at the
plant's clock (``clock()``: device seconds), which should be the device clock of the unit it
feeds; history past that time (a sampler that ran ahead) is recomputed.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

import numpy as np

AMBIENT_C = 23.0


class ChamberPlant:
    """The air of a climatic chamber and the unit in it, as functions of device time.

    Parameters
    ----------
    clock : callable, optional
        Device time now, s (default: seconds since the plant was made, times ``speed``).
    speed : float
        With the default clock: how many times faster than the wall clock device time runs
        (tests run minutes of chamber in seconds).
    ambient_c : float
        The room the chamber stands in, and where its air starts.
    tau_air_s, tau_unit_s, tau_ambient_s : float
        Lag of the air near the setpoint, of the unit behind the air, of a stopped chamber
        drifting to ambient (device seconds).
    gradient_k_per_min : float
        The controller's gradient up and down at power-up.
    min_c, max_c : float
        What the controller itself accepts as a setpoint.
    initial_c : float, optional
        Where the air and the unit start (default ``ambient_c``): a chamber taken over mid-campaign
        (a resumed run) holds the unit where the campaign left it.
    """

    def __init__(self, clock: Callable[[], float] | None = None, *, speed: float = 1.0,
                 ambient_c: float = AMBIENT_C, tau_air_s: float = 60.0, tau_unit_s: float = 180.0,
                 tau_ambient_s: float = 1800.0, gradient_k_per_min: float = 3.0, min_c: float = -70.0,
                 max_c: float = 180.0, initial_c: float | None = None):
        if speed <= 0 or min(tau_air_s, tau_unit_s, tau_ambient_s) <= 0:
            raise ValueError("speed and the time constants must be positive")
        started = time.monotonic()
        self.clock: Callable[[], float] = clock or (lambda: (time.monotonic() - started) * speed)
        self.ambient_c = ambient_c
        self.tau_air_s = tau_air_s
        self.tau_unit_s = tau_unit_s
        self.tau_ambient_s = tau_ambient_s
        self.min_c = min_c
        self.max_c = max_c
        start_c = ambient_c if initial_c is None else float(initial_c)
        self.setpoint_c = start_c
        self.gradient_up = gradient_k_per_min
        self.gradient_down = gradient_k_per_min
        self.running = False
        # A step a twentieth of the fastest lag keeps the unit's exact-per-step solution smooth.
        self.step_s = min(tau_air_s, tau_unit_s) / 20.0
        self._lock = threading.RLock()
        t0 = self.clock()
        self._t = [t0]
        self._air = [start_c]
        self._unit = [start_c]

    # --- commands (what an emulator does when the driver asks) --------------------------------

    def set_setpoint(self, celsius: float) -> None:
        """Change the setpoint from now on."""
        self._change(setpoint_c=float(celsius))

    def set_gradient(self, up_k_per_min: float, down_k_per_min: float | None = None) -> None:
        """Change the gradient (K/min) up, and down (the same when not given)."""
        down = up_k_per_min if down_k_per_min is None else down_k_per_min
        if up_k_per_min <= 0 or down <= 0:
            raise ValueError("a gradient is positive")
        self._change(gradient_up=float(up_k_per_min), gradient_down=float(down))

    def set_running(self, running: bool) -> None:
        """Start (run at the setpoint) or stop (drift to ambient) from now on."""
        self._change(running=bool(running))

    def _change(self, **state: float | bool) -> None:
        with self._lock:
            now = self.clock()
            if now < self._t[-1]:
                self._truncate(now)
            else:
                self._advance(now)
            for key, value in state.items():
                setattr(self, key, value)

    def _truncate(self, t: float) -> None:
        # The sampler evaluated past the command's time: that future was computed with the old
        # regime, so it is dropped and recomputed from the state at t.
        times = np.asarray(self._t)
        keep = int(np.searchsorted(times, t, side="right"))
        air = float(np.interp(t, times, self._air))
        unit = float(np.interp(t, times, self._unit))
        del self._t[keep:], self._air[keep:], self._unit[keep:]
        if not self._t or self._t[-1] < t:
            self._t.append(t)
            self._air.append(air)
            self._unit.append(unit)

    # --- integration ---------------------------------------------------------------------------

    def _air_step(self, air: float, dt: float) -> float:
        if not self.running:
            return self.ambient_c + (air - self.ambient_c) * math.exp(-dt / self.tau_ambient_s)
        error = self.setpoint_c - air
        gradient = (self.gradient_up if error > 0 else self.gradient_down) / 60.0
        band = gradient * self.tau_air_s  # where the lag's rate falls below the gradient
        if abs(error) > band:
            moved = math.copysign(min(gradient * dt, abs(error) - band), error)
            return air + moved
        return self.setpoint_c - error * math.exp(-dt / self.tau_air_s)

    def _advance(self, until: float) -> None:
        t, air, unit = self._t[-1], self._air[-1], self._unit[-1]
        while t < until:
            dt = min(self.step_s, until - t)
            new_air = self._air_step(air, dt)
            mean_air = 0.5 * (air + new_air)
            unit = mean_air + (unit - mean_air) * math.exp(-dt / self.tau_unit_s)
            t, air = t + dt, new_air
            self._t.append(t)
            self._air.append(air)
            self._unit.append(unit)

    def _history(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        with self._lock:
            if t.size:
                self._advance(float(np.max(t)))
            return np.asarray(self._t), np.asarray(self._air), np.asarray(self._unit)

    # --- evaluation ------------------------------------------------------------------------------

    def air_c(self, t: float | np.ndarray) -> np.ndarray:
        """The chamber air's temperature at device times ``t`` (degC; before the plant began: its
        first value).

        Parameters
        ----------
        t : float or ndarray
            Device times, s.

        Returns
        -------
        ndarray
            degC, the shape of ``t``.
        """
        times = np.asarray(t, float)
        hist_t, air, _ = self._history(times)
        return np.interp(times, hist_t, air)

    def unit_c(self, t: float | np.ndarray) -> np.ndarray:
        """The unit's temperature at device times ``t``, degC (eq. (3))."""
        times = np.asarray(t, float)
        hist_t, _, unit = self._history(times)
        return np.interp(times, hist_t, unit)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """The unit's temperature: the plant is a temperature profile of ``mocks.rig``."""
        return self.unit_c(t)

    def now_air_c(self) -> float:
        """The air's temperature now, what the controller measures."""
        return float(self.air_c(self.clock()))

    def now_unit_c(self) -> float:
        """The unit's temperature now."""
        return float(self.unit_c(self.clock()))

    def forget_before(self, t: float) -> None:
        """Drop history before device time ``t`` (a long run keeps its memory bounded)."""
        with self._lock:
            keep = max(0, int(np.searchsorted(np.asarray(self._t), t)) - 1)
            del self._t[:keep], self._air[:keep], self._unit[:keep]
