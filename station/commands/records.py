"""``imu-station records``: query the factory records by serial and date; export a unit's history;
``records report``: the fleet report."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from station.common.files import atomic_write_text
from station.common.text import printable
from station.console.options import RECORD_OUTCOMES, add_db_arguments, add_output_option, db_url
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from rich.table import Table

    from station.factory.records import RunRecord

NAME = "records"
HELP = "list factory run records by serial and date, export a unit's history as JSON, verify files"
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
--pdf prints the page with headless Chromium."""
EPILOG = """\
exit codes: 0 done; 1 --verify found a missing or altered file; 4 bad option or database, or
'report' with no record selected.

examples:
  imu-station records --serial A1234
  imu-station records --since 2026-11-01 --until 2026-11-22 --outcome FAIL
  imu-station records --serial A1234 --export A1234-history.json --verify
  imu-station records --since 2026-11-01 --plot trend.png --measurement gyro.bias.z
  imu-station records --db postgresql://line@db/imu --station line-a-3 --json
  imu-station records report --since 2026-11-01 -o fleet.html --pdf fleet.pdf
  imu-station records report --station line-a-3 --json"""

EXPORT_SCHEMA = "imu-station/records-export/1"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the records command's options to ``parser``."""
    parser.add_argument("action", nargs="?", choices=["report"], metavar="report",
                        help="report: the fleet report of the selected records (-o FILE.html and/or --json)")
    add_db_arguments(parser)
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

    table = Table(title=f"{len(records)} record(s)")
    for column in ("start (UTC)", "serial", "station", "plan", "outcome", "failed", "run id"):
        table.add_column(column)
    for r in records:
        failed = [m.name for m in r.measurements().values() if m.outcome == "FAIL"]
        table.add_row(r.start[:19].replace("T", " "), Text(printable(r.serial)), r.station,
                      r.plan.get("name", ""), r.outcome,
                      ", ".join(failed[:3]) + (" ..." if len(failed) > 3 else "") or r.reason[:40],
                      r.run_id[:8])
    return table


def run(args: argparse.Namespace) -> int:
    """Query, print, export, plot and verify the records; exit 1 when --verify finds a problem."""
    from rich.console import Console

    # the record store (sqlite3, uuid, hashlib) loads when a command runs, not for --help
    from station.factory.records import RecordStore, utc_now
    from station.plots.trend import left_out, write_trend_plot

    url = db_url(args)
    if "://" not in url and not Path(url).exists():
        raise StationError(f"--db {url}: no such record database; give the file 'imu-station run' wrote "
                           "(or set IMU_STATION_DB)")
    if args.action == "report":
        return _report(args, url)
    for option in ("output", "pdf"):
        if getattr(args, option) is not None:
            raise StationError(f"--{option} belongs to 'imu-station records report'")
    with RecordStore.open(url) as store:
        records = store.query(args.serial, args.since, args.until, args.station, args.outcome)
    problems: list[str] = []
    if args.verify:
        for r in records:
            problems += [f"{r.serial} {r.run_id[:8]}: {p}" for p in r.verify()]
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
            console.print(f"{args.export}: {len(records)} record(s) written")
        if args.plot:
            console.print(f"{args.plot}: {len(plotted)} measurement(s) plotted")
            skipped = left_out(records, args.measurement)
            if skipped:
                shown = "; ".join(f"{printable(name)} ({why})" for name, why in skipped.items())
                console.print(f"left out: {shown} (--measurement NAME plots one by name)", highlight=False)
        if args.verify:
            console.print(f"verified {sum(len(r.attachments()) for r in records)} attachment(s): "
                          + ("all intact" if not problems else f"{len(problems)} problem(s)"))
    for p in problems:
        print(f"imu-station records: {p}", file=sys.stderr)
    return ExitCode.OUT_OF_LIMITS if problems else ExitCode.OK


def _report(args: argparse.Namespace, url: str) -> int:
    """The fleet report: the page (-o), its PDF (--pdf) and the statistics (--json)."""
    from station.factory.records import RecordStore
    from station.report.attachments import CERTIFICATE_NAME
    from station.report.fleet import collect, fleet_json, render_fleet

    if args.output is None and not args.json:
        raise StationError("records report: give -o FILE.html for the page, or --json for the statistics")
    if args.pdf is not None and args.output is None:
        raise StationError("--pdf prints the page: give -o FILE.html too")
    for option in ("export", "plot", "verify"):
        if getattr(args, option):
            raise StationError(f"--{option} is not an option of 'records report'")
    query = {k: getattr(args, k) for k in ("serial", "since", "until", "station", "outcome")}
    with RecordStore.open(url) as store:
        fleet = collect(store, query)
        certificates = store.attachment_paths(CERTIFICATE_NAME, **query) if args.output else {}
    if args.output is not None:
        atomic_write_text(args.output, render_fleet(fleet, certificates, Path(args.output).resolve().parent))
        print(f"{args.output}: fleet report of {len(fleet.runs)} record(s), {len(fleet.limited)} "
              "measurement(s) with limits", file=sys.stderr if args.json else sys.stdout)
    if args.pdf is not None:
        from station.report.pdf import html_to_pdf

        html_to_pdf(args.output, args.pdf)
        print(f"{args.pdf}: PDF printed", file=sys.stderr if args.json else sys.stdout)
    if args.json:
        sys.stdout.write(json.dumps(fleet_json(fleet), indent=1, allow_nan=False) + "\n")
    return ExitCode.OK
