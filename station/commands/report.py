"""``imu-station report``: a unit's calibration certificate, HTML (self-contained) and PDF."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from station.console.options import add_db_arguments, add_instance_option, add_output_option, db_url
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from station.report.certificate import Certificate

NAME = "report"
HELP = "a unit's calibration certificate: one self-contained HTML page (and PDF) from PARAMS or a record"
DESCRIPTION = """\
Write a unit's calibration certificate: the unit (serial, model, firmware), the station and its
version, the date, the operator or station id, the method and sequence, the SHA-256 of the data,
every parameter with its 1-sigma uncertainty in mg, deg/h, ppm and deg, each measurement against
its limit (PASS/FAIL), and the plots: residuals per pose, Allan deviation with the fitted noise
lines and their band, bias against temperature with the model, the magnetometer's corrected sphere,
each where the parameter file has the section (what it lacks is said on the page).

From a parameter file: PARAMS [--capture FILE ...] [--plan PLAN.yaml]. A capture whose SHA-256
the file's 'sources' names is used for that section's plot (the labelled calibration capture for
the residuals, the still one for the measured Allan curve, the temperature sweep for the bias
against temperature, the magnetometer's for its sphere); --plan judges the calibration against the
plan's limits. Progress goes to stderr, with what the certificate does not show.
From the factory records: --db DB --serial SN [--run ID] (the unit's latest run by default): the
record's measurements with its plan's limits, its parameter file and raw capture.

The HTML has no network resource (styles inline, plots inline SVG) and prints well; --pdf prints it
with headless Chromium (Debian: apt-get install chromium)."""
EPILOG = """\
exit codes: 0 written; 4 bad input (unknown serial, unreadable file) or no Chromium for --pdf.

environment: IMU_STATION_DB (default --db), IMU_STATION_ID (default --station),
IMU_STATION_CHROMIUM (the browser --pdf uses; default chromium on the PATH)

examples:
  imu-station report unit.yaml --capture six-pose.csv --capture still.csv -o unit.html --pdf unit.pdf
  imu-station report unit.yaml --plan plan.yaml --operator "J. Smith" -o unit.html
  imu-station report --db records.sqlite --serial A1234 -o A1234.html --pdf A1234.pdf"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the report command's options to ``parser``."""
    parser.add_argument("params", nargs="?", type=Path, metavar="PARAMS",
                        help="the unit's parameter file (or give --serial to certify a factory record)")
    add_output_option(parser, required=True, metavar="FILE.html", help="the certificate's HTML page")
    parser.add_argument("--pdf", type=Path, metavar="FILE.pdf",
                        help="also print it to PDF (headless Chromium)")
    parser.add_argument("--capture", action="append", default=[], type=Path, metavar="FILE",
                        help="a capture the parameter file was computed from (repeat), for the plots; a PX4 "
                             "(.ulg) or ArduPilot (.bin) log's IMU is chosen with --instance")
    add_instance_option(parser)
    parser.add_argument("--plan", type=Path, metavar="PLAN.yaml",
                        help="judge the parameter file against this factory plan's limits")
    add_db_arguments(parser)
    parser.add_argument("--serial", metavar="SN", help="certify this unit's factory record (from --db)")
    parser.add_argument("--run", metavar="ID",
                        help="with --serial: this run (its id or a prefix; default the latest)")
    parser.add_argument("--station", metavar="ID",
                        help="station id on the certificate (default $IMU_STATION_ID, or the record's)")
    parser.add_argument("--operator", metavar="NAME", help="who calibrated the unit")


def _stage(text: str) -> None:
    """A progress line on stderr: what long step starts (reading captures, an Allan curve, printing);
    it names files and a unit's serial, shown escaped."""
    from station.common.text import printable

    print(f"imu-station report: {printable(text, max_chars=400)} ...", file=sys.stderr, flush=True)


def _from_params(args: argparse.Namespace) -> Certificate:
    from station.acquisition.autopilot_log import is_autopilot_log, log_notes
    from station.acquisition.capture import read_capture
    from station.common.files import sha256_file
    from station.console.log_notes import print_log_notes
    from station.engines.calibration.common import CalibrationReport
    from station.export.params.file import ParamsFile
    from station.factory.measure import measure
    from station.factory.plan import load_plan
    from station.factory.run import CALIBRATION_QUANTITIES
    from station.report.certificate import Certificate, capture_file

    params = ParamsFile.load(args.params)
    captures = []
    for path in args.capture:
        _stage(f"reading {path}")
        capture = read_capture(path, args.instance if is_autopilot_log(path) else None)
        print_log_notes(path, log_notes(capture))
        captures.append(capture_file(path, capture))
    measurements, plan = [], {}
    if args.plan is not None:
        loaded = load_plan(args.plan)
        report = CalibrationReport(params.accel, params.gyro, method="", gravity=float("nan"))
        measurements = measure(loaded, CALIBRATION_QUANTITIES, report, {})
        plan = {"name": loaded.name, "path": str(loaded.path), "sha256": loaded.sha256,
                "sequence": loaded.sequence.name,
                "instruments": loaded.instruments.urls() if loaded.instruments is not None else {}}
    return Certificate(params, str(args.params), sha256_file(args.params), measurements=measurements,
                       captures=captures, plan=plan)


def _from_record(args: argparse.Namespace) -> Certificate:
    from station.acquisition.capture import read_capture
    from station.factory.records import RecordStore
    from station.report.certificate import CaptureFile, from_record

    url = db_url(args)
    if "://" not in url and not Path(url).exists():
        raise StationError(f"--db {url}: no such record database; give the file 'imu-station run' wrote "
                           "(or set IMU_STATION_DB)")
    with RecordStore.open(url, readonly=True) as store:
        records = store.query(serial=args.serial)
    if not records:
        raise StationError(f"--serial {args.serial}: no record of this unit in {url}; "
                           "'imu-station records' lists the units recorded")
    if args.run:
        records = [r for r in records if r.run_id.startswith(args.run)]
        if len(records) != 1:
            raise StationError(f"--run {args.run}: {'no' if not records else len(records)} run(s) of unit "
                               f"{args.serial} start with it; 'imu-station records --serial {args.serial}' "
                               "lists them")
    record = records[-1]
    captures = []
    for a in record.attachments():
        path = record.attachment_file(a)  # None: out of the record's folder, or not a regular file
        if a.mimetype == "text/csv" and path is not None and path.is_file():
            try:
                captures.append(CaptureFile(str(path), a.sha256, read_capture(path)))
            except StationError:
                continue  # from_record names the attachment as altered or unreadable
    return from_record(record, captures)


def run(args: argparse.Namespace) -> int:
    """Write the certificate (and its PDF) as one set of files; exit 0, or 4 for bad input."""
    from station.common.text import printable
    from station.report.certificate import write_certificate
    from station.report.pdf import write_with_pdf

    if (args.params is None) == (args.serial is None):
        raise StationError("give the parameter file PARAMS, or --serial SN to certify a factory record "
                           "(not both)")
    if args.serial is None and args.run is not None:
        raise StationError("--run needs --serial")
    cert = _from_params(args) if args.params is not None else _from_record(args)
    cert.station = args.station or os.environ.get("IMU_STATION_ID") or cert.station
    cert.operator = args.operator or ""
    cert.on_stage = _stage
    notes = write_with_pdf(args.output, args.pdf, lambda: write_certificate(cert, args.output),
                           on_print=lambda: _stage(f"printing {args.pdf} with headless Chromium"))
    if cert.record is not None:
        serial = cert.record.serial
    else:
        serial = cert.params.device.get("serial", "?") if cert.params is not None else "?"
    print(f"{printable(args.output, 400)}: calibration certificate of unit {printable(serial)}")
    for note in notes:
        print(f"imu-station report: note: {printable(note, 400)}", file=sys.stderr)
    if args.pdf is not None:
        print(f"{printable(args.pdf, 400)}: PDF printed")
    return ExitCode.OK
