"""The three kinds of instrument the station drives, each one interface whatever its protocol.

- :class:`Chamber`: identify, read the air temperature, read and set the setpoint, set the
  gradient where the controller has one, start and stop, read alarms.
- :class:`Table`: identify, read position and rate, move to a position, turn at a rate, set the
  acceleration, stop, home; per axis (1 for a single-axis table).
- :class:`Supply`: identify, set voltage and current limit, switch the output, measure.

A kind speaks through a :class:`~drivers.instruments.speaker.Speaker` (a line protocol or Modbus,
from the instrument's description); it checks no limits itself: the station wraps it in the
plan's limits (``station.instruments.limits``) before anything is sent.
"""

from __future__ import annotations

import math
from typing import ClassVar

from drivers.errors import CommandUnsupported
from drivers.instruments.errors import InstrumentGarbled
from drivers.instruments.speaker import Reply, Speaker

ON_WORDS = ("1", "on", "true", "yes")
OFF_WORDS = ("0", "off", "false", "no")


class Instrument:
    """One instrument on one link.

    Parameters
    ----------
    url : str
        How it was named (``votsch://10.0.0.5``); every message and transcript entry carries it.
    speaker : Speaker
        Its protocol, from its description.
    """

    kind: ClassVar[str] = ""

    def __init__(self, url: str, speaker: Speaker):
        self.url = url
        self.speaker = speaker
        self.description = speaker.description

    def _number(self, operation: str, reply: Reply) -> float:
        text = reply.get("value", "")
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise InstrumentGarbled(f"{self.url}: {self.description.name}: '{operation}' gave {text!r}, "
                                    "not a number; check the reply pattern's (?P<value>...) group", self.url,
                                    operation, text)
        return value

    def _read(self, operation: str, axis: int = 1) -> float:
        return self._number(operation, self.speaker.do(operation, axis=axis))

    def _optional(self, operation: str, what: str) -> None:
        if not self.speaker.has(operation):
            raise CommandUnsupported(f"{self.url}: the {self.description.name} description gives no "
                                     f"'{operation}' ({what}); add one to the description if the controller "
                                     "has it", self.url)

    def identify(self) -> str:
        """The instrument's own identity string, or the description's name where it has no query."""
        if not self.speaker.has("identify"):
            return self.description.name
        reply = self.speaker.do("identify")
        return reply.get("identity", "").strip() or self.description.name

    def state(self) -> dict[str, object]:
        """What ``imu-station instrument URL --json`` prints: ``kind``, ``identity`` and the kind's
        readings."""
        return {"kind": self.kind, "identity": self.identify()}

    def close(self) -> None:
        """Release the link."""
        self.speaker.close()


class Chamber(Instrument):
    """A climatic chamber."""

    kind = "chamber"

    def temperature_c(self) -> float:
        """The air temperature the controller measures, degC."""
        return self._read("temperature")

    def setpoint_c(self) -> float:
        """The setpoint in use, degC."""
        return self._read("setpoint")

    def set_setpoint(self, celsius: float) -> None:
        """Set the temperature setpoint, degC."""
        self.speaker.do("set_setpoint", value=celsius)

    def set_gradient(self, k_per_min: float) -> None:
        """Set the ramp gradient (up and down), K/min."""
        self._optional("set_gradient", "the ramp gradient")
        self.speaker.do("set_gradient", value=k_per_min)

    def start(self) -> None:
        """Run at the setpoint (manual mode, constant mode)."""
        self._optional("start", "starting the chamber")
        self.speaker.do("start")

    def stop(self) -> None:
        """Stop conditioning (standby)."""
        self._optional("stop", "stopping the chamber")
        self.speaker.do("stop")

    def alarms(self) -> str:
        """The controller's alarm or status text ('' where it has no such query)."""
        if not self.speaker.has("alarms"):
            return ""
        reply = self.speaker.do("alarms")
        return reply.get("state", reply.get("value", "")).strip()

    def state(self) -> dict[str, object]:
        """Identity, air temperature and setpoint."""
        return {**super().state(), "temperature_c": self.temperature_c(), "setpoint_c": self.setpoint_c()}


class Table(Instrument):
    """A rate table: one to three axes, in the table's own degrees."""

    kind = "table"

    @property
    def axes(self) -> int:
        """How many axes the table has."""
        return self.description.axes

    def position_deg(self, axis: int = 1) -> float:
        """The axis's position, degrees."""
        return self._read("position", axis)

    def rate_dps(self, axis: int = 1) -> float:
        """The axis's rate, deg/s (0 where the table reports no rate)."""
        return self._read("rate", axis) if self.speaker.has("rate") else 0.0

    def move_to(self, degrees: float, axis: int = 1) -> None:
        """Move the axis to ``degrees`` (position mode); returns at once."""
        self.speaker.do("move", value=degrees, axis=axis)

    def turn(self, rate_dps: float, axis: int = 1) -> None:
        """Turn the axis at ``rate_dps`` (rate mode) until stopped; returns at once."""
        self._optional("turn", "rate mode")
        self.speaker.do("turn", value=rate_dps, axis=axis)

    def set_acceleration(self, dps2: float, axis: int = 1) -> None:
        """The axis's acceleration limit, deg/s^2."""
        self._optional("set_acceleration", "the acceleration limit")
        self.speaker.do("set_acceleration", value=dps2, axis=axis)

    def stop(self, axis: int | None = None) -> None:
        """Stop one axis, or every axis."""
        for a in range(1, self.axes + 1) if axis is None else (axis,):
            self.speaker.do("stop", axis=a)

    def home(self, axis: int = 1) -> None:
        """Move the axis to its home (zero)."""
        if self.speaker.has("home"):
            self.speaker.do("home", axis=axis)
        else:
            self.move_to(0.0, axis)

    def settled(self, axis: int = 1) -> bool | None:
        """True when the controller reports the axis in position (None where it cannot say)."""
        if not self.speaker.has("settled"):
            return None
        return _on_off(self, "settled", self.speaker.do("settled", axis=axis))

    def state(self) -> dict[str, object]:
        """Identity, position and rate (of axis 1; ``axes`` lists every axis)."""
        axes = [{"axis": a, "position_deg": self.position_deg(a), "rate_dps": self.rate_dps(a)}
                for a in range(1, self.axes + 1)]
        return {**super().state(), "position_deg": axes[0]["position_deg"], "rate_dps": axes[0]["rate_dps"],
                "axes": axes}


class Supply(Instrument):
    """A bench power supply (one channel of it)."""

    kind = "supply"

    def __init__(self, url: str, speaker: Speaker, channel: int | None = None):
        super().__init__(url, speaker)
        self.channel = channel

    def _do(self, operation: str, value: float | None = None) -> Reply:
        # A channel is selected only when the URL names one: a one-channel supply may refuse INST:NSEL.
        if self.channel is not None and self.speaker.has("select_channel"):
            self.speaker.do("select_channel", channel=self.channel)
        return self.speaker.do(operation, value=value, channel=self.channel or 1)

    def set_voltage(self, volts: float) -> None:
        """The output voltage, V."""
        self._do("set_voltage", volts)

    def set_current(self, amps: float) -> None:
        """The current limit, A."""
        self._do("set_current", amps)

    def set_output(self, on: bool) -> None:
        """Switch the output on or off."""
        self._do("output_on" if on else "output_off")

    def output(self) -> bool | None:
        """Whether the output is on (None where the supply cannot say)."""
        if not self.speaker.has("output"):
            return None
        return _on_off(self, "output", self._do("output"))

    def voltage_v(self) -> float:
        """The measured output voltage, V."""
        return self._number("voltage", self._do("voltage"))

    def current_a(self) -> float:
        """The measured output current, A."""
        return self._number("current", self._do("current"))

    def state(self) -> dict[str, object]:
        """Identity, output state, measured voltage and current."""
        return {**super().state(), "output": self.output(), "voltage_v": self.voltage_v(),
                "current_a": self.current_a(), "channel": self.channel}


def _on_off(instrument: Instrument, operation: str, reply: Reply) -> bool:
    # A pattern may classify the reply itself (a status byte's bit: groups ``on`` / ``off``).
    if "on" in reply or "off" in reply:
        return "on" in reply
    text = reply.get("state", reply.get("value", "")).strip().lower()
    if text in ON_WORDS:
        return True
    if text in OFF_WORDS:
        return False
    try:
        return float(text) != 0.0
    except ValueError:
        raise InstrumentGarbled(f"{instrument.url}: {instrument.description.name}: '{operation}' gave "
                                f"{text!r}, not on or off", instrument.url, operation, text) from None


KINDS: dict[str, type[Instrument]] = {"chamber": Chamber, "table": Table, "supply": Supply}
