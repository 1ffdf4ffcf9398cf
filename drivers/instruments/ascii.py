"""Line protocols spoken from a description: simserv, ESPEC, ACUTROL, Aerosmith, SCPI, Korad.

Each operation sends its command string(s) with the fields filled in, waits for the reply the
description expects, and matches it against the reply pattern. A missing or garbled reply to an
idempotent command (a query, setting a setpoint) is retried, after discarding whatever arrived
late, up to ``link.retries`` times; then, or at once for a command that must not be sent twice,
the error is one line naming the instrument, the command and the reply. A reply matching the
description's ``error_reply`` is the instrument refusing. Every exchange goes to the transcript.
"""

from __future__ import annotations

import time

from drivers.instruments.description import Command, InstrumentDescription
from drivers.instruments.errors import (
    InstrumentError,
    InstrumentGarbled,
    InstrumentLost,
    InstrumentRefused,
    InstrumentTimeout,
)
from drivers.instruments.link import Link
from drivers.instruments.speaker import Reply, Speaker
from drivers.instruments.transcript import Transcript

ENCODING = "latin-1"  # one byte per character: simserv's 0xB6 separator is written \xb6


def shown(text: str) -> str:
    """Text as one visible line (every byte outside printable ASCII as ``\\xNN``)."""
    return "".join(ch if 32 <= ord(ch) < 127 and ch != "\\" else f"\\x{ord(ch):02x}" for ch in text)


class AsciiSpeaker(Speaker):
    """A description's line protocol on a :class:`~drivers.instruments.link.Link`."""

    def __init__(self, url: str, description: InstrumentDescription, link: Link,
                 transcript: Transcript | None = None):
        super().__init__(url, description, transcript)
        self.link = link
        self._last_sent = 0.0

    def do(self, operation: str, value: float | None = None, axis: int = 1, channel: int = 1) -> Reply:
        """Send ``operation``'s command(s); the last reply's named fields."""
        command = self.description.commands.get(operation)
        if command is None:
            raise InstrumentError(f"{self.url}: the {self.description.name} description has no '{operation}' "
                                  "command; add it to the description (?description=FILE.yaml)", self.url,
                                  operation)
        fields: Reply = {}
        for text, pattern in zip(command.send, command.reply, strict=True):
            filled = text.format(value=value if value is not None else 0.0, axis=axis, channel=channel)
            fields = self._exchange(command, filled, pattern)
        return fields

    def _exchange(self, command: Command, text: str, pattern) -> Reply:  # noqa: ANN001 (re.Pattern | None)
        settings = self.description.link
        tries = 1 + (settings.retries if command.idempotent else 0)
        for attempt in range(tries):
            wait = self._last_sent + settings.delay_s - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            if attempt:
                self.link.drain()
            started = time.time()
            reply = ""
            try:
                self.link.write(text.encode(ENCODING) + settings.write_end.encode(ENCODING))
                self._last_sent = time.monotonic()
                if pattern is None:
                    self.transcript.add(self.url, shown(text), "", started)
                    return {}
                reply = self.link.read_reply(settings.read_end.encode(ENCODING), settings.timeout_s,
                                             settings.quiet_s).decode(ENCODING).strip("\r\n")
                self._last_sent = time.monotonic()
                refused = self.description.error_reply.match(reply) if self.description.error_reply else None
                if refused:
                    raise InstrumentRefused(f"{self.url}: {self.description.name} refused {shown(text)!r}: "
                                            f"{shown(reply)!r}", self.url, shown(text), shown(reply))
                match = pattern.match(reply)
                if match is None:
                    raise InstrumentGarbled(f"{self.url}: {self.description.name} answered {shown(text)!r} "
                                            f"with {shown(reply)!r}, not what its description expects "
                                            f"({pattern.pattern!r})", self.url, shown(text), shown(reply))
                self.transcript.add(self.url, shown(text), shown(reply), started)
                return {k: v for k, v in match.groupdict().items() if v is not None}
            except (InstrumentTimeout, InstrumentGarbled) as exc:
                self.transcript.add(self.url, shown(text), shown(reply or exc.reply), started,
                                    type(exc).__name__)
                if attempt + 1 < tries:
                    continue
                retried = f" (tried {tries} times)" if tries > 1 else ""
                what = "no reply" if isinstance(exc, InstrumentTimeout) else f"reply {shown(reply)!r}"
                raise type(exc)(f"{self.url}: {self.description.name}: command {shown(text)!r}: {what}"
                                f"{retried}; check the link and the description", self.url, shown(text),
                                shown(reply)) from None
            except (InstrumentRefused, InstrumentLost) as exc:
                self.transcript.add(self.url, shown(text), shown(reply), started, type(exc).__name__)
                raise
        raise AssertionError("unreachable: the loop returns or raises")

    def close(self) -> None:
        """Close the link."""
        self.link.close()
