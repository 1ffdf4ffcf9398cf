"""The root of every error the station reports, and the exit codes it reports them with.

It lives in the lowest layer so that every layer can raise under one root: ``protocols`` may
import nothing of the station, ``drivers`` nothing above ``protocols``. ``station.errors``
re-exports both names and draws the whole tree.
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    """The exit codes of every ``imu-station`` command and of the factory's run records."""

    OK = 0
    """Done; on the factory line, every measurement within its limits."""
    OUT_OF_LIMITS = 1
    """A result outside its limits (factory FAIL, TUI verdict, ``records --verify`` mismatch)."""
    ABORTED = 2
    """The run was aborted: a step kept failing its checks, or the data could not determine the result."""
    DEVICE = 3
    """Device or link error: a port missing, busy, lost, or a unit not answering."""
    USAGE = 4
    """Usage or configuration error: a bad option, an unreadable or invalid input file."""
    TIMEOUT = 5
    """A time limit of the factory plan was exceeded."""
    INTERRUPTED = 130
    """Ctrl-C (128 + SIGINT, as a shell reports it)."""
    TERMINATED = 143
    """SIGTERM (128 + SIGTERM), handled as Ctrl-C is: samples kept, unfinished output sets discarded."""


class StationError(Exception):
    """An error the user can act on; the CLI prints its message, never a traceback.

    ``exit_code`` is the :class:`ExitCode` the command ends with; subclasses set their own.
    """

    exit_code: ExitCode = ExitCode.USAGE
