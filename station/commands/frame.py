"""``imu-station frame``: check a frame description against a unit, or propose one from raw bytes."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from station.console.options import BAUD, DEFAULT_BAUDRATE, DURATION_S, port
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from rich.console import Group

    from station.frames.check import CheckReport

NAME = "frame"
HELP = "check a frame description (frame:FILE.yaml) against a unit, or guess one from raw bytes"
DESCRIPTION = """\
A board's own binary frames are described in YAML (schema imu-station/frame/1) and read with
--protocol frame:FILE.yaml by every command that reads a unit.

  frame check FILE.yaml --port PORT   a live table of the decoded values, frame and error rates,
                                      and the values that look wrong (|a| far from g or rates far
                                      from zero while the unit lies still, values that jump)
  frame check FILE.yaml --file RAW    the same over a raw byte capture
  frame guess RAW                     a description proposed from a raw byte capture (period,
                                      sync, checksum, counter, clock), printed as YAML to confirm

FILE.yaml may be the name of a shipped description: witmotion, mpu6050_dump.

exit codes: 0 done (check: nothing flagged), 1 check: values flagged, 3 port error,
4 unusable description or capture, or nothing to propose."""
EPILOG = """\
examples:
  imu-station frame guess raw.bin > myboard.yaml
  imu-station frame check myboard.yaml --file raw.bin
  imu-station frame check myboard.yaml --port /dev/ttyUSB0 --baud 115200 --duration 20
  imu-station capture --port /dev/ttyUSB0 --protocol frame:myboard.yaml --duration 60 -o cap.csv"""

MAX_RAW_BYTES = 64 * 2**20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the frame command's sub-commands (check, guess) to ``parser``."""
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    check = sub.add_parser("check", help="decode a unit or a raw capture with a description, show the values",
                           description="Decode a unit (--port) or a raw byte capture (--file) with a frame "
                                       "description and show the values, the frame and error rates and what "
                                       "looks wrong.")
    check.add_argument("description", metavar="FILE.yaml",
                       help="the frame description, or a shipped one's name")
    source = check.add_mutually_exclusive_group(required=True)
    source.add_argument("--port", type=port, metavar="PORT", help="serial device path or pyserial URL")
    source.add_argument("--file", type=Path, metavar="RAW", help="raw bytes as the unit sent them")
    # the same default as capture's: a description checked at one speed is captured at the same
    check.add_argument("--baud", type=BAUD, default=DEFAULT_BAUDRATE, metavar="BIT/S",
                       help=f"line speed (default: {DEFAULT_BAUDRATE}, as for capture)")
    check.add_argument("--duration", type=DURATION_S, default=None, metavar="S",
                       help="with --port: seconds to watch (default: until Ctrl-C)")
    guessing = sub.add_parser("guess", help="propose a description from a raw byte capture",
                              description="Propose a frame description from a raw byte capture: the frame "
                                          "length from the autocorrelation, the sync, the checksum type by "
                                          "trying each, a counter and a clock. Scales are left for you "
                                          "(frame check helps).")
    guessing.add_argument("raw", type=Path, metavar="RAW", help="raw bytes as the unit sent them")


def render(report: CheckReport, title: str) -> Group:
    """The check's table and flags, for the terminal.

    Parameters
    ----------
    report : CheckReport
        What the check found.
    title : str
        The description and the source.

    Returns
    -------
    rich.console.Group
    """
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    lost = (f", {report.lost} lost by the counter (the unit sent {report.sent_rate:.1f}/s)" if report.lost
            else "")
    head = Text(f"{title}\n{report.frames} frames, {report.frame_rate:.1f}/s{lost}; {report.errors} damaged "
                f"({report.error_rate:.2f}/s); {report.garbage_bytes} garbage bytes; {report.seconds:.1f} s")
    table = Table("value", "last", "mean", "std", "min", "max")
    for row in report.rows:
        table.add_row(row.name, *(f"{v:.6g}" for v in (row.last, row.mean, row.std, row.low, row.high)))
    if report.rows:
        still = "the unit lies still" if report.still else "the unit moves"
        table.caption = f"|a| = {report.acc_norm:.4f} m/s^2; {still}"
    flags = Text("\n".join(f"! {f}" for f in report.flags) or "nothing looks wrong",
                 style="bold red" if report.flags else "green")
    return Group(head, table, flags)


def _check(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    from station.common.text import PATH_CHARS, printable
    from station.common.yaml_file import read_bytes
    from station.frames.check import check_bytes, watch_port
    from station.frames.reader import load_decoder, load_description

    desc = load_description(args.description)
    console = Console()
    # shown as Text, not markup
    title = f"{printable(desc.name)}: {printable(args.file or args.port, PATH_CHARS)}"
    if args.file is not None:
        raw = read_bytes(args.file, "does not exist; give the raw capture's path", MAX_RAW_BYTES)
        report = check_bytes(load_decoder(args.description), raw)
        console.print(render(report, title))
    else:
        with Live(console=console, auto_refresh=False) as live:
            report = watch_port(args.port, f"frame:{args.description}", args.baud, args.duration, 0.5,
                                lambda r: live.update(render(r, title), refresh=True))
    return ExitCode.OUT_OF_LIMITS if report.flags else ExitCode.OK


def _guess(args: argparse.Namespace) -> int:
    from station.common.yaml_file import read_bytes
    from station.frames.guess import MIN_FRAMES, guess, to_yaml

    raw = read_bytes(args.raw, "does not exist; give the raw capture's path", MAX_RAW_BYTES)
    found = guess(raw)
    if found.length is None or not found.sync or found.frames < MIN_FRAMES:
        raise StationError(f"{args.raw}: nothing to propose: {'; '.join(found.problems)}")
    for problem in found.problems:
        print(f"imu-station frame guess: {problem}", file=sys.stderr)
    sys.stdout.write(to_yaml(found, str(args.raw)))
    return ExitCode.OK


def run(args: argparse.Namespace) -> int:
    """Run ``frame check`` or ``frame guess``."""
    return _check(args) if args.action == "check" else _guess(args)
