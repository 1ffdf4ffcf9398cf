"""The composition root: one sub-command a module in ``station.commands``.

Each command module has ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Errors the user can act on (``StationError``) are printed as one message, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import NoReturn

from drivers.errors import DriverError
from station import __version__
from station.errors import StationError

# Order is the order of ``--help``.
COMMANDS = [
    "demo",
    "simulate",
    "capture",
    "calibrate",
    "allan",
    "thermal",
    "apply",
    "export",
    "tui",
    "run",
    "run_many",
    "records",
]

EXIT_INTERRUPTED = 130
EXIT_USAGE = 4


class _Parser(argparse.ArgumentParser):
    """argparse with the station's exit code for usage errors (4, not argparse's 2)."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


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
    """The whole parser, or with ``only`` the one command's (engines are slow to import)."""
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
    return parser


def _chosen_command(argv: Sequence[str]) -> str | None:
    first = next((a for a in argv if not a.startswith("-")), None)
    module = first.replace("-", "_") if first else None
    return module if module in COMMANDS else None


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(_chosen_command(argv))
    except KeyboardInterrupt:
        print("imu-station: interrupted while starting", file=sys.stderr)
        return EXIT_INTERRUPTED
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        return int(args._run(args) or 0)
    except (StationError, DriverError) as exc:
        print(f"imu-station {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"imu-station {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
