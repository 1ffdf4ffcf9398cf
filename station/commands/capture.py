"""``imu-station capture``: record a unit's samples into a capture CSV or an HDF5 capture file."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import IO, Any

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from serial import SerialException

from drivers import (
    DEFAULT_BAUDRATE,
    CommandTimeout,
    CommandUnsupported,
    Device,
    LinkStats,
    NoSamples,
    PortLost,
    SerialDevice,
    open_device,
)
from drivers.serial_device import open_serial
from protocols.ascii_lines import parse_columns
from protocols.detect import ENOUGH_BYTES, Detection, detect
from protocols.mavlink import pymavlink_available
from protocols.registry import DECODER_OPTIONS, DECODERS, make_decoder
from station.acquisition.recorder import CaptureResult, record
from station.cli import EXIT_INTERRUPTED
from station.errors import StationError

NAME = "capture"
HELP = "record samples from a unit (serial port, pty or sim://) into a CSV or HDF5 capture file"
DESCRIPTION = """\
Record the samples a unit streams into a capture file: the capture CSV (t is the device clock in
seconds) or, when FILE ends in .h5 or .hdf5, the station's HDF5 capture file (with the unit's info
and the link statistics). It runs until --duration seconds of device clock, Ctrl-C, or the link
breaks; in every case the file keeps every sample received. A status line on stderr shows the
rate, samples, damaged frames and lost samples.

exit codes: 0 done, 3 device or link error (after saving what was received), 4 usage,
130 interrupted by Ctrl-C (after saving)."""
EPILOG = """\
examples:
  imu-station capture --port /dev/ttyUSB0 --duration 60 -o still.csv
  imu-station capture --port sim:// --rate 400 --duration 10 -o sim.h5
  imu-station capture --port /dev/ttyUSB0 --protocol auto --baud 115200 --duration 60 -o mti.csv
  imu-station capture --port /dev/ttyACM0 --protocol ascii \\
      --columns t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps --duration 30 -o arduino.csv"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", required=True,
                        help="serial device path (/dev/ttyUSB0, a pty), or pyserial URL (sim://, loop://)")
    parser.add_argument("--protocol", default="native", type=_protocol, metavar="NAME[:OPTION]",
                        help=f"wire protocol of the unit: {', '.join(sorted(DECODERS))} (default: native); "
                             f"auto: recognise it from the first bytes and say what was found. "
                             f"{', '.join(DECODER_OPTIONS)} take an option: xsens:hr (the high-rate "
                             f"packets), mavlink:SCALED_IMU2 (which IMU message), ascii:COLUMNS@HZ")
    parser.add_argument("--columns", metavar="SPEC",
                        help="with --protocol ascii: CSV columns and units, e.g. t:ms,ax:g,ay:g,az:g,gx:dps,"
                             "gy:dps,gz:dps (default: t,ax,ay,az,gx,gy,gz,temp in s, m/s^2, rad/s, degC)")
    parser.add_argument("--duration", type=_positive_float, metavar="S",
                        help="seconds of device clock to record (default: until Ctrl-C)")
    parser.add_argument("--rate", type=int, metavar="HZ",
                        help="set the unit's output rate first (SET_RATE); with text lines that carry no "
                             "clock (MotionCal, VectorNav), the rate they come at (default: 100)")
    parser.add_argument("--baud", type=int, default=DEFAULT_BAUDRATE,
                        help=f"line speed of a real serial port (default: {DEFAULT_BAUDRATE})")
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="FILE",
                        help="capture file to write: .csv, or .h5/.hdf5 for the HDF5 capture file")


def _protocol(text: str) -> str:
    name = text.partition(":")[0]
    if name not in DECODERS:
        raise argparse.ArgumentTypeError(f"unknown protocol {name!r}; known: {', '.join(sorted(DECODERS))}")
    if ":" in text:
        try:
            make_decoder(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _positive_float(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _get_info_quickly(device: Device) -> dict[str, Any]:
    """GET_INFO sent at most twice: a unit that does not answer is recorded anyway."""
    if isinstance(device, SerialDevice):
        return device.get_info(timeout=0.5, retries=1)
    return device.get_info(timeout=0.5)  # the Device interface has no retry count


def prepare_device(device: Device, rate_hz: int | None, err: IO[str]) -> None:
    """Ask the unit who it is, set its rate if asked, and start it if it does not stream yet.

    A unit that does not answer GET_INFO or START_STREAM is still recorded (a warning says so):
    a device streams from power-up. A refused or unanswered SET_RATE is an error; after a rate
    change the capture starts with the samples at the new rate.
    """
    try:
        info = _get_info_quickly(device)
        print(f"unit: {info.get('model', '?')} serial {info.get('serial', '?')} firmware "
              f"{info.get('firmware', '?')} at {info.get('rate_hz', '?')} Hz", file=err)
    except CommandUnsupported:
        return
    except CommandTimeout as exc:
        print(f"warning: {exc}; recording without the unit's info", file=err)
    if rate_hz is not None:
        device.set_rate(rate_hz)
        try:
            _get_info_quickly(device)  # the file records the unit's info at the new rate
        except CommandTimeout:
            pass
        device.read(0)  # samples at the old rate are not part of this capture
    if device.stats.samples == 0:
        try:
            device.start()
        except CommandTimeout as exc:
            print(f"warning: {exc}; recording what it sends", file=err)


def capture_to_file(port: str, output: Path, protocol: str = "native", duration_s: float | None = None,
                    rate_hz: int | None = None, baudrate: int = DEFAULT_BAUDRATE,
                    err: IO[str] | None = None) -> CaptureResult:
    """Open the unit at ``port``, prepare it, and record into ``output`` with a live status line."""
    err = err if err is not None else sys.stderr
    if port.startswith("sim://"):
        from mocks import register_sim_url  # the simulated unit, loaded only when asked for

        register_sim_url()
    with open_device(port, protocol=protocol, baudrate=baudrate) as device:
        try:
            prepare_device(device, rate_hz, err)
        except PortLost:
            pass  # record() saves what arrived before the loss, then reports it
        with _StatusLine(err, duration_s) as status:
            return record(device, output, duration_s=duration_s, on_status=status.update)


class _StatusLine:
    """A live line on stderr: progress (with --duration), rate, samples, errors, lost."""

    def __init__(self, err: IO[str], duration_s: float | None):
        self._progress = Progress(
            TextColumn("capturing"), BarColumn(), TextColumn("{task.fields[status]}"), TimeElapsedColumn(),
            console=Console(file=err), transient=False,
        )
        self._task = self._progress.add_task("capture", total=duration_s, status="waiting for samples")

    def __enter__(self) -> _StatusLine:
        self._progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    def update(self, stats: LinkStats, rows: int, device_time_s: float) -> None:
        self._progress.update(self._task, completed=device_time_s, status=_status_text(stats, rows))


def _status_text(stats: LinkStats, rows: int) -> str:
    return (f"{stats.rate_hz:7.1f} Hz  {rows} samples  {stats.errors} errors  {stats.lost} lost"
            + (f"  {stats.overflow_drops} dropped" if stats.overflow_drops else ""))


def report(result: CaptureResult, out: IO[str]) -> None:
    """The summary printed after a capture: where the samples went and how the link fared."""
    link = result.link
    print(f"wrote {result.rows} samples ({result.device_time_s:.3f} s of device clock) to {result.path}",
          file=out)
    print(f"link: {link.summary()}, {link.bytes} bytes", file=out)
    if result.non_increasing:
        print(f"left out {result.non_increasing} samples whose device time did not increase", file=out)


def sniff_protocol(port: str, baudrate: int = DEFAULT_BAUDRATE, timeout_s: float = 3.0) -> Detection:
    """Read the first bytes at ``port`` until a protocol is recognised, or for ``timeout_s``."""
    if port.startswith("sim://"):
        from mocks import register_sim_url  # the simulated unit, loaded only when asked for

        register_sim_url()
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
                     rate_hz: int | None = None) -> str:
    """The decoder name for ``--protocol`` and ``--columns``; ``auto`` sniffs the port and says what
    it found."""
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
        print(f"protocol: {found.protocol}: {found.explanation}", file=err)
        protocol = found.protocol
    if protocol == "ascii" and (columns is not None or rate_hz is not None):
        protocol = f"ascii:{columns or ''}" + (f"@{rate_hz}" if rate_hz is not None else "")
    return protocol


def run(args: argparse.Namespace) -> int:
    protocol = resolve_protocol(args.port, args.protocol, args.baud, args.columns, sys.stderr, args.rate)
    result = capture_to_file(args.port, args.output, protocol=protocol, duration_s=args.duration,
                             rate_hz=args.rate, baudrate=args.baud)
    report(result, sys.stdout)
    if result.error is not None:
        print(f"imu-station capture: error: {result.error}", file=sys.stderr)
        return result.error.exit_code
    if result.ended_by == "interrupted":
        print("imu-station capture: interrupted; the file keeps every sample received", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0
