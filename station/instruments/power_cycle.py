"""Power-cycling the unit through a bench supply, for turn-on repeatability without a person at the
switch (``imu-station characterise --turn-ons N --supply URL``).

:class:`SupplyPowerCycle` is a ``power_cycle(turn_on)`` callback for
:func:`station.acquisition.turn_ons.record_turn_ons`: it switches the supply's output off, confirms
it is off, holds it off long enough for the unit's rails to drain, switches it on and confirms that.
Every setting goes through the plan's limits (:mod:`station.instruments.limits`), so a voltage beyond
them is refused before anything reaches the supply. The unit's link is the acquisition's business:
the callback returns once the output is on, and the caller waits for the unit's samples.
"""

from __future__ import annotations

import time
from typing import IO

from drivers.instruments import Supply
from drivers.instruments.errors import InstrumentError
from station.common.text import printable
from station.instruments.limits import Limits, limited
from station.instruments.open import open_instrument

OFF_S = 2.0  # held off: a unit's input capacitors drain in well under a second; a USB bridge's take longer
CONFIRM_S = 3.0  # a supply's output relay and its readback settle within this


class SupplyPowerCycle:
    """Switches the unit's supply off and on again between turn-ons.

    Parameters
    ----------
    supply : Supply
        The supply the unit hangs on (already wrapped in the limits, see :func:`open_power_cycle`).
    volts, amps : float, optional
        Set before the first power-up (None: the supply's own settings are kept).
    off_s : float
        How long the output stays off.
    err : text stream, optional
        Where a line per switch goes.
    """

    def __init__(self, supply: Supply, volts: float | None = None, amps: float | None = None,
                 off_s: float = OFF_S, err: IO[str] | None = None):
        self.supply = supply
        self.volts = volts
        self.amps = amps
        self.off_s = off_s
        self.err = err
        self.cycles = 0

    def _say(self, text: str) -> None:
        if self.err is not None:
            print(f"{printable(self.supply.url)}: {text}", file=self.err)

    def _switch(self, on: bool) -> None:
        self.supply.set_output(on)
        deadline = time.monotonic() + CONFIRM_S
        while True:
            state = self.supply.output()
            if state is None or state == on:
                return
            if time.monotonic() >= deadline:
                want, was = ("on", "off") if on else ("off", "on")
                raise InstrumentError(f"{self.supply.url}: the output is still {was} {CONFIRM_S:g} s after "
                                      f"switching it {want}; check the supply (its front panel may hold it "
                                      "locked)", self.supply.url,
                                      "output_on" if on else "output_off")
            time.sleep(0.05)  # polling the supply's own readback, not waiting blind

    def power_on(self) -> None:
        """Set the voltage and current limit (when given) and switch the output on.

        Raises
        ------
        LimitRefused
            ``volts`` or ``amps`` beyond the limits; nothing was sent to the supply.
        """
        if self.volts is not None:
            self.supply.set_voltage(self.volts)
        if self.amps is not None:
            self.supply.set_current(self.amps)
        self._switch(True)
        self._say(f"output on: {self.supply.voltage_v():.2f} V, {self.supply.current_a():.3f} A")

    def __call__(self, turn_on: int) -> None:
        """Power-cycle the unit before turn-on ``turn_on``: off, held ``off_s``, on."""
        self._switch(False)
        self._say(f"turn-on {turn_on}: output off for {self.off_s:g} s")
        time.sleep(self.off_s)  # the off time is the point: the unit must really lose its power
        self.power_on()
        self.cycles += 1

    def close(self) -> None:
        """Release the supply's link; the output is left as it is (the unit powered, as it was found)."""
        self.supply.close()


def open_power_cycle(url: str, limits: Limits, volts: float | None = None, amps: float | None = None,
                     off_s: float = OFF_S, err: IO[str] | None = None) -> SupplyPowerCycle:
    """Open the supply at ``url`` held to ``limits``, as a power-cycle callback.

    Parameters
    ----------
    url : str
        The supply's URL (``scpi://HOST``, ``korad:///dev/ttyUSB0``, ``sim://supply``...).
    limits : Limits
        ``max_v`` and ``max_a`` every setting is checked against before it is sent.
    volts, amps, off_s, err :
        As for :class:`SupplyPowerCycle`.

    Raises
    ------
    StationError
        The URL names no supply, or the supply cannot be reached.
    """
    instrument = open_instrument(url, kind="supply")
    supply = limited(instrument, limits)
    assert isinstance(supply, Supply)
    return SupplyPowerCycle(supply, volts, amps, off_s, err)
