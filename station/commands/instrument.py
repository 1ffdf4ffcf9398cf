"""``imu-station instrument URL``: identify a lab instrument, print its state, and set it."""

from __future__ import annotations

import argparse
import json

from station.errors import ExitCode

NAME = "instrument"
HELP = "identify a climatic chamber, rate table or bench supply by URL, print its state, set it"
DESCRIPTION = """\
Open the instrument URL names, apply the settings given (in the order listed below), then print
its identity and state: a chamber's air temperature and setpoint, a table's position and rate, a
supply's output, voltage and current. For bring-up and scripts: --json prints kind, identity and
the readings (temperature_c, setpoint_c; position_deg, rate_dps; output, voltage_v, current_a).

URLs: votsch://HOST[:2049]  espec://PORT  watlow-f4://PORT[?unit=1]  binder://HOST[:502]
      acutrol://HOST:PORT | acutrol://PORT  aerosmith://PORT  scpi://HOST[:5025] | scpi://PORT
      korad://PORT  sim://chamber|table|supply (beside `imu-station simulate --instruments`)
Options after ?: description=FILE.yaml (your controller's own description), baud=, unit=,
timeout= (s), channel= (a supply's channel). PORT is a device path (espec:///dev/ttyUSB0) or a
pyserial URL.

Settings are checked against --max-* limits, where given, before anything is sent.

exit codes: 0 done, 3 the instrument did not answer or refused, 4 a bad URL, option or
description file (the message names file, line and key)."""
EPILOG = """\
examples:
  imu-station instrument votsch://10.0.0.5
  imu-station instrument votsch://10.0.0.5 --setpoint 40 --gradient 1 --start
  imu-station instrument acutrol://10.0.0.7:5000 --rate 10 --json
  imu-station instrument scpi://10.0.0.9?channel=2 --voltage 5 --current 0.5 --output on
  imu-station instrument korad:///dev/ttyACM0 --output off
  imu-station instrument "espec:///dev/ttyUSB0?description=my-espec.yaml" """


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the instrument command's options to ``parser``."""
    from station.console.options import number

    parser.add_argument("url", metavar="URL", help="the instrument (see above)")
    chamber = parser.add_argument_group("chamber")
    chamber.add_argument("--setpoint", type=number(float, -100.0, 300.0, unit="degC"), metavar="C",
                         help="set the temperature setpoint, degC")
    chamber.add_argument("--gradient", type=number(float, 0.0, 100.0, unit="K/min"), metavar="K_PER_MIN",
                         help="set the ramp gradient (up and down), K/min")
    chamber.add_argument("--start", action="store_true", help="run the chamber at its setpoint")
    table = parser.add_argument_group("rate table")
    table.add_argument("--position", type=number(float, -3600.0, 3600.0, unit="deg"), metavar="DEG",
                       help="move axis --axis to DEG (position mode)")
    table.add_argument("--rate", type=number(float, -3600.0, 3600.0, unit="deg/s"), metavar="DPS",
                       help="turn axis --axis at DPS (rate mode) until stopped")
    table.add_argument("--axis", type=number(int, 1, 3), default=1,
                       help="the table axis (default 1)")
    supply = parser.add_argument_group("bench supply")
    supply.add_argument("--voltage", type=number(float, 0.0, 1000.0, unit="V"), metavar="V",
                        help="set the output voltage, V")
    supply.add_argument("--current", type=number(float, 0.0, 100.0, unit="A"), metavar="A",
                        help="set the current limit, A")
    supply.add_argument("--output", choices=("on", "off"), help="switch the supply's output")
    parser.add_argument("--stop", action="store_true", help="stop: a chamber to standby, a table at rest")
    limits = parser.add_argument_group("limits (checked before anything is sent)")
    limits.add_argument("--min-c", type=number(float, -100.0, 300.0, unit="degC"),
                        help="lowest setpoint allowed")
    limits.add_argument("--max-c", type=number(float, -100.0, 300.0, unit="degC"),
                        help="highest setpoint allowed")
    limits.add_argument("--max-rate", type=number(float, 0.0, 3600.0, unit="deg/s"),
                        help="highest table rate allowed")
    limits.add_argument("--max-v", type=number(float, 0.0, 1000.0, unit="V"), help="highest voltage allowed")
    limits.add_argument("--max-a", type=number(float, 0.0, 100.0, unit="A"), help="highest current allowed")
    parser.add_argument("--json", action="store_true", help="print the state as JSON")


def _settings(args: argparse.Namespace) -> dict[str, list[str]]:
    """The settings given, by the kind they need (to refuse --rate on a chamber before opening it)."""
    given = {"chamber": ["--setpoint"] * (args.setpoint is not None)
             + ["--gradient"] * (args.gradient is not None) + ["--start"] * args.start,
             "table": ["--position"] * (args.position is not None) + ["--rate"] * (args.rate is not None),
             "supply": ["--voltage"] * (args.voltage is not None) + ["--current"] * (args.current is not None)
             + ["--output"] * (args.output is not None)}
    return {kind: options for kind, options in given.items() if options}


def run(args: argparse.Namespace) -> int:
    """Open, set, print; exit 0, 3 or 4."""
    from drivers.instruments import Chamber, Supply, Table, Transcript
    from station.common.text import printable
    from station.errors import StationError
    from station.instruments.limits import Limits, limited
    from station.instruments.open import open_instrument

    wanted = _settings(args)
    if len(wanted) > 1:
        raise StationError(f"{' '.join(o for opts in wanted.values() for o in opts)}: settings of a "
                           f"{' and a '.join(wanted)} at once; one instrument takes one kind")
    transcript = Transcript()
    instrument = limited(open_instrument(args.url, transcript, kind=next(iter(wanted), None)),
                         Limits(min_c=args.min_c, max_c=args.max_c, max_rate_dps=args.max_rate,
                                max_v=args.max_v, max_a=args.max_a,
                                source="the command line (--min-c/--max-c/--max-*)"))
    try:
        if isinstance(instrument, Chamber):
            if args.setpoint is not None:
                instrument.set_setpoint(args.setpoint)
            if args.gradient is not None:
                instrument.set_gradient(args.gradient)
            if args.start:
                instrument.start()
            if args.stop:
                instrument.stop()
        elif isinstance(instrument, Table):
            if args.stop:
                instrument.stop()
            if args.position is not None:
                instrument.move_to(args.position, args.axis)
            if args.rate is not None:
                instrument.turn(args.rate, args.axis)
        elif isinstance(instrument, Supply):
            if args.voltage is not None:
                instrument.set_voltage(args.voltage)
            if args.current is not None:
                instrument.set_current(args.current)
            if args.output is not None:
                instrument.set_output(args.output == "on")
        state = instrument.state()
    finally:
        instrument.close()
    if args.json:
        print(json.dumps({**state, "url": args.url}, indent=1))
    else:
        print(f"{printable(args.url)}: {state['kind']} {printable(state['identity'])}")
        for key, value in state.items():
            if key not in ("kind", "identity", "axes"):
                print(f"  {key}: {printable(value)}")
    return ExitCode.OK
