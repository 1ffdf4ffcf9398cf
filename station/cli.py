"""The composition root: one sub-command a module in ``station.commands``.

Each command module has ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Errors the user can act on (``StationError``, the one root of every layer's errors) are printed
as one line, never a traceback, and end the command with their ``ExitCode``; so do usage errors.
Nothing but this module imports a command module.
"""

from __future__ import annotations

import argparse
import atexit
import gc
import importlib
import os
import re
import signal
import sys
import warnings
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any, NoReturn

from station import __version__
from station.errors import ExitCode, InputFileWarning, StationError, Terminated

# OpenBLAS's threads buy no wall time on the small matrices the commands use, and spin on the other core
# meanwhile: on a busy two-core station an SVD of 4000 x 9 took 7 ms with two threads against 0.3 ms with
# one, and the free calibration 0.70 s against 0.46 s. numpy reads this once, when it loads (none of the
# modules above, nor any command module, imports it at module level); a user's own setting wins. The
# Allan engine runs its own threads and pins BLAS to one thread meanwhile anyway.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# Order is the order of ``--help``.
COMMANDS = [
    "demo",
    "simulate",
    "capture",
    "frame",
    "calibrate",
    "allan",
    "thermal",
    "characterise",
    "apply",
    "export",
    "tui",
    "run",
    "run_many",
    "records",
    "report",
    "ports",
    "instrument",
]


# Commands that read and write files only (captures, parameter files, records), never a unit's stream.
FILE_ONLY_COMMANDS = frozenset({"calibrate", "allan", "thermal", "apply", "export", "records", "report"})


class _Parser(argparse.ArgumentParser):
    """argparse with the station's usage errors: one line and exit 4 (argparse's 2 means aborted
    on the factory line)."""

    def error(self, message: str) -> NoReturn:
        from station.common.text import printable_message

        # the message repeats what was typed (or pasted: escape sequences, a file name from a unit)
        self.exit(ExitCode.USAGE, f"{self.prog}: error: {printable_message(message)}"
                                  f"{printable_message(_did_you_mean(message))} (see '{self.prog} --help')\n")


def _did_you_mean(message: str) -> str:
    """``; did you mean 'calibrate'?`` after argparse's "invalid choice: 'calibrat' (choose from ...)"."""
    found = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)$", message)
    if found is None:
        return ""
    # Python 3.11 quotes the choices, later versions do not
    choices = [c.strip().strip("'") for c in found.group(2).split(",")]
    import difflib  # only for a mistyped command: 5 ms of every start-up otherwise

    close = difflib.get_close_matches(found.group(1), choices, n=3, cutoff=0.6)
    return f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""


def _load_commands(names: Sequence[str] = COMMANDS) -> list:
    modules = []
    for name in names:
        try:
            modules.append(importlib.import_module(f"station.commands.{name}"))
        except ModuleNotFoundError as exc:
            if exc.name != f"station.commands.{name}":
                raise
    return modules


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole parser, or with ``only`` the one command's (engines are slow to import).

    Parameters
    ----------
    only : str, optional
        The module name of the one command to load (``run_many`` for ``run-many``).

    Returns
    -------
    argparse.ArgumentParser
        ``imu-station`` with a sub-parser per command; each sets ``_run`` to the command's ``run``.
    """
    parser = _Parser(
        prog="imu-station",
        description="IMU acquisition and calibration station.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"imu-station {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in _load_commands([only] if only else COMMANDS):
        cmd = sub.add_parser(
            module.NAME,
            help=module.HELP,
            description=getattr(module, "DESCRIPTION", module.HELP),
            epilog=getattr(module, "EPILOG", None),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    if not only:
        _add_completion(sub, parser)
    return parser


COMPLETION_HELP = "print the shell completion script for bash or zsh (see the epilog to install it)"
COMPLETION_EPILOG = """\
install (once; a new shell then completes commands, options and their choices):
  bash:  imu-station completion bash > ~/.local/share/bash-completion/completions/imu-station
  zsh:   mkdir -p ~/.zfunc && imu-station completion zsh > ~/.zfunc/_imu-station
         and in ~/.zshrc, before compinit: fpath=(~/.zfunc $fpath)"""


def _add_completion(sub: argparse._SubParsersAction, parser: argparse.ArgumentParser) -> None:
    """``imu-station completion bash|zsh``: shtab's script for the whole parser, commands included."""
    cmd = sub.add_parser("completion", help=COMPLETION_HELP, description=COMPLETION_HELP,
                         epilog=COMPLETION_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    cmd.add_argument("shell", choices=("bash", "zsh"), help="the shell to complete in")

    def print_script(args: argparse.Namespace) -> int:
        import shtab

        print(shtab.complete(parser, shell=args.shell))
        return ExitCode.OK

    cmd.set_defaults(_run=print_script)


def _chosen_command(argv: Sequence[str]) -> str | None:
    first = next((a for a in argv if not a.startswith("-")), None)
    module = first.replace("-", "_") if first else None
    return module if module in COMMANDS else None


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``imu-station`` with ``argv`` (default: the process's arguments).

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments after the program name.

    Returns
    -------
    int
        The command's :class:`~station.errors.ExitCode`. A usage error raises ``SystemExit(4)``
        from argparse after its one-line message.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    # At exit the interpreter clears every module and runs the collector over all of numpy's, scipy's and
    # numba's objects several times meanwhile: 0.15-0.2 s of the 2 s of `imu-station allan` on the
    # ADIS16405 record (issue 30). Frozen, they are left to the OS with the process; every file a command
    # writes is closed before it returns, and the standard streams are flushed at exit all the same.
    atexit.unregister(gc.freeze)  # once, however often main() runs in a process
    atexit.register(gc.freeze)
    previous = _raise_on_signals()
    try:
        return _main(argv)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _main(argv: list[str]) -> int:
    try:
        parser = build_parser(_chosen_command(argv))
        args = parser.parse_args(argv)
        if not getattr(args, "_run", None):
            parser.print_help()
            return ExitCode.USAGE
        # frame descriptions (--protocol frame:FILE.yaml, a plan's protocol) are readable by every command
        # that talks to a unit; those that only read files skip the reader and protocols.frame (30 ms)
        if args.command not in FILE_ONLY_COMMANDS:
            from station.frames import reader  # noqa: F401
    except BaseException as exc:
        if not (isinstance(exc, KeyboardInterrupt) or _SIGNALLED):
            raise
        print("imu-station: interrupted while starting", file=sys.stderr)
        return _interrupted_code(exc)
    try:
        with warnings.catch_warnings():  # restores what it changes, for a caller of main()
            warnings.simplefilter("always", InputFileWarning)
            warnings.showwarning = _warning_printer(args.command, warnings.showwarning)
            code = int(args._run(args) or ExitCode.OK)
        # a command that ended itself on the interrupt says Ctrl-C; the signal was SIGTERM
        return ExitCode.TERMINATED if code == ExitCode.INTERRUPTED and signal.SIGTERM in _SIGNALLED else code
    except StationError as exc:
        from station.common.text import printable_message

        # the message holds what the user, a file or a unit gave (a file name, a plan's key, a serial)
        print(f"imu-station {args.command}: error: {printable_message(exc)}", file=sys.stderr)
        return exc.exit_code
    except BaseException as exc:
        if not (isinstance(exc, KeyboardInterrupt) or _SIGNALLED):
            raise
        code = _interrupted_code(exc)
        print(f"imu-station {args.command}: {'terminated' if code == ExitCode.TERMINATED else 'interrupted'}",
              file=sys.stderr)
        return code


def _warning_printer(command: str, others: Callable[..., None]) -> Callable[..., None]:
    """``warnings.showwarning`` that prints an :class:`InputFileWarning` as one line, as errors are."""

    def show(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any) -> None:
        if not issubclass(category, InputFileWarning):
            others(message, category, *args, **kwargs)
            return
        from station.common.text import printable_message

        print(f"imu-station {command}: warning: {printable_message(message)}", file=sys.stderr)

    return show


_SIGNALLED: list[int] = []  # the signals that came while a command ran


def _raise_on_signals() -> dict[int, Any]:
    """Ctrl-C raises ``KeyboardInterrupt`` (in place of the handler ``station`` installs for the
    imports) and SIGTERM :class:`~station.errors.Terminated`, so that both end a command the same
    way: samples kept, unfinished output sets discarded, temporary files removed. Each signal is
    noted too, since a library may turn the interrupt into an error of its own (numpy's import
    into an ``ImportError``). Returns the handlers it replaced, to be put back."""
    import threading

    _SIGNALLED.clear()
    if threading.current_thread() is not threading.main_thread():
        return {}

    def interrupted(signum: int, frame: FrameType | None) -> None:
        _SIGNALLED.append(signum)
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    previous = {int(sig): signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, interrupted)
    signal.signal(signal.SIGTERM, interrupted)
    return previous


def _interrupted_code(exc: BaseException) -> ExitCode:
    terminated = isinstance(exc, Terminated) or signal.SIGTERM in _SIGNALLED
    return ExitCode.TERMINATED if terminated else ExitCode.INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
