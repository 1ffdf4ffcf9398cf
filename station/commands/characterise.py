"""``imu-station characterise``: turn-on bias repeatability, scale-factor nonlinearity and asymmetry, and
the unit's datasheet."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from station.console.options import (
    DURATION_S,
    add_output_option,
    add_port_options,
    add_replace_option,
    add_supply_options,
    check_supply_options,
    number,
)
from station.errors import EngineInputError, ExitCode, InputFileError

NAME = "characterise"
HELP = "datasheet figures: turn-on bias repeatability, gyro scale nonlinearity and asymmetry, --datasheet"
DESCRIPTION = """\
Measure what a datasheet says of the unit and merge it into the 'characterisation' section of PARAMS
(other sections are kept).

Turn-on bias repeatability: give three or more still captures, each one power-up of the unit in the
same pose (STILL1.csv ... STILLn.csv), or record them with --port PORT --turn-ons N --still S: the unit
is restarted with the native RESTART command before each record (a unit that cannot restart itself is
power-cycled by the operator when asked). With --supply URL the unit is power-cycled through its bench
supply instead (output off, held --supply-off S, on, then the station waits for its samples); give
--supply-volts V and --supply-amps A to set the supply, each checked against --supply-max-v and
--supply-max-a before anything is sent. The figure is the spread of the turn-on means with each
record's in-run noise of its mean removed (from its own Allan deviation), with a chi-square interval.

Scale-factor nonlinearity and asymmetry: give captures with constant-rate steps (labels rate+z:90,
rate-z:90, ...: three or more rates over the range, both ways, about each axis measured), or record
them with --port PORT --table TABLE --rates R1,R2,R3 [--axes xyz] [--hold S]: the rate table spins the
unit at each rate both ways (SPIN), and the rows are labelled where the unit's own rate is steady.
Per the parameter-file spec's definitions, in ppm.

--datasheet prints one table in datasheet units of every figure the parameter file holds (noise,
calibration, g-sensitivity, thermal and characterisation sections), each with its uncertainty and what
measured it; --json prints it for machines.

exit codes: 0 done, 3 the unit or its link failed, 4 unusable input (the message names the file)."""
EPILOG = """\
examples:
  imu-station characterise still1.csv still2.csv still3.csv still4.csv -o unit.yaml
  imu-station characterise --port /dev/ttyUSB0 --turn-ons 10 --still 60 -o unit.yaml --keep turn-ons/
  imu-station characterise --port /dev/ttyUSB0 --turn-ons 10 --still 60 --supply korad:///dev/ttyUSB1
  imu-station characterise rates.csv -o unit.yaml --datasheet
  imu-station characterise --port /dev/ttyUSB0 --table /dev/ttyUSB1 --rates 10,100,300,600 -o unit.yaml
  imu-station characterise --datasheet --params unit.yaml --json"""

MAX_TURN_ONS = 1000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the characterise command's options to ``parser``."""
    parser.add_argument("inputs", type=Path, nargs="*", metavar="CAPTURE",
                        help="still captures (one per power-up, same pose) and/or captures with rate steps")
    add_port_options(parser, required=False,
                     port_help="record the turn-ons from the unit at this port (with --turn-ons and --still)")
    parser.add_argument("--turn-ons", type=number(int, 3, MAX_TURN_ONS), default=None, metavar="N",
                        help=f"power-ups to record with --port, 3 to {MAX_TURN_ONS}")
    parser.add_argument("--still", type=DURATION_S, default=None, metavar="S",
                        help="seconds recorded still at each power-up with --port")
    add_supply_options(parser, help="power-cycle the unit through this bench supply between turn-ons "
                                    "(scpi://HOST, korad://PORT, sim://supply) instead of RESTART")
    parser.add_argument("--table", metavar="TABLE",
                        help="the rate table's port: record constant-rate steps of the unit at --port")
    parser.add_argument("--rates", type=_rates, default=None, metavar="R,R,R",
                        help="rates of the steps with --table, deg/s, each run both ways (three or more)")
    parser.add_argument("--axes", default="xyz", choices=("x", "y", "z", "xy", "xz", "yz", "xyz"),
                        help="axes the rate steps turn about (default xyz)")
    parser.add_argument("--hold", type=DURATION_S, default=5.0, metavar="S",
                        help="seconds each rate is held once steady (default 5)")
    parser.add_argument("--keep", type=Path, metavar="DIR",
                        help="keep the captures recorded with --port in DIR (default: not kept)")
    parser.add_argument("--level", type=number(float, 0.5, 0.999), default=None, metavar="P",
                        help="confidence level of the repeatability interval (default one sigma, 0.683)")
    add_output_option(parser, metavar="PARAMS",
                      help="parameter file to merge the 'characterisation' section into (of the same unit)")
    add_replace_option(parser)
    parser.add_argument("--datasheet", action="store_true",
                        help="print the datasheet table of the parameter file (-o, or --params)")
    parser.add_argument("--params", type=Path, metavar="PARAMS",
                        help="parameter file the datasheet is read from (default: -o)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


def _rates(text: str) -> list[float]:
    """``10,100,300``: three or more distinct positive rates, deg/s."""
    try:
        rates = sorted({float(r) for r in text.split(",") if r.strip()})
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give rates in deg/s like 10,100,300") from None
    if len(rates) < 3 or rates[0] <= 0 or rates[-1] > 720:
        raise argparse.ArgumentTypeError(f"{text!r}: give three or more distinct rates above 0 and up to "
                                         "720 deg/s")
    return rates


def _check_options(args: argparse.Namespace) -> None:
    turn_ons = args.turn_ons is not None or args.still is not None
    if args.port is not None and not turn_ons and args.table is None:
        raise EngineInputError("--port records the turn-ons (give --turn-ons N and --still S) or rate steps "
                               "(give --table TABLE and --rates R,R,R)")
    if turn_ons and (args.turn_ons is None or args.still is None):
        raise EngineInputError("the turn-ons need both --turn-ons N (3 or more) and --still S")
    if args.supply is not None and args.turn_ons is None:
        raise EngineInputError("--supply power-cycles the unit between turn-ons: give --turn-ons N and "
                               "--still S")
    check_supply_options(args)
    if (args.table is None) != (args.rates is None):
        raise EngineInputError("rate steps need both --table TABLE and --rates R,R,R")
    if args.port is None and (turn_ons or args.table is not None or args.keep is not None):
        raise EngineInputError("--turn-ons, --still, --table and --keep go with --port (the unit to record)")
    if not args.inputs and args.port is None and not args.datasheet:
        raise EngineInputError("nothing to do: give captures, --port with --turn-ons and --still, or "
                               "--datasheet")
    if args.datasheet and args.output is None and args.params is None:
        raise EngineInputError("--datasheet reads a parameter file: give -o PARAMS or --params PARAMS")


def _power_cycle(turn_on: int) -> None:
    """Ask the operator at the terminal to power-cycle the unit."""
    print(f"turn-on {turn_on}: the unit cannot restart itself. Switch it off, wait a few seconds, switch it "
          "on, then press Enter", file=sys.stderr)
    input()


def _record(args: argparse.Namespace, folder: Path) -> list[Path]:
    from drivers import open_device
    from drivers.turntable import Turntable
    from station.acquisition.port_capture import prepare_device
    from station.acquisition.rate_table import record_rate_steps
    from station.acquisition.turn_ons import record_turn_ons
    from station.console.status_line import CaptureStatusLine

    paths = []
    if args.turn_ons is not None:
        interactive = sys.stdin.isatty()
        status = ((lambda duration_s: CaptureStatusLine(sys.stderr, duration_s)) if sys.stderr.isatty()
                  else None)
        cycle = None
        if args.supply is not None:
            from station.instruments.limits import Limits
            from station.instruments.power_cycle import open_power_cycle

            limits = Limits(max_v=args.supply_max_v, max_a=args.supply_max_a,
                            source="--supply-max-v / --supply-max-a")
            cycle = open_power_cycle(args.supply, limits, args.supply_volts, args.supply_amps,
                                     args.supply_off, sys.stderr)
        try:
            if cycle is not None:
                cycle.power_on()  # the unit may be off (a supply starts with its output off)
            paths += record_turn_ons(args.port, folder, args.turn_ons, args.still, protocol=args.protocol,
                                     baudrate=args.baud, power_cycle=_power_cycle if interactive else None,
                                     supply_cycle=cycle, err=sys.stderr, status=status)
        finally:
            if cycle is not None:
                cycle.close()
    if args.table is not None:
        folder.mkdir(parents=True, exist_ok=True)
        with open_device(args.port, protocol=args.protocol, baudrate=args.baud) as device, \
                Turntable(args.table) as table:
            prepare_device(device, None, sys.stderr)
            paths.append(record_rate_steps(device, table, folder / "rates.csv", args.rates, args.axes,
                                           args.hold, err=sys.stderr))
    return paths


def _analyse(paths: list[Path], level: float | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Read the captures, sort them into turn-on records and rate captures, run the engines; returns
    the section's keys and what is known of the unit."""
    from station.acquisition.capture import read_capture
    from station.engines.allan.deviation import ONE_SIGMA
    from station.engines.characterisation.scale import rate_steps, scale_linearity
    from station.engines.characterisation.turn_on import reduce_record, turn_on_repeatability
    from station.export.params.characterisation import repeatability_keys, scale_keys

    stills, steps, rate_files = [], [], []
    device: dict[str, Any] = {}
    for path in paths:
        capture = read_capture(path)
        if device.get("serial") and capture.device.get("serial") not in (None, device["serial"]):
            raise InputFileError(path, f"is of unit {capture.device.get('serial')}, the first capture of "
                                 f"unit {device['serial']}: characterise one unit at a time")
        device = device or dict(capture.device)
        found = rate_steps(capture.t, capture.gyro, capture.step, str(path))
        if found:
            steps += found
            rate_files.append(str(path))
            continue
        poses = {label for label, _ in capture.segments()}
        if len(poses) > 1:
            raise InputFileError(path, f"holds several poses ({', '.join(sorted(poses))}) and no rate step: "
                                 "a turn-on record is one still pose, recorded at one power-up")
        pose = poses.pop() if poses else ""
        stills.append(reduce_record(str(path), capture.t, capture.acc, capture.gyro, pose))
    keys: dict[str, Any] = {}
    if stills:
        acc, gyro = turn_on_repeatability(stills, ONE_SIGMA if level is None else level)
        keys |= repeatability_keys(acc, gyro, [s.source for s in stills])
    if rate_files:
        keys |= scale_keys(scale_linearity(steps, ", ".join(rate_files)), rate_files)
    return keys, device


def _lines(keys: dict[str, Any]) -> list[str]:
    from station.report.datasheet import datasheet_rows, format_table

    rows = datasheet_rows({"characterisation": keys})
    return format_table(rows).splitlines() if rows else []


def run(args: argparse.Namespace) -> int:
    """Record or read the captures, compute the figures, merge them, print them (and the datasheet)."""
    from station.common.text import PATH_CHARS, printable
    from station.export.params.characterisation import merged
    from station.export.params.file import ParamsFile, merge_sections, name_unit, open_for_unit

    _check_options(args)
    result: dict[str, Any] = {}
    paths = list(args.inputs)
    if args.port is not None:
        if args.output:
            # refuse before minutes of recording; the unit says who it is once it is opened
            open_for_unit(args.output, name_unit(None, args.serial), replace=args.replace, unit_pending=True)
        if args.keep is not None:
            paths += _record(args, args.keep)
            keys, device = _analyse(paths, args.level)
        else:
            with tempfile.TemporaryDirectory(prefix="imu-turn-ons-") as folder:
                paths += _record(args, Path(folder))
                keys, device = _analyse(paths, args.level)
    elif paths:
        keys, device = _analyse(paths, args.level)
    else:
        keys, device = {}, {}
    if keys:
        result["characterisation"] = keys
        if args.output:
            device = name_unit(device, args.serial)
            held = open_for_unit(args.output, device, replace=args.replace)
            section = merged(held.other.get("characterisation"), keys)
            merge_sections(args.output, device, {"characterisation": section},
                           capture=paths[0] if len(paths) == 1 else None, replace=args.replace)
            result["output"] = str(args.output)
    if args.datasheet:
        from station.export.params.file import to_plain
        from station.report.datasheet import datasheet_rows, format_table

        source = args.params or args.output
        rows = datasheet_rows(to_plain(ParamsFile.load(source).to_dict()))
        result["datasheet"] = {"params": str(source), "rows": [r.as_dict() for r in rows]}
    if args.json:
        json.dump(result, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
        return ExitCode.OK
    if keys and not args.datasheet:
        for line in _lines(keys):
            print(line)
    if args.datasheet:
        print(f"datasheet of {printable(result['datasheet']['params'], PATH_CHARS)}:")
        print(format_table(rows) if rows else "(no section of the file gives a datasheet figure)")
    if "output" in result:
        print(f"{printable(result['output'], PATH_CHARS)}: characterisation section written")
    return ExitCode.OK
