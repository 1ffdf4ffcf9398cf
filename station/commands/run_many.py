"""``imu-station run-many``: one ``run`` process per unit, a live summary table, the worst outcome."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from station.common.text import printable
from station.console.options import (
    MAX_SEED,
    SEED,
    add_db_arguments,
    check_range,
    db_url,
    files_root,
    number,
    port,
)
from station.console.options import protocol as protocol_name
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from station.factory.many import UnitSpec

NAME = "run-many"
HELP = "run a factory plan on several units at once, one process per port, with a live summary table"
DESCRIPTION = """\
Start one 'imu-station run' process per unit (--port P with its --table-port T or its --table URL,
in the same order;
or --simulate N simulated units on simulated tables), follow them in a live table on stderr
(unit, serial, phase, step, time, outcome), and print the summary (or, with --json, every unit's
outcome and record) on stdout. Every unit's record goes to the one database --db; each unit's log
lines go to FILES/logs/<start>-<unit>.log. A record the database does not take is kept in
FILES/pending-records/ with the unit's outcome unchanged; a line on stderr says how many and that
'imu-station records sync' stores them."""
EPILOG = """\
exit code: the worst of the units' exit codes (see 'imu-station run --help'), ranked
  0 pass < 1 fail < 2 aborted < 5 timeout < 3 device or link error < 4 usage or configuration.

examples:
  imu-station run-many --plan plan.yaml --port /dev/ttyUSB0 --table-port /dev/ttyUSB1 \\
                       --port /dev/ttyUSB2 --table-port /dev/ttyUSB3 --serial A1 --serial A2
  imu-station run-many --plan plan.yaml --simulate 4 --db line.sqlite --json"""


MAX_UNITS = 64  # simulated units one station runs at once
MIN_SPEED, MAX_SPEED = 0.1, 20.0  # as 'imu-station run --speed'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the run-many command's options to ``parser``."""
    parser.add_argument("--plan", required=True, type=Path, metavar="PLAN.yaml", help="the factory plan")
    parser.add_argument("--port", action="append", default=[], type=port, metavar="PORT",
                        help="a unit's serial port (repeat for each unit)")
    parser.add_argument("--table-port", action="append", default=[], type=port, metavar="PORT",
                        help="the turntable port of the unit given by the --port in the same position")
    parser.add_argument("--table", action="append", default=[], metavar="URL",
                        help="a unit's rate table by URL (acutrol://HOST:PORT?axes=3, ...), instead of its "
                             "--table-port; repeat, in the order of --port")
    parser.add_argument("--protocol", type=protocol_name, default=None, metavar="frame:FILE.yaml",
                        help="the units stream a board's own frames described in YAML (or native); default: "
                             "the plan's device.protocol, else native (then give each unit's --serial)")
    parser.add_argument("--serial", action="append", default=[], metavar="SN",
                        help="serial numbers in --port order (default: each unit's own, as it reports it)")
    parser.add_argument("--simulate", type=int, default=None, metavar="N",
                        help=f"N simulated units on simulated turntables, 1 to {MAX_UNITS} (seeds --seed .. "
                             "--seed+N-1)")
    parser.add_argument("--seed", type=SEED, default=0, metavar="N",
                        help="--simulate: first seed (default 0)")
    parser.add_argument("--speed", type=number(float, MIN_SPEED, MAX_SPEED, unit="times real time"),
                        default=1.0, metavar="X",
                        help="--simulate: the simulated units' clocks run X times faster than real time, "
                             f"{MIN_SPEED:g} to {MAX_SPEED:g}")
    parser.add_argument("--station", default=None, metavar="ID",
                        help="this station's id (default $IMU_STATION_ID or the host name)")
    add_db_arguments(parser)
    parser.add_argument("--files", type=Path, default=None, metavar="DIR",
                        help="where captures, exports and logs are kept (as for 'run')")
    parser.add_argument("--json", action="store_true", help="print every unit's outcome and record as JSON")


def units_of(args: argparse.Namespace) -> list[UnitSpec]:
    """The units to run, from ``--port``/``--table-port`` pairs or ``--simulate N``; refuses a
    mismatched or repeated port, or serials that do not match the units.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options.

    Returns
    -------
    list of UnitSpec
        One per unit, in the order given.

    Raises
    ------
    StationError
        What is wrong with the combination of options.
    """
    from station.factory.many import UnitSpec

    if args.simulate is not None:
        if args.port or args.table_port:
            raise StationError("give either --simulate N or --port/--table-port pairs, not both")
        check_range("--simulate", args.simulate, 1, MAX_UNITS, unit="simulated units")
        if args.seed + args.simulate - 1 > MAX_SEED:
            raise StationError(f"--seed {args.seed} with --simulate {args.simulate}: the last seed passes "
                               f"{MAX_SEED}")
        if args.serial and len(args.serial) != args.simulate:
            raise StationError(f"{len(args.serial)} --serial for {args.simulate} simulated units")
        serials = args.serial or ["auto"] * args.simulate
        return [UnitSpec(f"sim {args.seed + i}", serials[i], seed=args.seed + i, speed=args.speed)
                for i in range(args.simulate)]
    if args.speed != 1.0:
        raise StationError("--speed applies to --simulate only")
    if not args.port:
        raise StationError("give --port P --table-port T for each unit, or --simulate N")
    tables = args.table_port or args.table
    if args.table_port and args.table:
        raise StationError("give each unit's --table-port or its --table URL, not both")
    if tables and len(tables) != len(args.port):
        raise StationError(f"{len(args.port)} --port but {len(tables)} --table-port/--table: each unit "
                           "needs its turntable, in the same order")
    if len(set(args.port)) != len(args.port) or len(set(tables)) != len(tables):
        raise StationError("a port is given twice: each unit and each table has its own port")
    if args.serial and len(args.serial) != len(args.port):
        raise StationError(f"{len(args.serial)} --serial for {len(args.port)} --port: give one per unit "
                           "or none")
    serials = args.serial or ["auto"] * len(args.port)
    return [UnitSpec(port, serials[i], port=port,
                     table_port=args.table_port[i] if args.table_port else None,
                     table=args.table[i] if args.table else None)
            for i, port in enumerate(args.port)]


def run(args: argparse.Namespace) -> int:
    """Run every unit, print the summary (or JSON); exit with the worst unit's code."""
    from rich.console import Console

    from station.console.markup import markup_safe
    from station.factory.many import RunMany, summary_table, worst_exit_code
    from station.factory.plan import load_plan, with_protocol
    from station.factory.spool import pending_dir

    units = units_of(args)
    plan = load_plan(args.plan)  # refused here, once, rather than by every child
    if args.port and not (args.table_port or args.table) and (plan.instruments is None
                                                              or plan.instruments.table is None):
        raise StationError("give --port P --table-port T (or --table URL) for each unit, or a table in the "
                           "plan's instruments, or --simulate N")
    if args.protocol is not None:
        plan = with_protocol(plan, args.protocol)
    if not plan.asks_serial and args.simulate is None and not args.serial:
        raise StationError(f"units read through {plan.protocol} cannot be asked their serial numbers: give "
                           "one --serial per --port")
    url = db_url(args)
    root = files_root(args, url)
    common = ["--db", url, "--files", str(root)]
    if args.protocol is not None:
        common += ["--protocol", plan.protocol]  # with its file found once, here (made absolute)
    if args.station:
        common += ["--station", args.station]
    console = Console(stderr=True)
    results = RunMany(plan.path.resolve(), units, common, root / "logs", console).run()
    code = worst_exit_code([u.exit_code if u.exit_code is not None else ExitCode.DEVICE for u in results])
    if args.json:
        out = {"plan": plan.name, "exit_code": code, "units": [
            {"unit": u.spec.label, "serial": u.serial or u.spec.serial, "outcome": u.outcome,
             "exit_code": u.exit_code, "reason": u.reason, "elapsed_s": round(u.elapsed_s, 3),
             "log": str(u.log_path), "record": u.record, "record_pending": u.pending or None}
            for u in results]}
        sys.stdout.write(json.dumps(out, indent=1, allow_nan=False) + "\n")
    else:
        table = summary_table(results, f"run-many {markup_safe(plan.name)}: exit {code}")  # a title is markup
        Console(file=sys.stdout, width=140).print(table)
    pending = [u for u in results if u.pending]
    if pending:
        # The units' outcomes stand; their records wait in the files folder for the database.
        print(f"imu-station run-many: {len(pending)} record(s) PENDING, not in the database, kept in "
              f"{printable(pending_dir(root), 1000)}; 'imu-station records sync --db {printable(url, 1000)} "
              f"--files {printable(root, 1000)}' stores them, as does the next run", file=sys.stderr)
    return code
