"""The composition root: one sub-command a module in ``station.commands``.

Each command module has ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
Errors the user can act on (``StationError``) are printed as one message, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

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


def _load_commands() -> list:
    modules = []
    for name in COMMANDS:
        try:
            modules.append(importlib.import_module(f"station.commands.{name}"))
        except ModuleNotFoundError as exc:
            if exc.name != f"station.commands.{name}":
                raise
    return modules


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="imu-station",
        description="IMU acquisition and calibration station.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"imu-station {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in _load_commands():
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


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 4
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
