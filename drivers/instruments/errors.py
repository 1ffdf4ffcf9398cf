"""What goes wrong with a lab instrument, each a one-line message naming the instrument, the command
and the reply, and what to do next.

::

    DriverError (drivers.errors)
     └── InstrumentError            an instrument failed or answered what it should not
          ├── InstrumentTimeout     no reply in time (after the retries an idempotent command gets)
          ├── InstrumentGarbled     a reply that does not match what the description expects
          ├── InstrumentRefused     the instrument answered with an error
          ├── InstrumentLost        the link went away (cable, network, the instrument powered off)
          └── LimitRefused          the station refused to send a command beyond the plan's limits
"""

from __future__ import annotations

from drivers.errors import DriverError
from protocols.errors import ExitCode


class InstrumentError(DriverError):
    """An instrument command failed.

    Parameters
    ----------
    message : str
        One line: the instrument, the command, the reply, what to do.
    instrument : str
        The instrument's URL.
    command : str
        The command sent ('' where none was).
    reply : str
        The reply received ('' where none came).
    """

    def __init__(self, message: str, instrument: str = "", command: str = "", reply: str = ""):
        super().__init__(message, instrument)
        self.instrument = instrument
        self.command = command
        self.reply = reply


class InstrumentTimeout(InstrumentError):
    """No reply in time."""


class InstrumentGarbled(InstrumentError):
    """A reply that does not match the description's pattern."""


class InstrumentRefused(InstrumentError):
    """The instrument answered the command with an error."""


class InstrumentLost(InstrumentError):
    """The link to the instrument went away."""


class LimitRefused(InstrumentError):
    """A command the plan's limits forbid; nothing was sent."""

    exit_code = ExitCode.USAGE
