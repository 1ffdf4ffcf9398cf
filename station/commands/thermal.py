"""``imu-station thermal``: fit the temperature compensation of the bias and write the ``thermal`` section."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from station.acquisition.capture import read_capture
from station.engines.thermal import STANDARD_GRAVITY, ThermalFit, ThermalSettings, ThermalSweep, fit_thermal
from station.engines.thermal_model import TERMS
from station.errors import InputFileError
from station.export.params_file import ParamsFile, to_plain

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
  imu-station thermal sweep.h5 -o unit42.yaml --segments 2 --json"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", type=Path, metavar="INPUT",
                        help="capture CSV (.csv, .csv.gz) or capture file (.h5) with a temp column")
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="PARAMS",
                        help="parameter file to write the thermal section into (created if missing)")
    parser.add_argument("--segments", default="auto", type=_segments, metavar="auto|N",
                        help="temperature segments: auto (1 to --max-segments, by cross-validation) or N "
                             "equal-width segments (default: auto)")
    parser.add_argument("--joins", type=_joins, metavar="T1[,T2...]",
                        help="segment joins at these temperatures (degC) instead of --segments")
    parser.add_argument("--terms", type=_terms, metavar="TERM[,TERM...]",
                        help="fit these terms on every axis instead of choosing them (of t3, t2, t, dt2, dt, "
                             "tdt; the constant is always in)")
    parser.add_argument("--max-segments", type=int, default=4, metavar="N",
                        help="most segments --segments auto tries (default: 4)")
    parser.add_argument("--reference-temp", type=float, metavar="DEGC",
                        help="T_ref of the model (default: middle of the swept range)")
    parser.add_argument("--tau", type=_positive, metavar="S",
                        help="dT filter time constant (default: chosen by cross-validation among "
                             "2, 5, 15, 40 s)")
    parser.add_argument("--gravity", type=_positive, default=STANDARD_GRAVITY, metavar="M/S2",
                        help=f"local gravity (default: {STANDARD_GRAVITY})")
    parser.add_argument("--no-scale", action="store_true",
                        help="do not try the accel scale factor against temperature (several poses)")
    parser.add_argument("--plot", type=Path, metavar="FILE.png",
                        help="write a PNG of the bias against temperature with the fit and its segments")
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")


def _positive(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def _segments(text: str) -> str | int:
    if text == "auto":
        return text
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give 'auto' or a number of segments") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: at least one segment")
    return value


def _joins(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give temperatures in degC separated by commas") from None


def _terms(text: str) -> list[str]:
    names = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [n for n in names if n not in TERMS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown terms {unknown}; choose among {', '.join(TERMS)}")
    return names


SCALES = {"accel": ("mg", 1e3 / STANDARD_GRAVITY), "gyro": ("deg/h", 3600.0 * 57.29577951308232)}


def format_report(fit: ThermalFit, calibrated: dict[str, bool]) -> str:
    """The terminal summary: one line per axis, held-out figures in mg and deg/h."""
    m = fit.model
    lines = [
        f"temperature {fit.block_temp.min():.1f} .. {fit.block_temp.max():.1f} degC, dT "
        f"{fit.block_dtemp.min() * 60:.2f} .. {fit.block_dtemp.max() * 60:.2f} degC/min, "
        f"{len(fit.block_temp)} blocks of {fit.block_s:g} s, poses {', '.join(fit.poses)}",
        f"T_ref {m.reference_temp:g} degC, dT filter ema tau {m.dtemp_filter.tau_s:g} s",
    ]
    for name, tri in fit.triads.items():
        unit, factor = SCALES[name]
        segs = ", ".join(f"[{s.t_min:.1f}, {s.t_max:.1f}]" for s in tri.bias_model.segments)
        basis = "relative to the calibration in PARAMS" if calibrated[name] else "absolute (no calibration)"
        lines.append(f"{name}: segments {segs} degC; bias {basis}")
        for j, a in enumerate(tri.axes):
            by_seg = " | ".join(f"{b * factor:.3g}->{c * factor:.3g}" for b, c in
                                zip(a.cv_rms_before_by_segment, a.cv_rms_after_by_segment, strict=True))
            extra = f", scale {a.scale_per_degc * 1e6:+.1f} ppm/degC" if a.scale_per_degc is not None else ""
            per_segment = f" (segments {by_seg})" if len(tri.bias_model.segments) > 1 else ""
            lines.append(f"  {'xyz'[j]}: {'+'.join(a.terms):<22} held-out RMS "
                         f"{a.cv_rms_before * factor:.4g} -> {a.cv_rms_after * factor:.4g} {unit}"
                         + per_segment + extra)
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    err = Console(stderr=True)
    params = ParamsFile.load_or_new(args.output)
    with Progress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=err,
                  transient=True, disable=not sys.stderr.isatty()) as progress:
        task = progress.add_task(f"reading {args.input}", total=1.0)
        capture = read_capture(args.input)
        if capture.temp is None:
            raise InputFileError(args.input, "has no temperature; a thermal fit needs the 'temp' column",
                                 column="temp")
        progress.update(task, description="fitting the thermal model", completed=0.0)
        settings = ThermalSettings(
            gravity=args.gravity, segments=args.joins if args.joins else args.segments, terms=args.terms,
            max_segments=args.max_segments,
            reference_temp=args.reference_temp, tau_s=args.tau, fit_scale=not args.no_scale,
        )
        sweep = ThermalSweep(capture.t, capture.temp, capture.acc, capture.gyro, capture.step,
                             accel_cal=params.accel, gyro_cal=params.gyro)
        fit = fit_thermal(sweep, settings, progress=lambda done: progress.update(task, completed=done))
        if args.plot:
            progress.update(task, description=f"plotting {args.plot}")
            from station.plots.thermal_plot import plot_thermal

            plot_thermal(fit, args.plot)
        progress.update(task, description=f"writing {args.output}")
        params.thermal = fit.model
        params.update_device(capture.device)
        params.save(args.output)
    calibrated = {"accel": params.accel is not None, "gyro": params.gyro is not None}
    for message in fit.warnings:
        print(f"warning: {message}", file=sys.stderr)
    if args.json:
        report = fit.report()
        report.update({"input": str(args.input), "output": str(args.output), "calibrated": calibrated})
        print(json.dumps(to_plain(report), indent=2))
    else:
        print(format_report(fit, calibrated))
        print(f"wrote the thermal section to {args.output}" + (f", plot {args.plot}" if args.plot else ""))
    return 0
