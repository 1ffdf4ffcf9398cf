"""The station's exceptions and exit codes. Every message says what went wrong and what to do next.

One root, :class:`StationError`, defined in the lowest layer (``protocols.errors``) so that the
protocols and the drivers, which may not import ``station``, raise under it too; each layer
has its own root below it. The CLI catches ``StationError`` alone, prints the message as one
line and exits with the error's ``exit_code`` (an :class:`ExitCode`)::

    StationError                          exit 4 unless a subclass says otherwise
     ├── InputFileError                   a file the user gave cannot be read: file, line, field
     ├── EngineInputError                 the data cannot determine what was asked
     ├── OutputFileError                  a file the station writes cannot be written
     ├── SequenceError                    a step label that does not follow the spec (acquisition)
     ├── BlobError                        a parameter blob that cannot be built or read (export)
     ├── UnitMismatchError                a parameter file holds another unit's results (export)
     ├── DemoFailed                       a check of the demo did not hold
     ├── TurnOnError                      the unit's power-ups could not be recorded (acquisition)
     ├── RateTableError                   a rate step never held its rate (acquisition)
     ├── SettleTimeout                    exit 5: a soak's unit never settled (acquisition)
     ├── MavlinkUnavailable               the MAVLink protocol needs pymavlink (protocols)
     ├── FrameDescriptionError            a frame description breaks its schema's rules (protocols)
     ├── DescriptionError                 an instrument description breaks its schema (drivers.instruments)
     ├── RecordStoreError                 the record database is damaged, foreign or unreachable (factory)
     │    └── RecordsUnavailable          locked or read-only now: a run's record waits, pending
     ├── BadRecord                        a stored record that is not one: its row is refused (factory)
 ├── JournalError                     a run folder that cannot be resumed from its journal (factory)
     └── DriverError                      exit 3: device or link (drivers, see drivers.errors)
          ├── PortError                   opening the port failed
          │    ├── PortNotFound
          │    ├── PortBusy
          │    └── PortPermission
          ├── PortLost                    the port went away while open
          ├── PortFlooding                a port sent more than it could be decoded: dropped
          ├── NoSamples                   the port is open but no sample arrives
          ├── FramesRefused               exit 4: most frames fail their description's checksum
          ├── TableFault                  the turntable reports a fault
          ├── InstrumentError             a lab instrument failed (drivers.instruments.errors)
          │    ├── InstrumentTimeout      no reply in time, after the retries
          │    ├── InstrumentGarbled      a reply its description does not expect
          │    ├── InstrumentRefused      the instrument answered with an error
          │    ├── InstrumentLost         the link went away
          │    ├── MountRefused           a step the table cannot do with the unit as mounted
          │    └── LimitRefused           exit 4: beyond the plan's limits, nothing sent
          └── CommandError                a command to the device failed
               ├── CommandTimeout
               ├── CommandRejected
               └── CommandUnsupported

Decoders never raise on bad bytes (they count them), so no decoding error appears here.

Beside the tree, :class:`Terminated` is SIGTERM raised where Ctrl-C's ``KeyboardInterrupt`` would
be, so that every command that keeps its samples or discards an unfinished output set on Ctrl-C
does the same when a service manager or a factory script stops it (exit 143).
"""

from __future__ import annotations

from protocols.errors import ExitCode, StationError

__all__ = ["EngineInputError", "ExitCode", "InputFileError", "InputFileWarning", "OutputFileError",
           "StationError", "Terminated"]


class Terminated(KeyboardInterrupt):
    """SIGTERM: raised as Ctrl-C is, handled wherever Ctrl-C is; the command exits 143."""


class InputFileError(StationError):
    """A file the user gave cannot be read: names the file, line and field.

    Parameters
    ----------
    path : object
        The file, as the user named it.
    problem : str
        What is wrong, and what to do about it.
    line : int, optional
        1-based line of the problem, when the format has lines.
    column : str, optional
        The column or field at fault.
    """

    def __init__(self, path: object, problem: str, line: int | None = None, column: str | None = None):
        where = str(path)
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column '{column}'"
        super().__init__(f"{where}: {problem}")
        self.path = path
        self.problem = problem
        self.line = line
        self.column = column

    @classmethod
    def invalid_yaml(cls, path: object, exc: Exception) -> InputFileError:
        """The error for a file PyYAML could not parse, at the line of its problem mark if it has one."""
        mark = getattr(exc, "problem_mark", None)
        # PyYAML's own text spans lines and repeats the mark; context and problem alone read as one line.
        parts = [getattr(exc, "context", None), getattr(exc, "problem", None)]
        problem = ", ".join(" ".join(str(p).split()) for p in parts if p) or " ".join(str(exc).split())
        return cls(path, f"is not valid YAML: {problem}", line=mark.line + 1 if mark is not None else None)


class InputFileWarning(UserWarning):
    """A file the user gave was read with part of it left out (a capture's last line cut by a power
    loss): the command goes on, and the CLI prints the message as one ``warning:`` line."""


class EngineInputError(StationError):
    """The data cannot determine what was asked (too few poses, rank deficiency, motion, ...)."""


class OutputFileError(StationError):
    """A file the station writes cannot be written (disk full, no permission): names the file.

    Parameters
    ----------
    path : object
        The file that could not be written.
    problem : str
        Why, and what to do about it.
    """

    def __init__(self, path: object, problem: str):
        super().__init__(f"{path}: {problem}")
        self.path = path
