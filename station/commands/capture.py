"""``imu-station capture``: record a unit's samples into a capture CSV or an HDF5 capture file."""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path
from typing import IO, TYPE_CHECKING

from station.common.text import PATH_CHARS, printable, printable_message
from station.console.options import DEFAULT_BAUDRATE, DURATION_S, add_output_option, add_port_options, number
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from protocols.detect import Detection
    from station.acquisition.recorder import CaptureResult

NAME = "capture"
HELP = "record samples from a unit (serial port, pty or sim://) into a CSV or HDF5 capture file"
DESCRIPTION = """\
Record the samples a unit streams into a capture file: the capture CSV (t is the device clock in
seconds) or, when FILE ends in .h5 or .hdf5, the station's HDF5 capture file (with the unit's info
and the link statistics). It runs until --duration seconds of device clock, Ctrl-C, or the link
breaks; in every case the file keeps every sample received. A status line on stderr shows the
rate, samples, damaged frames and lost samples.

With several --port, every unit is recorded at once, by one process, into its own file in the
directory -o names: SERIAL.csv (or SERIAL.h5 with --format h5), with the serial the unit reports
(a unit that does not say it is named after its port; a serial two ports report names the
second file SERIAL-2). One status line per unit. A unit that fails (vanishes, is silent, sends
no frames) is reported and the others go on.

A board of several IMUs (MAVLink SCALED_IMU, SCALED_IMU2, SCALED_IMU3 or the id of HIGHRES_IMU and
RAW_IMU; a frame description whose fields give imu: k): --instances all (or 0,1,2) records each
instance into a file of its own, FILE for instance 0 and FILE's name with .imu<k> before its suffix
for instance k (cap.csv, cap.imu1.csv, cap.imu2.csv), with the board's clock, the same step labels
and an "instance: k" metadata line. Without it, one instance is recorded as before (instance 0 for
a frame description; for MAVLink the first IMU message seen), and a note names the others.

exit codes: 0 done, 3 device or link error (after saving what was received; with several ports,
any unit's), 4 usage, or a frame description whose checksum most frames fail (after saving; the
message names the checksum that fits), 130 interrupted by Ctrl-C (after saving)."""
EPILOG = """\
examples:
  imu-station capture --port /dev/ttyUSB0 --duration 60 -o still.csv
  imu-station capture --port sim:// --rate 400 --duration 10 -o sim.h5
  imu-station capture --port /dev/ttyUSB0 --protocol auto --baud 115200 --duration 60 -o mti.csv
  imu-station capture --port /dev/ttyUSB0 --protocol xsens --field 49.8 --duration 120 -o mti-mag.h5
  imu-station capture --port /dev/ttyACM0 --protocol ascii \\
      --columns t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps --duration 30 -o arduino.csv
  imu-station capture --port /dev/ttyUSB0 --port /dev/ttyUSB1 --port /dev/ttyUSB2 --duration 60 -o tray/
  imu-station capture --port /dev/ttyACM0 --protocol mavlink --instances all --duration 60 -o board.csv"""


# SET_RATE carries the rate as an unsigned 16-bit number of Hz (specs/native-protocol.md).
RATE_HZ = number(int, 1, 0xFFFF, unit="Hz")
# The local field --field accepts: the Earth's is 22 to 67 uT; a lab's coil more.
FIELD_UT = number(float, 1.0, 1000.0, unit="uT")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the capture command's options to ``parser``."""
    add_port_options(parser, required=True, repeat=True,
                     port_help="serial device path (/dev/ttyUSB0, a pty), or pyserial URL (sim://, loop://); "
                               "repeat it to record several units at once (device paths and ptys only)")
    parser.add_argument("--columns", metavar="SPEC",
                        help="with --protocol ascii: CSV columns and units, e.g. t:ms,ax:g,ay:g,az:g,gx:dps,"
                             "gy:dps,gz:dps (default: t,ax,ay,az,gx,gy,gz,temp in s, m/s^2, rad/s, degC)")
    parser.add_argument("--duration", type=DURATION_S, metavar="S",
                        help="seconds of device clock to record (default: until Ctrl-C)")
    parser.add_argument("--rate", type=RATE_HZ, metavar="HZ",
                        help="set the unit's output rate first (SET_RATE, 1..65535 Hz); with text lines that "
                             "carry no clock (MotionCal, VectorNav), the rate they come at (default: 100)")
    add_output_option(parser, required=True, metavar="FILE",
                      help="capture file to write: .csv, or .h5/.hdf5 for the HDF5 capture file; with "
                           "several --port, the directory the units' files go in")
    parser.add_argument("--field", type=FIELD_UT, metavar="UT",
                        help="with an Xsens unit: the local magnetic field's magnitude, which scales its "
                             "normalised MagneticField to microtesla (default: the field is not recorded)")
    parser.add_argument("--instances", type=_instances_option, metavar="all|K,K",
                        help="a board of several IMUs (mavlink, or a frame description with imu: on fields): "
                             "record these IMU instances (all, or e.g. 0,1,2; 0..255), each into its own "
                             "file: FILE for instance 0, NAME.imu<k>.SUFFIX for instance k (default: one "
                             "instance, as from a board of one)")
    parser.add_argument("--format", choices=("csv", "h5"), default=None,
                        help="with several --port: the files' format, SERIAL.csv or SERIAL.h5 (default: csv)")


def _instances_option(text: str) -> str:
    """``--instances``: checked here (``all`` or instances 0..255), parsed again where it is used."""
    from station.acquisition.instance_capture import parse_instances

    try:
        parse_instances(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def report(result: CaptureResult, out: IO[str]) -> None:
    """The summary printed after a capture: where the samples went and how the link fared.

    Parameters
    ----------
    result : CaptureResult
        What the capture wrote and how the link fared.
    out : text stream
        Where the summary is printed.
    """
    link = result.link
    if result.rows or Path(result.path).exists():
        print(f"wrote {result.rows} samples ({result.device_time_s:.3f} s of device clock) to "
              f"{printable(result.path, PATH_CHARS)}", file=out)
    else:
        print(f"captured no sample: {printable(result.path, PATH_CHARS)} was not written", file=out)
    print(f"link: {link.summary()}, {link.bytes} bytes", file=out)
    if result.non_increasing:
        print(f"left out {result.non_increasing} samples whose device time did not increase", file=out)
    if result.field_dropped:
        print(f"the magnetic field came after the first rows and {printable(result.path, PATH_CHARS)} could "
              f"not be rewritten with mx, my, mz (the disk?): the field of {result.field_dropped} samples is "
              "not in the file; capture to .h5 to keep it", file=out)
    for jump in result.clock_jumps:
        why = ("(a unit restart?); the rows after it are re-based to follow on" if jump.step_s < 0
               else "(a clock set anew, or samples lost that seq does not show?)")
        print(f"clock jump: {jump.describe()} {why}", file=out)


def sniff_protocol(port: str, baudrate: int = DEFAULT_BAUDRATE, timeout_s: float = 3.0) -> Detection:
    """Read the first bytes at ``port`` until a protocol is recognised, or for ``timeout_s``.

    Parameters
    ----------
    port : str
        Device path or pyserial URL.
    baudrate : int
        Line speed of a real serial port.
    timeout_s : float
        How long to read before giving up.

    Returns
    -------
    Detection
        The protocol found (None when none was), with the explanation shown to the user.
    """
    from serial import SerialException

    from drivers.serial_device import open_serial
    from protocols.detect import ENOUGH_BYTES, detect

    data = bytearray()
    found = detect(b"")
    deadline = time.monotonic() + timeout_s
    failure = ""
    with open_serial(port, baudrate) as ser:
        while time.monotonic() < deadline and len(data) < 16 * ENOUGH_BYTES:
            tried = len(data)
            try:
                while len(data) < tried + max(64, tried // 4) and time.monotonic() < deadline:
                    data += ser.read(max(1, ser.in_waiting))
            except (SerialException, OSError) as exc:
                failure = f"; then the port failed ({exc})"
                deadline = 0.0
            found = detect(bytes(data))
            if found.protocol is not None:
                return found
    if not data:
        found.explanation = (f"the unit sent nothing in {timeout_s:g} s: check that it is powered and "
                             f"streaming, and the baud rate")
    found.explanation += failure
    return found


def resolve_protocol(port: str, protocol: str, baudrate: int, columns: str | None, err: IO[str],
                     rate_hz: int | None = None, field_ut: float | None = None) -> str:
    """The decoder name for ``--protocol`` and ``--columns``; ``auto`` sniffs the port and says what
    it found.

    Parameters
    ----------
    port : str
        The unit's port, read when ``protocol`` is ``auto``.
    protocol : str
        ``--protocol`` as given (validated by the option).
    baudrate : int
        Line speed of a real serial port.
    columns : str, optional
        ``--columns``, for ``ascii`` only.
    err : text stream
        Where what ``auto`` found is said.
    rate_hz : int, optional
        ``--rate``: with ``ascii``, the rate of lines that carry no clock.
    field_ut : float, optional
        ``--field``: with ``xsens``, the local field that scales its normalised MagneticField to uT.

    Returns
    -------
    str
        The decoder name with its option (``ascii:COLUMNS@HZ``, ``xsens:field=UT``).

    Raises
    ------
    StationError
        ``--columns`` without ``ascii`` or unreadable, ``--field`` without ``xsens``, or MAVLink
        without pymavlink.
    NoSamples
        ``auto`` recognised no protocol.
    """
    from drivers import NoSamples
    from protocols.ascii_lines import parse_columns
    from protocols.mavlink import pymavlink_available

    if columns is not None:
        if protocol != "ascii":
            raise StationError(f"--columns applies to --protocol ascii, not {protocol}")
        try:
            parse_columns(columns)
        except ValueError as exc:
            raise StationError(f"--columns: {exc}") from None
    if protocol.partition(":")[0] == "mavlink" and not pymavlink_available():
        raise StationError("--protocol mavlink needs pymavlink: pip install 'imu-station[mavlink]'")
    if protocol == "auto":
        found = sniff_protocol(port, baudrate)
        if found.protocol is None:
            raise NoSamples(f"{port}: {found.explanation}", port)
        print(f"protocol: {found.protocol}: {printable_message(found.explanation)}", file=err)
        protocol = found.protocol
    if protocol == "ascii" and (columns is not None or rate_hz is not None):
        protocol = f"ascii:{columns or ''}" + (f"@{rate_hz}" if rate_hz is not None else "")
    base, _, option = protocol.partition(":")
    if field_ut is not None:
        if base != "xsens":
            raise StationError(f"--field scales the normalised magnetic field of an Xsens unit; {protocol} "
                               f"reports it in physical units, or not at all: leave --field out")
        protocol = f"xsens:{option + ',' if option else ''}field={field_ut:g}"
    elif base == "xsens":
        print("note: an Xsens unit reports its magnetic field normalised to the field where it was last "
              "calibrated; it is recorded only with --field UT (the local field's magnitude)", file=err)
    return protocol


def run(args: argparse.Namespace) -> int:
    """Capture, print the summary, and exit with the capture's outcome."""
    from station.acquisition.port_capture import capture_to_file
    from station.console.status_line import CaptureStatusLine

    if len(args.port) > 1:
        if args.instances is not None:
            raise StationError("--instances records the IMUs of one board: give one --port")
        return run_many(args)
    if args.instances is not None:
        return run_instances(args)
    if args.format is not None:
        raise StationError("--format applies to several --port; with one, the suffix of -o FILE decides "
                           "(.csv, or .h5/.hdf5)")
    args.port = args.port[0]
    protocol = resolve_protocol(args.port, args.protocol, args.baud, args.columns, sys.stderr, args.rate,
                                args.field)
    result = capture_to_file(args.port, args.output, protocol=protocol, duration_s=args.duration,
                             rate_hz=args.rate, baudrate=args.baud,
                             status=lambda duration_s: CaptureStatusLine(sys.stderr, duration_s))
    report(result, sys.stdout)
    if result.error is not None:
        print(f"imu-station capture: error: {printable_message(result.error)}", file=sys.stderr)
        return result.error.exit_code
    if result.ended_by == "interrupted":
        print("imu-station capture: interrupted; the file keeps every sample received", file=sys.stderr)
        return ExitCode.INTERRUPTED
    return ExitCode.OK


def run_instances(args: argparse.Namespace) -> int:
    """Capture the ``--instances`` of one board, one file each, print one summary per file, and exit with
    the capture's outcome."""
    from station.acquisition.instance_capture import capture_instances_to_file, parse_instances
    from station.console.status_line import CaptureStatusLine

    if args.format is not None:
        raise StationError("--format applies to several --port; with --instances, the suffix of -o FILE "
                           "decides (.csv, or .h5/.hdf5)")
    port = args.port[0]
    protocol = resolve_protocol(port, args.protocol, args.baud, args.columns, sys.stderr, args.rate,
                                args.field)
    wanted = parse_instances(args.instances)
    result = capture_instances_to_file(port, args.output, wanted, protocol=protocol, duration_s=args.duration,
                                       rate_hz=args.rate, baudrate=args.baud,
                                       status=lambda duration_s: CaptureStatusLine(sys.stderr, duration_s))
    for instance, capture in result.captures.items():
        summary = io.StringIO()
        report(capture, summary)
        # the link is the board's, one for all its instances: said once below
        lines = [line for line in summary.getvalue().splitlines() if not line.startswith("link: ")]
        print(f"IMU instance {instance}: " + "\n".join(lines), file=sys.stdout)
    if result.captures:
        print(f"link: {result.link.summary()}, {result.link.bytes} bytes", file=sys.stdout)
    if result.missing:
        seen = ", ".join(map(str, result.seen)) or "none"
        print(f"no file for IMU instance(s) {', '.join(map(str, result.missing))}: the board did not send "
              f"them (it streams {seen})", file=sys.stdout)
    if result.error is not None:
        print(f"imu-station capture: error: {printable_message(result.error)}", file=sys.stderr)
        return result.error.exit_code
    if result.ended_by == "interrupted":
        print("imu-station capture: interrupted; the files keep every sample received", file=sys.stderr)
        return ExitCode.INTERRUPTED
    return ExitCode.OK


def run_many(args: argparse.Namespace) -> int:
    """Capture every ``--port`` at once into the directory ``-o``, print one summary line per unit,
    and exit with the worst outcome."""
    from station.acquisition.multi_capture import capture_many
    from station.console.multi_status import UnitStatusLines

    if args.protocol == "auto":
        raise StationError("--protocol auto reads one port; with several, name the protocol (native, ...)")
    if args.output.exists() and not args.output.is_dir():
        raise StationError(f"-o {args.output}: with several --port, -o names a directory, and this is a file")
    protocol = resolve_protocol(args.port[0], args.protocol, args.baud, args.columns, sys.stderr, args.rate,
                                args.field)
    outcomes = capture_many(args.port, args.output, fmt=args.format or "csv", protocol=protocol,
                            duration_s=args.duration, rate_hz=args.rate, baudrate=args.baud,
                            status=lambda ports, duration_s: UnitStatusLines(sys.stderr, ports, duration_s))
    failed = interrupted = with_file = 0
    for outcome in outcomes:
        name = outcome.serial or outcome.port
        result = outcome.capture
        if result is not None and result.rows:
            with_file += 1
            print(f"{printable(name)} ({printable(outcome.port)}): wrote {result.rows} samples "
                  f"({result.device_time_s:.3f} s of device clock) to {printable(result.path, PATH_CHARS)}; "
                  f"link: {result.link.summary()}", file=sys.stdout)
            if outcome.note:
                print(f"  note: {printable_message(outcome.note)}", file=sys.stdout)
        if outcome.error is not None:
            failed += 1
            print(f"imu-station capture: error: {printable_message(outcome.error)}", file=sys.stderr)
        elif result is not None and result.ended_by == "interrupted":
            interrupted += 1
    print(f"{with_file} of {len(outcomes)} units have a file, {failed} ended with an error "
          f"({printable(args.output, PATH_CHARS)})",
          file=sys.stdout)
    if failed:
        return ExitCode.DEVICE
    if interrupted:
        print("imu-station capture: interrupted; the files keep every sample received", file=sys.stderr)
        return ExitCode.INTERRUPTED
    return ExitCode.OK
