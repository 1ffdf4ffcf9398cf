"""``imu-station tui``: the operator's station in the terminal."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from station.console.options import (
    EXPORT_FORMATS,
    MAX_SPEED,
    SEED,
    SPEED,
    add_output_option,
    add_port_options,
    add_supply_options,
    add_table_options,
    check_supply_options,
    positive,
)
from station.errors import ExitCode, StationError
from station.tui.config import TuiConfig

NAME = "tui"
HELP = "guided calibration in the terminal: connect, live view, sequence wizard, results, Allan, thermal"
DESCRIPTION = """\
The operator's station, keyboard only (press ? for every key). Connect to a unit, watch it live,
then let the sequence wizard guide you through the calibration: for each step a drawing of the
pose (which face up) or of the turn (axis, direction, angle), a live check that the unit is in
that pose (angle error) and still (stillness bar), then automatic capture with a progress bar.
Redo or skip any step; abort keeps what was captured. The results screen shows the parameters
with their 1-sigma uncertainties, residuals and pass/fail against limits (the built-in loose ones,
or a factory plan's with --plan), and saves them to
--out (and any --export format). Long recordings: an Allan recording with a live Allan
deviation plot, and a temperature-sweep monitor for the thermal fit.

The magnetometer step (key m, for a unit that reports a magnetometer): the two halves of the sphere
of field directions are drawn with the directions seen so far; the screen says which way to turn
the unit next and ends by itself at 80 % of the sphere (Enter ends it earlier, from 15 %). Its
capture goes beside --capture FILE.csv as FILE-mag.csv (else PARAMS-mag-capture.csv beside --out),
for calibrate --method mag. A unit without a magnetometer is told apart and the step says so.

With --simulate a simulated operator places a simulated unit (served on a pseudo-terminal) as
each step asks: Enter alone accepts every prompt and runs the whole flow.

Files: --out PARAMS.yaml gets the accel and gyro sections (other sections are kept); the
labelled capture of the sequence goes to --capture (default PARAMS-capture.csv beside --out);
Allan and temperature recordings go to PARAMS-allan.h5 and PARAMS-thermal.h5.

Lab instruments by URL: with --supply URL (scpi://HOST, korad://PORT, ...) the bench supply powering
the unit switches it on when connecting (--supply-volts, --supply-amps, each checked against
--supply-max-v and --supply-max-a first) and the turn-on screen power-cycles it through the supply
(off, held --supply-off seconds, on) instead of RESTART or asking the operator, saying each switch;
a supply that fails stops the turn-ons with the reason on the screen. With --table URL
(acutrol://HOST:PORT?axes=3, aerosmith://PORT, ...) the rate table carrying the unit (--table-mount:
the unit axis along its axis) places and turns it for every step of the wizard, within
--table-max-rate and --table-accel; the screen says what the table is doing, and x or Escape stops
it at once. A single-axis table reaches only the mount's pose and turns about it: give a sequence
of those steps (or a three-axis table, ?axes=3).

A port that cannot be opened, a supply or table that cannot be reached, or a link lost during the
run, is shown on the screen (what was captured is kept) and another port can be chosen.

Quitting (q, Ctrl-C) with a calibration that is not saved asks to save it, discard it or go back;
if the terminal closes first, it is saved to PARAMS-unsaved-TIME.yaml beside --out (or
imu-station-unsaved-TIME.yaml here).

exit codes: 0 done, every result within its limits; 1 a result is outside its limits; 2 the run
was aborted or cut short, or its data gave no calibration; 3 the port never opened (quitting after
it failed); 4 usage; 130 Ctrl-C during the sequence wizard (what was captured is kept)."""
EPILOG = """\
examples:
  imu-station tui --port /dev/ttyUSB0 --out unit42.yaml --export c
  imu-station tui --simulate --sequence six-position --hold 2 --out sim.yaml
  imu-station tui --simulate --speed 4 --out sim.yaml          (a quick demonstration)
  imu-station tui --simulate --mag --speed 4 --out sim.yaml    (then m: the magnetometer step)
  imu-station tui --port /dev/ttyACM0 --sequence my-fixture.yaml --no-rotations
  imu-station tui --port /dev/ttyUSB0 --plan line-a.yaml --out unit42.yaml  (the line's limits)
  imu-station tui --port /dev/ttyUSB0 --supply scpi://10.0.0.9 --supply-volts 5 --out unit42.yaml
  imu-station tui --port /dev/ttyUSB0 --table acutrol://10.0.0.7:5000?axes=3 --out unit42.yaml"""


# The simulated unit's rates (mocks.device); a turn faster than 720 deg/s no turntable or hand makes.
MAX_SIM_RATE_HZ = 4000.0
MAX_ROTATION_RATE_DPS = 720.0
MAX_HOLD_S = 600.0
MAX_ALLAN_MINUTES = 7 * 24 * 60.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the TUI's options to ``parser``."""
    where = parser.add_mutually_exclusive_group()
    add_port_options(parser, required=False, port_group=where, baud=False,
                     port_help="serial device path or pyserial URL (default: choose on the connect screen)")
    where.add_argument("--simulate", action="store_true",
                       help="a simulated unit on a pseudo-terminal, placed by a simulated operator")
    parser.add_argument("--sequence", default="six-position", metavar="NAME|FILE",
                        help="six-position (default), twelve-position, rotations, or a YAML sequence file")
    parser.add_argument("--no-rotations", action="store_true",
                        help="leave out the six rotations after the poses (the gyroscope section is "
                        "then not written: its scale and misalignment need the turns)")
    parser.add_argument("--hold", type=positive("s", MAX_HOLD_S), default=5.0, metavar="S",
                        help="seconds of capture per pose (default 5)")
    parser.add_argument("--rotation-rate", type=positive("deg/s", MAX_ROTATION_RATE_DPS), default=90.0,
                        metavar="DPS", help="turn rate asked of the operator, deg/s (default 90)")
    add_output_option(parser, dest="out", metavar="PARAMS.yaml", help="parameter file to write")
    parser.add_argument("--capture", type=Path, metavar="FILE",
                        help="labelled capture of the sequence (.csv or .h5; default beside --out)")
    parser.add_argument("--export", action="append", default=[], choices=EXPORT_FORMATS, metavar="FORMAT",
                        help=f"also export the saved parameters ({', '.join(EXPORT_FORMATS)}); repeatable")
    parser.add_argument("--export-dir", type=Path, metavar="DIR",
                        help="where exports go (default: beside --out)")
    parser.add_argument("--allan-minutes", type=positive("min", MAX_ALLAN_MINUTES), default=60.0,
                        metavar="MIN",
                        help="length of the Allan recording before it stops by itself (default 60)")
    parser.add_argument("--plan", "--limits", dest="plan", type=Path, metavar="PLAN.yaml",
                        help="judge the results against this factory plan's limits (imu-station run's plan) "
                        "instead of the built-in loose ones; the header and the results say which")
    parser.add_argument("--seed", type=SEED, default=0, help="--simulate: which simulated unit (default 0)")
    parser.add_argument("--mag", action="store_true",
                        help="--simulate: the simulated unit has a magnetometer (m: the magnetometer step)")
    parser.add_argument("--rate", type=positive("Hz", MAX_SIM_RATE_HZ), default=200.0, metavar="HZ",
                        help="--simulate: the simulated unit's sample rate (default 200)")
    parser.add_argument("--speed", type=SPEED, default=1.0, metavar="X",
                        help="--simulate: run the simulated unit's clock X times faster than the wall clock "
                        "(demos and tests; every hold and turn is timed on the device clock), at most "
                        f"{MAX_SPEED:g}")
    add_supply_options(parser, help="the bench supply powering the unit (scpi://HOST, korad://PORT, ...): "
                       "switched on when connecting; the turn-on screen power-cycles the unit through it")
    add_table_options(parser, help="a rate table carrying the unit (acutrol://HOST:PORT?axes=3, "
                      "aerosmith://PORT, ...): it places and turns the unit for every step of the wizard")


def config_from_args(args: argparse.Namespace) -> TuiConfig:
    """The TUI's configuration from the parsed options; a bad sequence is refused here, before the
    screen opens, with its file and line.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options.

    Returns
    -------
    TuiConfig
        What the app needs to start.

    Raises
    ------
    StationError
        --export without --out, or a sequence or plan file with an error.
    """
    from station.acquisition.sequences import resolve
    from station.factory.plan import load_plan

    if args.export and args.out is None:
        raise StationError("--export writes from the saved parameter file: give --out PARAMS.yaml too")
    check_supply_options(args)
    if args.simulate and (args.supply is not None or args.table is not None):
        raise StationError("--supply and --table power and move the unit at --port; the --simulate unit is "
                           "not wired to them (serve one that is with `imu-station simulate --instruments` "
                           "and give its pty as --port)")
    max_rate = args.table_max_rate
    if args.table is not None and max_rate is not None and args.rotation_rate > max_rate:
        raise StationError(f"--rotation-rate {args.rotation_rate:g} is above --table-max-rate "
                           f"{args.table_max_rate:g}: the table may not turn that fast")
    resolve(args.sequence, rotations=not args.no_rotations, hold_s=args.hold,
            rotation_rate_dps=args.rotation_rate)
    return TuiConfig(port=args.port, simulate=args.simulate, protocol=args.protocol, sequence=args.sequence,
                     rotations=not args.no_rotations, out=args.out, capture=args.capture, export=args.export,
                     export_dir=args.export_dir, hold_s=args.hold, rotation_rate_dps=args.rotation_rate,
                     seed=args.seed, rate_hz=args.rate, speed=args.speed, allan_minutes=args.allan_minutes,
                     plan=load_plan(args.plan) if args.plan is not None else None, mag=args.mag,
                     supply=args.supply, supply_volts=args.supply_volts, supply_amps=args.supply_amps,
                     supply_max_v=args.supply_max_v, supply_max_a=args.supply_max_a,
                     supply_off_s=args.supply_off, table=args.table, table_mount=args.table_mount,
                     table_max_rate_dps=args.table_max_rate, table_accel_dps2=args.table_accel)


def run(args: argparse.Namespace) -> int:
    """Run the TUI; print what it saved; exit 0, 1 when a result is out of its limits, 2 when the run
    was aborted, 3 (or the error's code) when the port never opened, 130 when Ctrl-C cut a run short
    (:meth:`StationApp.exit_code_for_run`)."""
    from station.tui.app import StationApp

    app = StationApp(config_from_args(args))
    code = app.run()
    from station.common.text import PATH_CHARS, printable, printable_message

    for path in app.saved:
        print(f"saved {printable(path, PATH_CHARS)}")
    note = app.exit_note()
    if note is not None:  # an interrupted run, or a port that never opened: one line, as other commands
        print(f"imu-station {NAME}: {printable_message(note)}", file=sys.stderr)
    return int(code or ExitCode.OK)
