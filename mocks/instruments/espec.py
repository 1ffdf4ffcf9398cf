"""An ESPEC SH/SU chamber's (SH-641 style) serial command set, for a raw pty: :class:`EspecChamber`.

``shared/specs/instruments.md``, "Chambers": ASCII lines ended by CR LF. ``TEMP?`` answers
``measured,setpoint,upper alarm,lower alarm``; ``TEMP,S25.0`` sets the setpoint (``OK:TEMP,S25.0``);
``MODE,CONSTANT`` runs at the setpoint, ``MODE,STANDBY`` idles; ``POWER,ON`` / ``POWER,OFF``;
``TYPE?`` identifies; anything refused is answered ``NA:<reason>``. The temperatures come from a
:class:`~mocks.instruments.chamber_plant.ChamberPlant`, which the commands change. Serve it with
``ByteServer(EspecChamber(plant), "pty")`` (``mocks.instruments.serving``).
"""

from __future__ import annotations

import re

from mocks.instruments.chamber_plant import ChamberPlant

MAX_LINE = 1024
_SET = re.compile(r"TEMP,S([-+]?[0-9]+(?:\.[0-9]*)?)$")


class EspecChamber:
    """The ESPEC line protocol, fed the host's bytes.

    Parameters
    ----------
    plant : ChamberPlant
        The chamber it reports and commands.
    identity : str
        What ``TYPE?`` answers.
    upper_alarm_c, lower_alarm_c : float
        The alarm limits ``TEMP?`` reports (and beyond which a setpoint is refused).
    """

    def __init__(self, plant: ChamberPlant, identity: str = "SCP220,T,85,-40", upper_alarm_c: float = 85.0,
                 lower_alarm_c: float = -40.0):
        self.plant = plant
        self.identity = identity
        self.upper_alarm_c = upper_alarm_c
        self.lower_alarm_c = lower_alarm_c
        self.powered = True
        self.requests: list[str] = []
        self._buffer = b""

    def feed(self, data: bytes) -> bytes:
        """Lines in (any split, CR LF or LF); one reply line out per complete line."""
        self._buffer += data
        out = b""
        while b"\n" in self._buffer:
            line, _, self._buffer = self._buffer.partition(b"\n")
            text = line.rstrip(b"\r").decode("latin-1").strip()
            if not text:
                continue
            self.requests.append(text)
            out += self.answer(text).encode("latin-1") + b"\r\n"
        if len(self._buffer) > MAX_LINE:
            self._buffer = b""
        return out

    def answer(self, command: str) -> str:
        """The reply to one command line."""
        plant = self.plant
        upper = command.upper()
        if upper == "TYPE?":
            return self.identity
        if upper == "TEMP?":
            return (f"{plant.now_air_c():.1f},{plant.setpoint_c:.1f},{self.upper_alarm_c:.1f},"
                    f"{self.lower_alarm_c:.1f}")
        if upper.startswith("POWER,"):
            if upper not in ("POWER,ON", "POWER,OFF"):
                return "NA:PARAMETER ERR"
            self.powered = upper == "POWER,ON"
            if not self.powered:
                plant.set_running(False)
            return f"OK:{command}"
        if upper == "MODE?":
            return "CONSTANT" if plant.running else ("STANDBY" if self.powered else "OFF")
        if upper.startswith("MODE,"):
            if upper not in ("MODE,CONSTANT", "MODE,STANDBY"):
                return "NA:PARAMETER ERR"
            if not self.powered:
                return "NA:CONTROLLER NOT READY-POWER OFF"
            plant.set_running(upper == "MODE,CONSTANT")
            return f"OK:{command}"
        if upper.startswith("TEMP,"):
            match = _SET.match(upper)
            if match is None:
                return "NA:PARAMETER ERR"
            value = float(match.group(1))
            if not self.lower_alarm_c <= value <= self.upper_alarm_c:
                return "NA:DATA OUT OF RANGE"
            plant.set_setpoint(value)
            return f"OK:{command}"
        return "NA:COMMAND ERR"
