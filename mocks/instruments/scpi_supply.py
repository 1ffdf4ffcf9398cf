"""An emulated SCPI bench supply coupled to the simulated unit (``shared/specs/instruments.md``, Bench
supplies): what ``scpi://`` and the shipped ``scpi.yaml`` expect, LF-ended lines, served with
:class:`~mocks.instruments.serving.ByteServer` on a pty or a loopback TCP port.

The unit hangs on one channel (``unit_channel``) of the supply: switching that output off powers the
:class:`~mocks.device.SimDevice` off (silent), switching it on with the voltage in the unit's range
boots it as after a RESTART, so turn-on repeatability can be recorded through the supply exactly as
on the bench. The unit's load is a resistor above its brown-out voltage (0.12 A at 5 V) held to the
channel's current limit; :class:`SupplyOutputs` holds that model, which the Korad emulator shares.
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass

from mocks.device import SimDevice

UNIT_MIN_V = 3.0   # below: the unit's regulator browns out
UNIT_MAX_V = 16.0  # above: its input protection keeps it off
UNIT_OHMS = 5.0 / 0.12  # 0.12 A at 5 V
IDLE_A = 0.002  # what the regulator draws below brown-out
IDENTITY = "IMU-STATION,SIM-SUPPLY,0001,1.0"
MAX_LINE = 256


@dataclass
class Channel:
    """One output: its setpoints and whether it is on."""

    volts: float = 0.0
    amps: float = 0.1
    on: bool = False


class SupplyOutputs:
    """A supply's channels and the unit on one of them; thread-safe.

    Parameters
    ----------
    device : SimDevice, optional
        The unit powered from ``unit_channel`` (None: an unloaded supply).
    channels : int
        How many outputs the supply has.
    unit_channel : int
        The output the unit is wired to.
    max_v, max_a : float
        The supply's own range; settings beyond it are clamped, as a real supply does.
    """

    def __init__(self, device: SimDevice | None = None, channels: int = 1, unit_channel: int = 1,
                 max_v: float = 30.0, max_a: float = 5.0):
        if not 1 <= unit_channel <= channels:
            raise ValueError(f"the unit's channel {unit_channel} is not one of 1..{channels}")
        self.device = device
        self.channels = [Channel() for _ in range(channels)]
        self.unit_channel = unit_channel
        self.max_v = max_v
        self.max_a = max_a
        self.lock = threading.RLock()
        if device is not None:
            device.power(False)  # the supply starts with its outputs off, as after *RST

    def channel(self, n: int) -> Channel:
        """Output ``n`` (1-based); IndexError for one the supply does not have."""
        if not 1 <= n <= len(self.channels):
            raise IndexError(n)
        return self.channels[n - 1]

    def set(self, n: int, volts: float | None = None, amps: float | None = None,
            on: bool | None = None) -> None:
        """Change output ``n``'s setpoints or state, then power the unit as the output now says."""
        with self.lock:
            ch = self.channel(n)
            if volts is not None:
                ch.volts = min(max(volts, 0.0), self.max_v)
            if amps is not None:
                ch.amps = min(max(amps, 0.0), self.max_a)
            if on is not None:
                ch.on = on
            self._couple()

    def reset(self) -> None:
        """``*RST``: every output off at 0 V and 0.1 A."""
        with self.lock:
            self.channels = [Channel() for _ in self.channels]
            self._couple()

    def measure(self, n: int) -> tuple[float, float]:
        """Output ``n``'s voltage and current as its terminals see them, (V, A)."""
        with self.lock:
            ch = self.channel(n)
            if not ch.on:
                return 0.0, 0.0
            if n != self.unit_channel or self.device is None:
                return ch.volts, 0.0
            if ch.volts < UNIT_MIN_V:
                return ch.volts, min(IDLE_A, ch.amps)
            demand = ch.volts / UNIT_OHMS
            if demand > ch.amps:  # constant current: the voltage sags to what the limit drives
                return ch.amps * UNIT_OHMS, ch.amps
            return ch.volts, demand

    def constant_current(self, n: int) -> bool:
        """Whether output ``n`` is limiting its current (CC) rather than holding its voltage (CV)."""
        with self.lock:
            ch = self.channel(n)
            volts, _ = self.measure(n)
            return ch.on and volts < ch.volts - 1e-9

    def _couple(self) -> None:
        if self.device is None:
            return
        volts, _ = self.measure(self.unit_channel)
        self.device.power(self.channel(self.unit_channel).on and UNIT_MIN_V <= volts <= UNIT_MAX_V)


_KEYWORDS = (("VOLT", "VOLTAGE"), ("CURR", "CURRENT"), ("OUTP", "OUTPUT"), ("MEAS", "MEASURE"),
             ("INST", "INSTRUMENT"), ("NSEL", "NSELECT"), ("SYST", "SYSTEM"), ("ERR", "ERROR"),
             ("SOUR", "SOURCE"), ("STAT", "STATE"))
_NUMBER = re.compile(r"^[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?$")


def _short(token: str) -> str:
    """A SCPI keyword in either form (VOLT, VOLTage, volt) as its short form; others unchanged."""
    word = token.upper()
    for short, long in _KEYWORDS:
        if word.startswith(short) and long.startswith(word):
            return short
    return word


class ScpiSupply:
    """A SCPI supply's command set over :class:`SupplyOutputs` (``feed`` bytes in, answers out).

    Parameters
    ----------
    outputs : SupplyOutputs
        The channels (and the unit on one of them).
    identity : str
        What ``*IDN?`` answers.
    """

    def __init__(self, outputs: SupplyOutputs, identity: str = IDENTITY):
        self.outputs = outputs
        self.identity = identity
        self.selected = 1
        self.errors: list[str] = []
        self.commands: list[str] = []  # every command heard, for tests
        self._buffer = b""

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host; the answers to every complete line in them, each LF-ended."""
        self._buffer += data
        out = []
        while b"\n" in self._buffer:
            line, self._buffer = self._buffer.split(b"\n", 1)
            text = line.decode("latin-1").strip()
            # Several commands on one line are separated by ';' (IEEE 488.2 program message units).
            for unit in filter(None, (u.strip() for u in text.split(";"))):
                self.commands.append(unit)
                answer = self._execute(unit)
                if answer is not None:
                    out.append(answer.encode("latin-1") + b"\n")
        if len(self._buffer) > MAX_LINE:  # a line that never ends: the input buffer overflows
            self._buffer = b""
            self._error('-363,"Input buffer overrun"')
        return b"".join(out)

    def _error(self, text: str) -> None:
        self.errors.append(text)

    def _execute(self, unit: str) -> str | None:
        header, _, argument = unit.partition(" ")
        argument = argument.strip()
        query = header.endswith("?")
        if header.startswith("*"):
            common = header.upper()
            if common == "*IDN?":
                return self.identity
            if common == "*RST":
                self.outputs.reset()
                self.selected = 1
                return None
            if common == "*CLS":
                self.errors.clear()
                return None
            if common == "*OPC?":
                return "1"
            self._error('-113,"Undefined header"')
            return None
        path = tuple(_short(t) for t in header.rstrip("?").lstrip(":").split(":") if t)
        if path[:1] == ("SOUR",):  # SOURce is the default root
            path = path[1:]
        try:
            return self._path(path, argument, query)
        except IndexError:
            self._error('-221,"Settings conflict"')
            return None
        except ValueError:
            self._error('-104,"Data type error"')
            return None

    def _path(self, path: tuple[str, ...], argument: str, query: bool) -> str | None:
        outputs, n = self.outputs, self.selected
        if path == ("SYST", "ERR") and query:
            return self.errors.pop(0) if self.errors else '0,"No error"'
        if path == ("INST", "NSEL"):
            if query:
                return str(n)
            wanted = int(argument)
            outputs.channel(wanted)
            self.selected = wanted
            return None
        if path in (("VOLT",), ("CURR",)):
            ch = outputs.channel(n)
            if query:
                return f"{ch.volts if path == ('VOLT',) else ch.amps:.4f}"
            if not _NUMBER.match(argument):
                raise ValueError(argument)
            if path == ("VOLT",):
                outputs.set(n, volts=float(argument))
            else:
                outputs.set(n, amps=float(argument))
            return None
        if path in (("OUTP",), ("OUTP", "STAT")):
            if query:
                return "1" if outputs.channel(n).on else "0"
            word = argument.upper()
            if word not in ("ON", "OFF", "1", "0"):
                raise ValueError(argument)
            outputs.set(n, on=word in ("ON", "1"))
            return None
        if path in (("MEAS", "VOLT"), ("MEAS", "CURR")) and query:
            volts, amps = outputs.measure(n)
            return f"{volts if path[1] == 'VOLT' else amps:.4f}"
        self._error('-113,"Undefined header"')
        return None
