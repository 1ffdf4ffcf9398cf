"""``imu-station thermal``: fit the temperature compensation of the bias and write the ``thermal`` section."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from protocols.units import STANDARD_GRAVITY
from station.console.options import (
    GRAVITY,
    MAX_GRAVITY,
    MIN_GRAVITY,
    add_instance_option,
    add_output_option,
    add_replace_option,
    describe_range,
    number,
    positive,
)
from station.errors import ExitCode, InputFileError

if TYPE_CHECKING:
    from station.engines.thermal.model import ThermalModel

NAME = "thermal"
HELP = "fit the bias against temperature and its rate from a still temperature sweep"
DESCRIPTION = """\
Fit the temperature compensation of the bias from a recording of the unit held still (in one
pose or several) while its temperature sweeps: a climatic-chamber programme or power-on
self-heating. Per axis the bias is modelled as

    B(T, dT) = a t^3 + b t^2 + c t + e dT^2 + f dT + g t dT + h,   t = T - T_ref

(dT: temperature rate in degC/s, from the noisy temperature through the dT filter stored in the
file). Terms, the number of temperature segments (continuous at the joins) and the dT filter
time constant are chosen by cross-validation on held-out stretches of the sweep. The bias is
measured against the accel/gyro calibration already in PARAMS when there is one (else absolute
biases); the thermal section is written into PARAMS, other sections kept.

The report gives, per axis, the chosen terms and the held-out RMS of 1 s bias means without
and with the model, per segment too; warnings name a span under 10 degC and heating and
cooling that disagree beyond what the dT terms explain (hysteresis).

exit codes: 0 done, 4 unreadable input or data that cannot determine the model."""
EPILOG = """\
examples:
  imu-station thermal sweep.csv -o unit42.yaml --plot thermal.png
  imu-station thermal sweep.h5 -o unit42.yaml --segments 2 --json
  imu-station thermal sweep.ulg --instance 1 -o board.yaml"""


# The parameter file holds at most 64 thermal segments (specs/params-file.md).
MAX_SEGMENTS = 64
SEGMENTS = number(int, 1, MAX_SEGMENTS)
MIN_TEMP_DEGC, MAX_TEMP_DEGC = -100.0, 200.0  # beyond any IMU's operating range
TEMPERATURE = number(float, MIN_TEMP_DEGC, MAX_TEMP_DEGC, unit="degC")
MAX_TAU_S = 3600.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the thermal command's options to ``parser``."""
    parser.add_argument("input", type=Path, metavar="INPUT",
                        help="capture CSV (.csv, .csv.gz) or capture file (.h5) with a temp column, or a PX4 "
                             "(.ulg) or ArduPilot (.bin) log")
    add_instance_option(parser)
    add_output_option(parser, required=True, metavar="PARAMS",
                      help="parameter file to write the thermal section into (created if missing; "
                           "of the same unit)")
    add_replace_option(parser)
    parser.add_argument("--segments", default="auto", type=_segments, metavar="auto|N",
                        help="temperature segments: auto (1 to --max-segments, by cross-validation) or N "
                             "equal-width segments (default: auto)")
    parser.add_argument("--joins", type=_joins, metavar="T1[,T2...]",
                        help="segment joins at these temperatures (degC) instead of --segments")
    parser.add_argument("--terms", type=_terms, metavar="TERM[,TERM...]",
                        help="fit these terms on every axis instead of choosing them (of t3, t2, t, dt2, dt, "
                             "tdt; the constant is always in)")
    parser.add_argument("--max-segments", type=SEGMENTS, default=4, metavar="N",
                        help=f"most segments --segments auto tries, {describe_range(1, MAX_SEGMENTS)} "
                             "(default: 4)")
    parser.add_argument("--reference-temp", type=TEMPERATURE, metavar="DEGC",
                        help="T_ref of the model (default: middle of the swept range)")
    parser.add_argument("--tau", type=positive("s", MAX_TAU_S), metavar="S",
                        help="dT filter time constant (default: chosen by cross-validation among "
                             "2, 5, 15, 40 s)")
    parser.add_argument("--gravity", type=GRAVITY, default=STANDARD_GRAVITY, metavar="M/S2",
                        help=f"local gravity, {describe_range(MIN_GRAVITY, MAX_GRAVITY)} (default: "
                             f"{STANDARD_GRAVITY})")
    parser.add_argument("--no-scale", action="store_true",
                        help="do not try the accel scale factor against temperature (several poses)")
    parser.add_argument("--plot", type=Path, metavar="FILE.png",
                        help="write a PNG of the bias against temperature with the fit and its segments")
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")


def _segments(text: str) -> str | int:
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give 'auto' or a number of segments") from None
    if not 1 <= value <= MAX_SEGMENTS:
        raise argparse.ArgumentTypeError(f"{text!r} is outside the allowed range, "
                                         f"{describe_range(1, MAX_SEGMENTS)} segments")
    return value


def _joins(text: str) -> list[float]:
    try:
        return [TEMPERATURE(v.strip()) for v in text.split(",") if v.strip()]
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: give temperatures in degC separated by commas ({exc})") \
            from None


def _terms(text: str) -> list[str]:
    from station.engines.thermal.model import TERMS

    names = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [n for n in names if n not in TERMS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown terms {unknown}; choose among {', '.join(TERMS)}")
    return names


def _reference_temp(args: argparse.Namespace, held: ThermalModel | None) -> float | None:
    """--reference-temp, or, where the file holds a calibration across temperature, the temperature its
    polynomials are about (the new bias model must share it); another --reference-temp is refused."""
    if held is None or not (held.scale or held.misalignment):
        return args.reference_temp
    if args.reference_temp is not None and abs(args.reference_temp - held.reference_temp) > 1e-9:
        raise InputFileError(args.output, f"holds a calibration across temperature about "
                             f"{held.reference_temp:g} degC: fit the bias about it (leave --reference-temp "
                             f"out, or give {held.reference_temp:g}), or write to another file",
                             column="thermal.reference_temp")
    return float(held.reference_temp)


def run(args: argparse.Namespace) -> int:
    """Fit the sweep, write the thermal section, print the report (or JSON)."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from station.acquisition.autopilot_log import log_notes
    from station.acquisition.capture import read_capture, require_finite
    from station.common.files import output_set
    from station.common.text import PATH_CHARS, printable, printable_message
    from station.console.log_notes import print_log_notes
    from station.console.markup import markup_safe
    from station.console.thermal_report import format_report
    from station.engines.thermal.fit import ThermalSettings, ThermalSweep, fit_thermal
    from station.export.params.file import merge_sections, name_unit, open_for_unit, to_plain

    err = Console(stderr=True)
    with Progress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=err,
                  transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task(f"reading {markup_safe(args.input, PATH_CHARS)}", total=1.0)
        capture = read_capture(args.input, args.instance)
        print_log_notes(args.input, log_notes(capture))
        if capture.temp is None:
            raise InputFileError(args.input, "has no temperature; a thermal fit needs the 'temp' column",
                                 column="temp")
        require_finite(capture, args.input, ("temp",), "a thermal fit needs the temperature of every sample; "
                       "cut the rows without one, or fill them from their neighbours")
        # its accel and gyro sections calibrate the sweep: only the same unit's
        device = name_unit(capture.device, args.serial)
        params = open_for_unit(args.output, device, replace=args.replace)
        progress.update(task, description="fitting the thermal model", completed=0.0)
        settings = ThermalSettings(
            gravity=args.gravity, segments=args.joins if args.joins else args.segments, terms=args.terms,
            max_segments=args.max_segments,
            reference_temp=_reference_temp(args, params.thermal), tau_s=args.tau, fit_scale=not args.no_scale,
        )
        sweep = ThermalSweep(capture.t, capture.temp, capture.acc, capture.gyro, capture.step,
                             accel_cal=params.accel, gyro_cal=params.gyro)
        fit = fit_thermal(sweep, settings, progress=lambda done: progress.update(task, completed=done))
        with output_set():  # the section and its plot together, or neither
            if args.plot:
                progress.update(task, description=f"plotting {markup_safe(args.plot, PATH_CHARS)}")
                from station.plots.thermal import plot_thermal

                plot_thermal(fit, args.plot)
            progress.update(task, description=f"writing {markup_safe(args.output, PATH_CHARS)}")
            # A bias fit does not make the scale and misalignment polynomials: the file's are kept.
            merge_sections(args.output, device, {"thermal": fit.model.keeping_intrinsics(params.thermal)},
                           capture=args.input,
                           replace=args.replace)
    calibrated = {"accel": params.accel is not None, "gyro": params.gyro is not None}
    for message in fit.warnings:
        print(f"warning: {printable_message(message)}", file=sys.stderr)
    if args.json:
        report = fit.report()
        report.update({"input": str(args.input), "output": str(args.output), "calibrated": calibrated})
        print(json.dumps(to_plain(report), indent=2))
    else:
        print(format_report(fit, calibrated))
        print(f"wrote the thermal section to {printable(args.output, PATH_CHARS)}"
              + (f", plot {printable(args.plot, PATH_CHARS)}" if args.plot else ""))
    return ExitCode.OK
