"""An emulated Korad / Tenma KA3005P coupled to the simulated unit: what ``korad://`` and the shipped
``korad.yaml`` expect (``shared/specs/instruments.md``, Bench supplies).

The KA3005P ends nothing: neither its commands nor its replies have a terminator. The real one tells
commands apart by their shapes (``VSET1:05.00``, ``OUT1``, ``STATUS?``...) and by the pause between
them (its manual asks for about 50 ms); this emulator does the same: a command whose every byte is
known is done at once, a number is done when a byte that cannot continue it arrives, when it has
all its decimals, or after a pause of ``gap_s``; bytes that start no known command are dropped one by
one until one does (a real unit's resynchronisation after line noise). ``STATUS?`` answers one byte:
bit 0 CV (1) or CC (0), bit 4 the beeper, bit 5 unlocked, bit 6 the output.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable

from mocks.instruments.scpi_supply import SupplyOutputs

IDENTITY = "KORAD KA3005P V5.8 SN:00000001"
GAP_S = 0.03  # a pause this long ends a command (the manual's 50 ms between commands, less margin)

_FIXED = re.compile(rb"\*IDN\?|STATUS\?|OUT[01]|BEEP[01]|OCP[01]|OVP[01]|LOCK[01]|[VI]SET\d\?|[VI]OUT\d\?")
_NUMERIC = re.compile(rb"([VI])SET(\d):(\d{0,2}(?:\.(\d*))?)")
_DECIMALS = {b"V": 2, b"I": 3}
# What may still grow into a command: a prefix of a fixed one, or of a setting or a reading.
_LITERALS = (b"*IDN?", b"STATUS?", b"OUT1", b"BEEP1", b"OCP1", b"OVP1", b"LOCK1")
_GROWING = re.compile(rb"[VI](S(E(T(\d(:[\d.]*)?)?)?)?)?|[VI](O(U(T(\d)?)?)?)?")


def _could_grow(buffer: bytes) -> bool:
    return any(lit.startswith(buffer) for lit in _LITERALS) or _GROWING.fullmatch(buffer) is not None


class KoradSupply:
    """The KA3005P's command set over one channel of :class:`SupplyOutputs`.

    Parameters
    ----------
    outputs : SupplyOutputs
        The supply (channel 1 is the KA3005P's only output).
    clock : callable
        Monotonic seconds (a test's fake clock); the gap between commands is measured on it.
    gap_s : float
        The pause that ends a command.
    """

    def __init__(self, outputs: SupplyOutputs, clock: Callable[[], float] = time.monotonic,
                 gap_s: float = GAP_S, identity: str = IDENTITY):
        self.outputs = outputs
        self.clock = clock
        self.gap_s = gap_s
        self.identity = identity
        self.beep = True
        self.locked = False
        self.commands: list[str] = []  # every command understood, for tests
        self.dropped = 0  # bytes that started no command
        self._buffer = b""
        self._last = clock()

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host; the answers to every command they complete (no terminators)."""
        now = self.clock()
        out = []
        if self._buffer and now - self._last >= self.gap_s:
            out.append(self._parse(final=True))  # the pause ended what was pending
        self._last = now
        self._buffer += data
        out.append(self._parse(final=False))
        return b"".join(out)

    def _parse(self, final: bool) -> bytes:
        out = []
        while self._buffer:
            buffer = self._buffer
            fixed = _FIXED.match(buffer)
            if fixed:
                self._buffer = buffer[fixed.end():]
                out.append(self._execute(fixed.group().decode("ascii")))
                continue
            numeric = _NUMERIC.match(buffer)
            if numeric and numeric.group(3).strip(b"."):
                decimals = numeric.group(4) or b""
                complete = (final or numeric.end() < len(buffer)
                            or len(decimals) >= _DECIMALS[numeric.group(1)])
                if not complete:
                    return b"".join(out)
                self._buffer = buffer[numeric.end():]
                out.append(self._execute(numeric.group().decode("ascii")))
                continue
            if not final and _could_grow(buffer):
                return b"".join(out)
            self._buffer = buffer[1:]
            self.dropped += 1
        return b"".join(out)

    def _execute(self, command: str) -> bytes:
        self.commands.append(command)
        outputs = self.outputs
        if command == "*IDN?":
            return self.identity.encode("ascii")
        if command == "STATUS?":
            return bytes([self.status()])
        if command[:3] in ("OUT", "BEE", "OCP", "OVP", "LOC") and command[-1] in "01":
            on = command[-1] == "1"
            if command.startswith("OUT"):
                outputs.set(1, on=on)
            elif command.startswith("BEEP"):
                self.beep = on
            elif command.startswith("LOCK"):
                self.locked = on
            return b""
        channel = int(command[4])
        if channel != 1:
            return b""  # a one-channel supply ignores another channel's commands
        if command.endswith("?"):
            ch = outputs.channel(1)
            volts, amps = outputs.measure(1)
            value = {"VSET": ch.volts, "ISET": ch.amps, "VOUT": volts, "IOUT": amps}[command[:4]]
            return (f"{value:05.2f}" if command[0] == "V" else f"{value:.3f}").encode("ascii")
        value = float(command.split(":", 1)[1])
        if command[0] == "V":
            outputs.set(1, volts=value)
        else:
            outputs.set(1, amps=value)
        return b""

    def status(self) -> int:
        """The STATUS? byte: bit 0 CV, bit 4 beeper, bit 5 unlocked, bit 6 output."""
        on = self.outputs.channel(1).on
        return ((0 if self.outputs.constant_current(1) else 1) | (0x10 if self.beep else 0)
                | (0 if self.locked else 0x20) | (0x40 if on else 0))
