"""The drivers' exception root. Every message names the port and says what to do next.

``DriverError`` is a :class:`protocols.errors.StationError` (the one root every layer raises
under, kept in the lowest layer since ``drivers`` may not import ``station``), with exit code
``ExitCode.DEVICE`` (3: device or link). The whole tree is drawn in ``station.errors``.

::

    DriverError
     ├── PortError                 opening the port failed
     │    ├── PortNotFound         no such device, or an unknown URL scheme
     │    ├── PortBusy             another program holds the port
     │    └── PortPermission       the user may not open it
     ├── PortLost                  the port went away while open (unplugged, simulator stopped)
     ├── NoSamples                 the port is open but no sample arrives
     └── CommandError             a command to the device failed
          ├── CommandTimeout       no answer in time
          ├── CommandRejected      the device answered with an error status
          └── CommandUnsupported   the protocol has no such command
"""

from __future__ import annotations

from protocols.errors import ExitCode, StationError


class DriverError(StationError):
    """A device or link error the user can act on; ``port`` names the port it concerns.

    Parameters
    ----------
    message : str
        What failed, naming the port, and what to do next.
    port : str
        The port (device path or URL) the error concerns.
    """

    exit_code = ExitCode.DEVICE

    def __init__(self, message: str, port: str = ""):
        super().__init__(message)
        self.port = port


class PortError(DriverError):
    """The port could not be opened."""


class PortNotFound(PortError):
    """No device at that path, or a URL scheme nobody registered."""


class PortBusy(PortError):
    """Another program holds the port (an exclusive lock is taken where the OS supports it)."""


class PortPermission(PortError):
    """The operating system refuses to open the port for this user."""


class PortLost(DriverError):
    """The port disappeared while open. Every sample received before it is still delivered."""


class PortFlooding(DriverError):
    """The port sends more than the station can decode in its share of each turn; it was dropped so
    that the other units go on. Every sample decoded before is still delivered."""


class FramesRefused(DriverError):
    """Most of the unit's frames fail the checksum its frame description names: the description is
    wrong, not the link (exit 4). The message names the checksum that fits, when one does."""

    exit_code = ExitCode.USAGE


class NoSamples(DriverError):
    """The port is open but no sample frame arrives (unit stopped, wrong baud rate or protocol)."""


class CommandError(DriverError):
    """A command to the device did not succeed."""


class CommandTimeout(CommandError):
    """The device did not answer a command in time."""


class CommandRejected(CommandError):
    """The device answered a command with an error status (unknown command, bad argument, busy).

    Parameters
    ----------
    message : str
        What the device refused, naming the port.
    port : str
        The port the device is on.
    status : int
        The device's error status code.
    """

    def __init__(self, message: str, port: str = "", status: int = 0):
        super().__init__(message, port)
        self.status = status


class CommandUnsupported(CommandError):
    """The protocol spoken on this port has no such command."""
