"""A Voetsch / Weiss chamber's simserv interface, spoken over loopback TCP by :class:`SimservChamber`.

``shared/specs/instruments.md``, "Chambers": a request is ASCII fields separated by the byte 0xB6
and ended by CR; the reply's fields are separated by 0xB6 and end with CR LF, the first field
``1`` on success. Every command of the spec's table is answered from a
:class:`~mocks.instruments.chamber_plant.ChamberPlant` (so a setpoint sent by the station's driver
moves the air, and the simulated unit that follows the plant); a command it does not know, or
an argument it cannot read, is answered with a first field other than 1, as the controller does.
Serve it with ``ByteServer(SimservChamber(plant), "tcp")`` (``mocks.instruments.serving``).
"""

from __future__ import annotations

from mocks.instruments.chamber_plant import ChamberPlant

SEP = b"\xb6"
MAX_LINE = 1024  # a request longer than this without CR is noise: dropped


class SimservChamber:
    """The simserv protocol of one chamber (index 1), fed the host's bytes.

    Parameters
    ----------
    plant : ChamberPlant
        The chamber it reports and commands.
    identity : str
        The fields 99997 answers after ``1`` (0xB6-separated when several).
    """

    def __init__(self, plant: ChamberPlant, identity: str = "SIMSERV\xb6VT 4021\xb6emulated"):
        self.plant = plant
        self.identity = identity.encode("latin-1")
        self.requests: list[bytes] = []  # every request, without its CR
        self.errors = 0  # set by 17012
        self._buffer = b""

    def feed(self, data: bytes) -> bytes:
        """Requests in (any split); replies out, one per complete request."""
        self._buffer += data
        out = b""
        while b"\r" in self._buffer:
            line, _, self._buffer = self._buffer.partition(b"\r")
            line = line.lstrip(b"\n")
            self.requests.append(line)
            out += self.answer(line) + b"\r\n"
        if len(self._buffer) > MAX_LINE:
            self._buffer = b""
        return out

    def answer(self, request: bytes) -> bytes:
        """The reply to one request (without CR LF)."""
        fields = request.split(SEP)
        try:
            return self._answer(fields[0].decode("latin-1"), [f.decode("latin-1") for f in fields[1:]])
        except (ValueError, IndexError):
            return b"-5" + SEP + b"bad argument"

    def _answer(self, command: str, args: list[str]) -> bytes:
        ok = b"1"
        plant = self.plant
        if command == "99997":
            return ok + SEP + self.identity
        if command == "10012":
            return ok + SEP + (b"1" if self.errors else b"0")
        if command == "17012":
            self.errors = 0
            return ok
        if args and args[0] != "1":
            return b"-3" + SEP + b"no such chamber"
        rest = args[1:]
        if command in ("11001", "11002", "11004", "11066", "11068", "11070", "11072") and rest[0] != "1":
            return b"-4" + SEP + b"no such control variable"
        if command == "11001":
            value = float(rest[1])
            if not plant.min_c <= value <= plant.max_c:
                return b"-6" + SEP + b"value out of range"
            plant.set_setpoint(value)
            return ok
        if command == "11002":
            return ok + SEP + f"{plant.setpoint_c:.1f}".encode()
        if command == "11004":
            return ok + SEP + f"{plant.now_air_c():.2f}".encode()
        if command in ("11066", "11070"):
            value = plant.gradient_up if command == "11066" else plant.gradient_down
            return ok + SEP + f"{value:.2f}".encode()
        if command in ("11068", "11072"):
            value = float(rest[1])
            if value <= 0:
                return b"-6" + SEP + b"value out of range"
            if command == "11068":
                plant.set_gradient(value, plant.gradient_down)
            else:
                plant.set_gradient(plant.gradient_up, value)
            return ok + SEP + f"{value:.2f}".encode()
        if command in ("14001", "14003"):
            if rest[0] != "1":
                return b"-4" + SEP + b"no such digital output"
            if command == "14001":
                plant.set_running(rest[1] == "1")
                return ok
            return ok + SEP + (b"1" if plant.running else b"0")
        return b"-1" + SEP + b"unknown command"
