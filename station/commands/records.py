"""``imu-station records``: query the factory records by serial and date; export a unit's history;
``records report``: the fleet report; ``records sync``: store the records runs kept pending.

Everything shown from a record (serial, station, plan, reason, measurement names) is data: it
reaches the terminal as ``rich.text.Text`` of :func:`~station.common.text.printable` text, never
inside a markup string, so ``[link=...]`` or an escape sequence in a record shows as typed."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from station.common.files import atomic_write_text
from station.common.text import PATH_CHARS, printable
from station.console.options import RECORD_OUTCOMES, add_db_arguments, add_output_option, db_url, files_root
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

    from station.factory.records import RunRecord

NAME = "records"
HELP = ("list factory run records by serial and date, export a unit's history as JSON, verify files, "
        "store pending records")
DESCRIPTION = """\
List the records of 'imu-station run' / 'run-many' from the record database (SQLite or PostgreSQL),
oldest first, filtered by unit serial, station, outcome and start date (UTC). --json prints the
full records (phases, measurements with limits and units, attachments with SHA-256); --export FILE
writes them as one JSON document (schema imu-station/records-export/1), e.g. a unit's history
with --serial. --plot draws each measurement across the records against its limits (PNG).
--verify re-hashes every attachment and reports missing or altered files.

'records report -o fleet.html' writes the fleet report of the records the filters select: per
measurement with limits n, mean, standard deviation (n-1), Cpk against the plan's limits (one-sided
for one limit), a histogram against the limits and the individuals control chart in time order
with its moving-range control limits (points beyond flagged); per station and per day; the outlier
units with links to their certificates. --json prints its statistics instead of the record list;
--pdf prints the page with headless Chromium.

'records sync' stores the records that runs kept pending because the database would not take them
(locked, read-only, unreachable): FILES/pending-records/*.json, FILES being --files or the folder
beside the SQLite database, as for 'imu-station run'.

Reading never takes a write lock. A database locked by another process is waited for 5 s
($IMU_STATION_DB_WAIT sets the wait), then reported in one line. A row whose record is not one
this station wrote (not JSON, a field missing or of another type) is refused in one line naming
its run on stderr, and the other records are read."""
EPILOG = """\
exit codes: 0 done; 1 --verify found a missing or altered file, or a row that is not a record;
4 bad option, a database that is missing, damaged, of another layout or locked past the wait,
'report' with no record selected, or 'sync' with a database that still does not take the records or
a pending file that is not a record.

examples:
  imu-station records --serial A1234
  imu-station records --since 2026-11-01 --until 2026-11-22 --outcome FAIL
  imu-station records --serial A1234 --export A1234-history.json --verify
  imu-station records --since 2026-11-01 --plot trend.png --measurement gyro.bias.z
  imu-station records --db postgresql://line@db/imu --station line-a-3 --json
  imu-station records report --since 2026-11-01 -o fleet.html --pdf fleet.pdf
  imu-station records report --station line-a-3 --json
  imu-station records sync --db line.sqlite"""

EXPORT_SCHEMA = "imu-station/records-export/1"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the records command's options to ``parser``."""
    parser.add_argument("action", nargs="?", choices=["report", "sync"], metavar="ACTION",
                        help="report: the fleet report of the selected records (-o FILE.html and/or --json); "
                             "sync: store the records runs kept pending")
    add_db_arguments(parser)
    parser.add_argument("--files", type=Path, default=None, metavar="DIR",
                        help="the runs' files folder, as for 'run' (default: beside a SQLite database as "
                             "<name>-files/): sync reads DIR/pending-records; --verify reads attachments "
                             "inside DIR alone")
    parser.add_argument("--serial", metavar="SN", help="only this unit")
    parser.add_argument("--station", metavar="ID", help="only this station")
    parser.add_argument("--outcome", type=str.upper, choices=RECORD_OUTCOMES, help="only this outcome")
    parser.add_argument("--since", metavar="DATE", help="started on or after (2026-11-22 or ISO date-time)")
    parser.add_argument("--until", metavar="DATE",
                        help="started on or before (a date includes the whole day)")
    parser.add_argument("--json", action="store_true", help="print the full records as JSON on stdout")
    parser.add_argument("--export", type=Path, metavar="FILE.json", help="write the records as one JSON file")
    parser.add_argument("--plot", type=Path, metavar="FILE.png",
                        help="PNG of the measurements across the records, with their limits")
    parser.add_argument("--measurement", action="append", default=None, metavar="NAME",
                        help="--plot: this measurement (repeat; default: every one with limits, up to 12)")
    parser.add_argument("--verify", action="store_true",
                        help="check every attachment against its SHA-256 (exit 1 when one differs)")
    add_output_option(parser, metavar="FILE.html", help="report: the fleet report's HTML page")
    parser.add_argument("--pdf", type=Path, metavar="FILE.pdf",
                        help="report: also print the page to PDF (headless Chromium)")


def _table(records: list[RunRecord]) -> Table:
    from rich.table import Table
    from rich.text import Text

    table = Table(title=Text(f"{len(records)} record(s)"))
    for column in ("start (UTC)", "serial", "station", "plan", "outcome", "failed", "run id"):
        table.add_column(column)
    for r in records:
        failed = [m.name for m in r.measurements().values() if m.outcome == "FAIL"]
        detail = ", ".join(failed[:3]) + (" ..." if len(failed) > 3 else "") or r.reason
        # Every cell is data: Text objects, never markup, each one line of printable text.
        cells = (r.start[:19].replace("T", " "), r.serial, r.station, r.plan.get("name", ""), r.outcome,
                 detail, r.run_id[:8])
        table.add_row(*(Text(printable(c, 40 if c is detail else 120)) for c in cells))
    return table


def _say(console: Console, text: str) -> None:
    """Print one line of plain text (a path, a count), never read as markup."""
    from rich.text import Text

    console.print(Text(printable(text, 2000)), highlight=False)


def _refused(lines: list[str]) -> None:
    for line in lines:
        print(f"imu-station records: {printable(line, 2000)}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    """Query, print, export, plot and verify the records; exit 1 when --verify finds a problem."""
    from rich.console import Console

    # the record store (sqlite3, uuid, hashlib) loads when a command runs, not for --help
    from station.factory.records import RecordStore, utc_now
    from station.plots.trend import left_out, write_trend_plot

    url = db_url(args)
    if "://" not in url and not Path(url).exists():
        raise StationError(f"--db {printable(url, 1000)}: no such record database; give the file "
                           "'imu-station run' wrote (or set IMU_STATION_DB)")
    if args.action == "report":
        return _report(args, url)
    if args.action == "sync":
        return _sync(args, url)
    for option in ("output", "pdf"):
        if getattr(args, option) is not None:
            raise StationError(f"--{option} belongs to 'imu-station records report'")
    refused: list[str] = []
    with RecordStore.open(url, readonly=True) as store:
        records = store.query(args.serial, args.since, args.until, args.station, args.outcome, refused)
    _refused(refused)
    problems: list[str] = []
    if args.verify:
        root = args.files.resolve() if args.files is not None else None
        for r in records:
            problems += [f"{printable(r.serial)} {printable(r.run_id[:8])}: {p}" for p in r.verify(root)]
    if args.export:
        doc = {"schema": EXPORT_SCHEMA, "exported": utc_now(), "query": {
            k: getattr(args, k) for k in ("serial", "station", "outcome", "since", "until")},
            "records": [r.to_dict() for r in records]}
        atomic_write_text(args.export, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    plotted: list[str] = []
    if args.plot:
        if not records:
            raise StationError("--plot: no record matches; nothing to plot")
        plotted = write_trend_plot(args.plot, records, args.measurement)
    if args.json:
        sys.stdout.write(json.dumps([r.to_dict() for r in records], indent=1, allow_nan=False) + "\n")
    else:
        console = Console(file=sys.stdout, width=160)
        console.print(_table(records))
        if args.export:
            _say(console, f"{args.export}: {len(records)} record(s) written")
        if args.plot:
            _say(console, f"{args.plot}: {len(plotted)} measurement(s) plotted")
            skipped = left_out(records, args.measurement)
            if skipped:
                shown = "; ".join(f"{printable(name)} ({why})" for name, why in skipped.items())
                _say(console, f"left out: {shown} (--measurement NAME plots one by name)")
        if args.verify:
            _say(console, f"verified {sum(len(r.attachments()) for r in records)} attachment(s): "
                 + ("all intact" if not problems else f"{len(problems)} problem(s)"))
    for p in problems:
        print(f"imu-station records: {printable(p, 2000)}", file=sys.stderr)
    return ExitCode.OUT_OF_LIMITS if problems or (refused and args.verify) else ExitCode.OK


def _sync(args: argparse.Namespace, url: str) -> int:
    """Store the records kept pending in the files folder; exit 4 when one is not a record."""
    from station.factory.records import RecordStore
    from station.factory.spool import pending_dir, pending_files, sync

    for option in ("serial", "station", "outcome", "since", "until", "export", "plot", "output", "pdf"):
        if getattr(args, option) is not None:
            raise StationError(f"--{option} is not an option of 'records sync': it stores every pending "
                               "record")
    if args.json or args.verify:
        raise StationError("--json and --verify are not options of 'records sync'")
    root = files_root(args, url)
    folder = printable(pending_dir(root), 1000)
    if not pending_files(root):
        print(f"{folder}: no pending record")
        return ExitCode.OK
    with RecordStore.open(url) as store:
        done = sync(store, root)
    _refused(done.refused)
    print(f"{folder}: {len(done.stored)} pending record(s) stored in {printable(store.shown, 1000)}"
          + (f"; {len(done.refused)} refused" if done.refused else ""))
    return ExitCode.USAGE if done.refused else ExitCode.OK


def _report(args: argparse.Namespace, url: str) -> int:
    """The fleet report: the page (-o), its PDF (--pdf) and the statistics (--json)."""
    from station.factory.records import RecordStore
    from station.report.attachments import CERTIFICATE_NAME
    from station.report.fleet import collect, fleet_json, render_fleet

    if args.output is None and not args.json:
        raise StationError("records report: give -o FILE.html for the page, or --json for the statistics")
    if args.pdf is not None and args.output is None:
        raise StationError("--pdf prints the page: give -o FILE.html too")
    for option in ("export", "plot", "verify", "files"):
        if getattr(args, option):
            raise StationError(f"--{option} is not an option of 'records report'")
    query = {k: getattr(args, k) for k in ("serial", "since", "until", "station", "outcome")}
    refused: list[str] = []
    with RecordStore.open(url, readonly=True) as store:
        store.refused = refused
        fleet = collect(store, query)
        certificates = store.attachment_paths(CERTIFICATE_NAME, **query) if args.output else {}
    _refused(refused)
    if args.output is not None:
        from station.report.pdf import write_with_pdf

        page = render_fleet(fleet, certificates, Path(args.output).resolve().parent)
        write_with_pdf(args.output, args.pdf, lambda: atomic_write_text(args.output, page))
    said = sys.stderr if args.json else sys.stdout
    if args.output is not None:
        print(f"{printable(args.output, PATH_CHARS)}: fleet report of {len(fleet.runs)} record(s), "
              f"{len(fleet.limited)} measurement(s) with limits", file=said)
    if args.pdf is not None:
        print(f"{printable(args.pdf, PATH_CHARS)}: PDF printed", file=said)
    if args.json:
        sys.stdout.write(json.dumps(fleet_json(fleet), indent=1, allow_nan=False) + "\n")
    return ExitCode.OK
