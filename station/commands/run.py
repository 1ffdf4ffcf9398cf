"""``imu-station run``: one unattended factory run of one unit, recorded, with an exit code."""

from __future__ import annotations

import argparse
import json
import logging
import os
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from station.common.text import printable
from station.console.options import DURATION_S, SEED, add_db_arguments, check_range, db_url, files_root, port
from station.console.options import protocol as protocol_name
from station.errors import StationError

if TYPE_CHECKING:
    from station.factory.records import RunRecord
    from station.factory.spool import Pending

NAME = "run"
HELP = "run a factory plan on one unit unattended (turntable or --simulate), record it, exit with its outcome"
DESCRIPTION = """\
Run the plan's sequence on the unit at --port with the motorized turntable at --table-port placing
and turning it, calibrate, judge every measurement against the plan's limits, export, and store one
record (unit, station, start/end, outcome, phases, measurements with limits and units, attachments
with SHA-256) in the record database. The raw capture, the parameter file and the exports are kept
beside the record in FILES/<serial>/<start>-<run id>/, with record.json.

A plan with a 'campaign:' section runs a chamber campaign: soaks at several temperatures (the
sequence, power cycles through the supply, still records), the ramps recorded, a calibration
across temperature at the end; every completed step is journaled (journal.jsonl, fsync'ed) and
--resume RUN_DIR carries on after a crash, ending with the one record.

One JSON record on stdout with --json (else a short summary); logs go to stderr."""
EPILOG = """\
exit codes:
  0  pass: every measurement within its limits
  1  fail: a measurement outside its limits (or the unit reports another serial than --serial)
  2  aborted: a step kept failing its checks, the calibration could not be determined, Ctrl-C
  3  device or link error: unit or turntable port missing, lost (unplugged) or not answering
  4  usage or configuration error: bad options, a plan with an error (the message names the line)
  5  timeout: the plan's run.timeout_s or run.step_timeout_s was exceeded
A record the database does not take (locked past 30 s, read-only, unreachable) keeps the unit's exit
code: it is kept in FILES/pending-records/<run id>.json, a line on stderr says so, and
'imu-station records sync' (or the next run) stores it.

environment: IMU_STATION_DB (default --db), IMU_STATION_ID (default --station), IMU_STATION_DB_WAIT
  (seconds to wait for another process's lock on the database, default 30)

examples:
  imu-station run --plan plan.yaml --port /dev/ttyUSB0 --table-port /dev/ttyUSB1 --serial A1234 --json
  imu-station run --plan plan.yaml --simulate --seed 3 --serial SIM-3 --db postgresql://line@db/imu
  imu-station run --plan plan.yaml --protocol frame:myboard.yaml --port /dev/ttyUSB0 \\
                  --table-port /dev/ttyUSB1 --serial B-0042
  imu-station run --plan examples/campaign.yaml --simulate --serial auto
  imu-station run --resume imu-station-records-files/SIM-000000/20261128T123500Z-46303b15 --simulate"""

# The simulated units' clock may run this much faster than the wall clock (rehearsals).
MIN_SPEED, MAX_SPEED = 0.1, 20.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the run command's options to ``parser``."""
    parser.add_argument("--plan", type=Path, metavar="PLAN.yaml",
                        help="the factory plan (with --resume: default the journal's, checked by SHA-256)")
    parser.add_argument("--resume", type=Path, default=None, metavar="RUN_DIR",
                        help="carry on a chamber campaign cut short (a crash, kill -9, a power cut) from the "
                             "journal in its run folder: the steps journaled are kept (their files checked "
                             "by SHA-256), the instruments brought back, the first step not journaled done "
                             "next")
    parser.add_argument("--port", type=port, metavar="PORT",
                        help="the unit's serial port (device path or pyserial URL)")
    parser.add_argument("--table-port", type=port, metavar="PORT", help="the turntable's serial port")
    parser.add_argument("--table", metavar="URL",
                        help="a rate table by URL (acutrol://HOST:PORT?axes=3, ...) instead of --table-port: "
                             "replaces the plan's instruments.table URL")
    parser.add_argument("--chamber", metavar="URL", help="the climatic chamber (votsch://HOST, ...): "
                        "replaces the plan's instruments.chamber URL")
    parser.add_argument("--supply", metavar="URL", help="the bench supply (scpi://HOST, ...): replaces the "
                        "plan's instruments.supply URL")
    parser.add_argument("--protocol", type=protocol_name, default=None, metavar="frame:FILE.yaml",
                        help="the unit streams a board's own frames described in YAML (or native); default: "
                             "the plan's device.protocol, else native. A frame-described unit is asked "
                             "nothing: give its --serial")
    parser.add_argument("--simulate", action="store_true",
                        help="a simulated unit on a simulated turntable, both on pseudo-terminals")
    parser.add_argument("--seed", type=SEED, default=0, metavar="N",
                        help="--simulate: the simulated unit's intrinsics and noise (default 0)")
    parser.add_argument("--unplug-after", type=DURATION_S, default=None, metavar="S",
                        help="--simulate: pull the unit's cable after S seconds (to rehearse exit 3)")
    parser.add_argument("--speed", type=float, default=None, metavar="X",
                        help="--simulate: run the simulated unit's clock X times faster than real time, "
                             f"{MIN_SPEED:g} to {MAX_SPEED:g} (rehearsals; default 1, a campaign's "
                             "campaign.simulate.speed)")
    parser.add_argument("--serial", default=None, metavar="SN",
                        help="the unit's serial number; 'auto' takes the one the unit reports")
    parser.add_argument("--station", default=None, metavar="ID",
                        help="this station's id (default $IMU_STATION_ID or the host name)")
    add_db_arguments(parser)
    parser.add_argument("--files", type=Path, default=None, metavar="DIR",
                        help="where captures, parameter files and exports are kept (default: beside a "
                             "SQLite database as <name>-files/, else ./imu-station-files)")
    parser.add_argument("--json", action="store_true", help="print the record as JSON on stdout")
    parser.add_argument("--events", action="store_true",
                        help="also write progress events as '@event {json}' lines on stderr (run-many)")


def _check(args: argparse.Namespace) -> None:
    missing = [name for name, value in (("--plan", args.plan), ("--serial", args.serial)) if value is None]
    if args.resume is None and missing:
        # a usage error, as argparse's own for a required option (exit 4)
        print(f"imu-station run: error: the following arguments are required: {', '.join(missing)} (or "
              "--resume RUN_DIR, a campaign's folder)", file=sys.stderr)
        raise SystemExit(4)
    if args.simulate and (args.port or args.table_port or args.table or args.chamber or args.supply):
        raise StationError("give either --simulate or --port/--table-port (and instrument URLs), not both: "
                           "--simulate serves the plan's instruments simulated")
    if not args.simulate and not args.port:
        raise StationError("give the unit's --port and the turntable's --table-port, or --simulate")
    if args.table_port and args.table:
        raise StationError("give the table's --table-port (the station's own table) or --table URL, not both")
    if (args.unplug_after is not None or args.seed or args.speed is not None) and not args.simulate:
        raise StationError("--seed, --speed and --unplug-after apply to --simulate only")
    if args.speed is not None:
        check_range("--speed", args.speed, MIN_SPEED, MAX_SPEED, unit="times real time")
    if args.resume is not None and args.seed:
        raise StationError("--resume takes the simulated unit's --seed from the run's journal; leave it out")


def summary(record: RunRecord) -> str:
    """The record as the short text the command prints: outcome, measurements with limits, files."""
    lines = [f"{record.outcome} {printable(record.serial)} (exit {record.exit_code})"
             + (f": {record.reason}" if record.reason else "")]
    for m in record.measurements().values():
        if m.outcome == "UNSET":
            continue
        value = f"{m.value:.6g}" if isinstance(m.value, float) else printable(m.value)
        bounds = "" if m.low is None and m.high is None else \
            f"  [{'' if m.low is None else f'{m.low:g}'} .. {'' if m.high is None else f'{m.high:g}'}]"
        lines.append(f"  {m.outcome:4} {m.name:28} {value:>14} {m.unit:6}{bounds}")
    lines.append(f"record {record.run_id}; files in {record.files_dir or '(none)'}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the plan on the unit, store the record, print it; exit with the run's outcome."""
    from station.factory.plan import load_plan, with_instruments, with_protocol
    from station.factory.records import READ_WAIT_S, RecordStore
    from station.factory.run import RunRequest, check_serial, configure_logging
    from station.factory.simrig import SimulatedUnit
    from station.factory.spool import keep
    from station.factory.store_errors import RecordsUnavailable, wait_s
    from station.factory.unit import run_unit

    _check(args)
    resumed = resume_arguments(args)
    plan = load_plan(args.plan)
    plan_table = plan.instruments is not None and plan.instruments.table is not None
    if not args.simulate and not (args.table_port or args.table or plan_table):
        raise StationError("give the turntable's --table-port, a --table URL or a table in the plan's "
                           "instruments (a manual fixture is driven from a factory script through the "
                           "Python API, station.factory.api)")
    if args.protocol is not None:
        plan = with_protocol(plan, args.protocol)
    plan = with_instruments(plan, {"chamber": args.chamber, "table": args.table, "supply": args.supply})
    station = args.station or os.environ.get("IMU_STATION_ID") or socket.gethostname()
    url = db_url(args)
    progress = CampaignProgress.start() if plan.campaign is not None and sys.stderr.isatty() else None
    handler = configure_logging(args.serial, progress.stream if progress is not None else None)
    on_event = None
    if args.events or progress is not None:
        def on_event(event: dict[str, Any]) -> None:
            if progress is not None:
                progress.update(event)
            if args.events:
                sys.stderr.write("@event " + json.dumps(event) + "\n")
                sys.stderr.flush()

    request = RunRequest(plan=plan, serial=args.serial, station=station, port=args.port,
                         table_port=args.table_port, files_root=files_root(args, url), on_event=on_event,
                         simulate=SimulatedUnit(args.seed, unplug_after_s=args.unplug_after,
                                                speed=_speed(args, plan),
                                                # a campaign's unit: its scale and misalignment move with T
                                                thermal_intrinsics=plan.campaign is not None)
                         if args.simulate else None, resume=resumed)
    check_serial(request)  # before the record database is opened
    try:
        # A damaged or foreign database is refused before the unit is touched; one that is locked or
        # read-only now does not stop the run: its record is kept pending.
        RecordStore.open(url, wait=wait_s(READ_WAIT_S)).close()
    except RecordsUnavailable as exc:
        print(f"imu-station run: {exc}; the unit is run, its record will be kept pending if the database "
              "still cannot take it", file=sys.stderr)
    try:
        record = run_unit(request)
    finally:
        logging.getLogger("imu_station.factory").removeHandler(handler)
        if progress is not None:
            progress.stop()
    pending = keep(record, url, request.files_root)
    if args.json:
        sys.stdout.write(json.dumps(record.to_dict(), indent=1, allow_nan=False) + "\n")
    else:
        print(summary(record))
    if pending is not None:
        if on_event is not None:
            on_event({"serial": record.serial, "event": "record_pending", "path": str(pending.path),
                      "reason": pending.reason})
        print(pending_line(record, pending, url, request.files_root), file=sys.stderr)
    return record.exit_code  # the unit's outcome, whether its record is stored or pending


def _speed(args: argparse.Namespace, plan: Any) -> float:
    if args.speed is not None:
        return float(args.speed)
    return plan.campaign.speed if plan.campaign is not None else 1.0


def resume_arguments(args: argparse.Namespace) -> Path | None:
    """With ``--resume``: the plan, serial and simulated seed from the run's journal where not given.

    Returns
    -------
    Path or None
        The run folder to resume.

    Raises
    ------
    StationError
        No resumable journal in the folder, or a --serial that is not the run's.
    """
    if args.resume is None:
        return None
    from station.factory.campaign import resume_folder

    begin = resume_folder(args.resume)
    if args.plan is None:
        args.plan = Path(begin.get("plan_file") or begin["plan"]["path"])
    if args.serial is not None and args.serial not in ("auto", begin["serial"]):
        raise StationError(f"--serial {args.serial}: the run in {args.resume} is unit {begin['serial']}")
    args.serial = begin["serial"]
    simulated = begin.get("simulate")
    if simulated is not None and not args.simulate:
        raise StationError(f"the run in {args.resume} was simulated: resume it with --simulate")
    if simulated is None and args.simulate:
        raise StationError(f"the run in {args.resume} ran on real instruments: resume it without --simulate")
    if simulated is not None:
        args.seed = int(simulated["seed"])
    return Path(args.resume)


class CampaignProgress:
    """A campaign's live line on the terminal (rich): step i/N, soak i/N, the unit's temperature; the log
    lines print above it."""

    def __init__(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.console = Console(stderr=True)
        self.progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TimeElapsedColumn(), console=self.console, redirect_stderr=False,
                                 redirect_stdout=False)
        self.task = self.progress.add_task("campaign", total=None)
        self.where = "starting"
        self.stream = _ConsoleStream(self.console)

    @classmethod
    def start(cls) -> CampaignProgress:
        """Show the line until :meth:`stop`."""
        progress = cls()
        progress.progress.start()
        return progress

    def update(self, event: dict[str, Any]) -> None:
        """Follow the run's events (``campaign``: a step begins; ``temperature``: a reading while waiting)."""
        if event.get("event") == "campaign":
            soak = f"soak {event['soak']}/{event['soaks']}" if event["soak"] else "end"
            self.where = f"{soak} {event['temp_c']:g} degC: {event['kind']}"
            self.progress.update(self.task, total=event["total"], completed=event["index"],
                                 description=self.where)
        elif event.get("event") == "temperature":
            slope = event.get("slope")
            text = f"{self.where} | unit {event['unit_c']:.2f} degC" + \
                ("" if slope is None else f" ({slope:+.2f} degC/min)")
            self.progress.update(self.task, description=text)
        elif event.get("event") in ("phase", "outcome"):
            self.progress.update(self.task, description=str(event.get("phase") or event.get("outcome")))

    def stop(self) -> None:
        """Leave the last line on the terminal."""
        self.progress.stop()


class _ConsoleStream:
    """A text stream that prints through the rich console (log lines above the live line)."""

    def __init__(self, console: Any):
        self.console = console

    def write(self, text: str) -> int:
        self.console.print(text, end="", markup=False, highlight=False, soft_wrap=True)
        return len(text)

    def flush(self) -> None:
        """Nothing kept back."""


def pending_line(record: RunRecord, pending: Pending, url: str, root: Path) -> str:
    """The one line that says a record is pending, where it is kept and how to store it."""
    kept, db, files = (printable(x, 1000) for x in (pending.path, url, root))
    return (f"imu-station run: record {record.run_id} ({record.outcome}, unit {printable(record.serial)}) "
            f"is PENDING, not in the database: {pending.reason}; it is kept in {kept}; "
            f"'imu-station records sync --db {db} --files {files}' stores it, as does the next run; the exit "
            "code is the unit's outcome")
