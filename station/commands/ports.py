"""``imu-station ports``: the serial ports of this machine, with what is known of them."""

from __future__ import annotations

import argparse
import json

from station.errors import ExitCode

NAME = "ports"
HELP = "list the serial ports of this machine with what is known of them (maker, serial number, USB ids)"
DESCRIPTION = """\
List the serial ports the system knows (pyserial's list_ports): the device path to give --port,
its description, and where the system reports them the maker, product, serial number, USB
vendor:product ids and location, and pyserial's hardware id. Pseudo-terminals (imu-station
simulate) and pyserial URLs (sim://) are not listed: give them to --port directly.

exit codes: 0 (also when there is no port)."""
EPILOG = """\
examples:
  imu-station ports
  imu-station ports --json"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ports command's options to ``parser``."""
    parser.add_argument("--json", action="store_true",
                        help="print a JSON list: device, description, hwid, vid, pid, usb_id, serial_number, "
                             "manufacturer, product, location (null where unknown)")


def run(args: argparse.Namespace) -> int:
    """Print the ports, one a line (or as JSON)."""
    from drivers.ports import list_serial_ports
    from station.common.text import printable

    ports = list_serial_ports()
    if args.json:
        print(json.dumps([p.as_dict() for p in ports], indent=1))
    elif not ports:
        print("no serial port found (a USB adapter not plugged in, or no driver for it?)")
    else:
        for p in ports:
            print(printable(p.line()))
    return ExitCode.OK
