"""How a driver's operations reach the wire: one ``Speaker`` per protocol family.

A kind's driver (``drivers.instruments.kinds``) asks for an operation by name
(``do("set_setpoint", value=35.0)``) and gets the reply's fields; the speaker knows the
description's command strings or registers, the link, the retries and the transcript.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from drivers.instruments.description import InstrumentDescription
from drivers.instruments.transcript import Transcript

Reply = dict[str, str]
"""A reply's named fields (``value``, ``identity``, ``state``, ...), as text."""


class Speaker(ABC):
    """Carries out a description's operations on one instrument."""

    def __init__(self, url: str, description: InstrumentDescription, transcript: Transcript | None):
        self.url = url
        self.description = description
        self.transcript = transcript if transcript is not None else Transcript()

    def has(self, operation: str) -> bool:
        """True when the description gives ``operation``."""
        return self.description.has(operation)

    @abstractmethod
    def do(self, operation: str, value: float | None = None, axis: int = 1, channel: int = 1) -> Reply:
        """Carry out ``operation``; the reply's fields (empty where none is expected)."""

    @abstractmethod
    def close(self) -> None:
        """Release the link."""
