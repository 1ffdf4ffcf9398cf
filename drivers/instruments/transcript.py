"""Every command sent to an instrument and every reply, with its time: the run record keeps them.

A run that goes wrong at 3 a.m. is understood from this list: what the station asked of the
chamber, the table and the supply, when, and what each answered.
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Exchange:
    """One command and its reply.

    Parameters
    ----------
    t : float
        Wall-clock time the command was sent (Unix seconds).
    instrument : str
        The instrument's URL.
    command : str
        What was sent, as text (non-printable bytes escaped).
    reply : str
        What came back ('' where nothing did, or none was expected).
    duration_s : float
        From sending to the end of the reply.
    error : str
        Why the exchange failed ('' where it did not).
    """

    t: float
    instrument: str
    command: str
    reply: str
    duration_s: float
    error: str = ""


class Transcript:
    """A thread-safe, append-only list of :class:`Exchange` (bounded: the oldest go first)."""

    def __init__(self, max_entries: int = 100_000):
        self.max_entries = max_entries
        self._entries: list[Exchange] = []
        self._lock = threading.Lock()
        self.dropped = 0

    def add(self, instrument: str, command: str, reply: str, started: float, error: str = "") -> None:
        """Append one exchange that began at wall time ``started`` and ends now."""
        entry = Exchange(started, instrument, command, reply, time.time() - started, error)
        with self._lock:
            self._entries.append(entry)
            if len(self._entries) > self.max_entries:
                del self._entries[0]
                self.dropped += 1

    def entries(self) -> list[Exchange]:
        """A copy of the exchanges so far, oldest first."""
        with self._lock:
            return list(self._entries)

    def to_list(self) -> list[dict[str, object]]:
        """Plain data for the run record (JSON)."""
        return [asdict(e) for e in self.entries()]
