"""``imu-station calibrate``: accelerometer and gyroscope intrinsics from a capture.

Why this module is long: one command with five ways in (turntable, free, mag, across temperature, a
board of several IMUs) that share its parser, its options' checks (gravity, rate, place) and the way
results are merged into the parameter file; each way's composition of reading, engine, output set and
report is a function here, the engines and the printing are elsewhere.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import sys
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from protocols.units import STANDARD_GRAVITY
from station.console.options import (
    DURATION_S,
    MAX_GRAVITY,
    MIN_GRAVITY,
    RATE_HZ,
    add_instance_option,
    add_output_option,
    add_replace_option,
    check_range,
    number,
    positive,
)
from station.console.phase_line import PhaseLine
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from station.acquisition.capture import Capture
    from station.engines.calibration.common import CalibrationReport

NAME = "calibrate"
HELP = ("accelerometer and gyroscope scale, misalignment and bias from a capture (turntable or hand-held); "
        "magnetometer hard and soft iron (--method mag)")
DESCRIPTION = """\
Estimate the intrinsics of both triads, raw = K (I + S) true + b, from a capture and merge the
'accel' and 'gyro' sections into PARAMS (other sections are kept; the file is written atomically).

--method turntable: a capture whose rows carry step labels (+x, -x, +x+y, ..., rot+z, rot-z:180):
  accelerometer by least squares over the static poses (six-position: Ferraris' analytic solution),
  gyroscope bias from the static steps and scale/misalignment from the rotations' integrated angles.
--method free: an unlabelled hand-held session (Tedaldi et al. 2014, imu_tk): an initial still period,
  then many still orientations joined by moves. Static intervals by moving variance; the accelerometer
  fit minimises r = g - |a| (analytic Jacobian, Levenberg-Marquardt); the gyroscope fit integrates the
  calibrated rates (RK4) between static intervals and matches the gravity directions.
--method auto (default): turntable when the capture has step labels, else free.
--across-temperature (turntable): several labelled captures, each at one soak temperature (its 'temp'
  column), each calibrated as above; bias, scale factor and misalignment of both triads are fitted as
  polynomials in T (order by leave-one-out cross-validation, weighted by each soak's 1-sigma) and the
  'accel', 'gyro' (at the reference temperature) and 'thermal' sections (bias change, thermal.scale,
  thermal.misalignment) are written; prints every soak, the orders and the scale-factor temperature
  coefficient (ppm/degC), misalignment change (urad) and bias sensitivity; --plot (default beside -o)
  draws them against T.
Several IMUs of one board: a PX4/ArduPilot log with several IMUs and no --instance, or one capture
  per IMU (NAME.csv, NAME.imu1.csv, ... each with its '# instance: k' line): each IMU is calibrated as
  above, then its rotation relative to the first (v_k = R v_0, each IMU in its own axes, --convention)
  by Wahba's problem over the first IMU's still poses (and the turns' integrated rates), with its
  1-sigma; the first IMU's sections and an 'imus' section (every IMU's sections, device ids and
  rotation_to_first) are merged. --instance N calibrates IMU N alone.
--method mag: the magnetometer (capture columns mx, my, mz) into the 'mag' section: hard iron, soft iron
  and the rotation to the accelerometer, fitted jointly with the dip constraint (the angle between
  gravity and the field is the same at every still pose), so a desk-bound session whose z axis stays
  within 45 deg of up still calibrates; the accelerometer is corrected first with PARAMS's 'accel'
  section when it has one, else its bias, scale and misalignment are estimated from the still poses
  with the magnetometer (the rotation is then to the axes --method free's lower convention gives;
  calibrating it first is better near level). The field magnitude: --field, or the World Magnetic
  Model at --latitude/--longitude/--height/--date, else the data's own. Prints the coverage of the
  sphere of field directions (and which are missing), every parameter's 1-sigma and the residuals;
  disturbed stretches are left out and named.

Input may be in any raw unit (counts included): initial guesses come from the data.
Every parameter is printed with its 1-sigma uncertainty; per-pose residuals and warnings follow.

exit codes: 0 done, 4 unusable input (the message says what the data fail to determine)."""
EPILOG = """\
examples:
  imu-station calibrate twelve.csv --method turntable -o unit.yaml
  imu-station calibrate m20.csv p00.csv p20.csv p40.csv p60.csv --across-temperature -o unit.yaml
  imu-station calibrate board.csv board.imu1.csv board.imu2.csv --method turntable -o board.yaml
  imu-station calibrate handheld.ulg -o board.yaml
  imu-station calibrate handheld.csv --method free --initial-still 30 --convention upper -o unit.yaml
  imu-station calibrate session.csv --latitude 45.07 --height 240 --json
  imu-station calibrate compass.csv --method mag --latitude 45.07 --longitude 7.68 -o unit.yaml"""


# A station's height above the WGS-84 ellipsoid: from below the Dead Sea to above any laboratory.
MIN_HEIGHT_M, MAX_HEIGHT_M = -1000.0, 10_000.0
MAX_WINDOW_S = 60.0
MAX_SOAK_SPREAD_DEGC = 2.0  # a soak's capture whose temperature moved more is flagged
# The field magnitude --field accepts, microtesla: the Earth's is 22 to 67 uT; a lab's coil more.
MIN_FIELD_UT, MAX_FIELD_UT = 1.0, 1000.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the calibrate command's options to ``parser``."""
    parser.add_argument("input", type=Path, metavar="INPUT", nargs="+",
                        help="capture CSV (.csv, .csv.gz) or capture file (.h5); several with "
                             "--across-temperature, one per soak temperature")
    parser.add_argument("--method", choices=("auto", "turntable", "free", "mag"), default="auto",
                        help="turntable (labelled poses and rotations), free (hand-held), auto (default), "
                             "mag (the magnetometer)")
    add_output_option(parser, metavar="PARAMS.yaml",
                      help="parameter file to merge the accel and gyro sections into (of the same unit)")
    add_replace_option(parser)
    parser.add_argument("--gravity", type=float, metavar="G",
                        help=f"local gravity in m/s^2 (default {STANDARD_GRAVITY}, "
                             "or normal gravity from --latitude)")
    parser.add_argument("--latitude", type=float, metavar="DEG",
                        help="latitude: WGS-84 normal gravity (Somigliana + free-air with --height) and, "
                             "for the turntable method, the Earth rate's vertical part")
    parser.add_argument("--height", type=number(float, MIN_HEIGHT_M, MAX_HEIGHT_M, unit="m"), default=0.0,
                        metavar="M", help="height above the ellipsoid (m)")
    parser.add_argument("--field", type=number(float, MIN_FIELD_UT, MAX_FIELD_UT, unit="uT"), metavar="UT",
                        help="mag method: the local field's magnitude in microtesla (default: the World "
                             "Magnetic Model's with --latitude/--longitude, else the data's own)")
    parser.add_argument("--longitude", type=number(float, -180.0, 180.0, unit="degrees"), metavar="DEG",
                        help="mag method: longitude, with --latitude, --height and --date for the World "
                             "Magnetic Model's field magnitude and dip")
    parser.add_argument("--date", type=_iso_date, metavar="YYYY-MM-DD",
                        help="mag method: the date of the capture for the World Magnetic Model "
                             "(default today)")
    parser.add_argument("--no-earth-rate", action="store_true",
                        help="with --latitude, do not compensate the Earth rate (gravity only)")
    parser.add_argument("--initial-still", type=DURATION_S, metavar="S",
                        help="free method: length of the initial still period (default: detected)")
    parser.add_argument("--convention", choices=("lower", "upper"), default="lower",
                        help="free method: accelerometer misalignment triangle; lower = body x along "
                             "accel x, body xy plane = accel xy plane (default); upper = imu_tk's T")
    parser.add_argument("--window", type=positive("s", MAX_WINDOW_S), default=1.0, metavar="S",
                        help="free method: moving-variance window in seconds (default 1)")
    parser.add_argument("--imu-tk", action="store_true",
                        help="free method: imu_tk's detector and cost (101-sample window, first 100 "
                             "samples of each interval, 1/2 sum r^2)")
    parser.add_argument("--gyro-bias", choices=("still", "intervals"),
                        help="free method: gyro bias from all static intervals, each move de-biased with the "
                             "intervals on either side (default; follows a drifting bias), or from the "
                             "initial still period only (imu_tk; the default with --imu-tk)")
    parser.add_argument("--rate", type=RATE_HZ, metavar="HZ",
                        help="the sample rate the device was set to (default: the capture's device "
                             "info, if any); refused if the timestamps disagree")
    parser.add_argument("--across-temperature", action="store_true",
                        help="turntable method on one capture per soak temperature: bias, scale and "
                             "misalignment as polynomials in T into the accel, gyro and thermal sections")
    add_instance_option(parser)
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    parser.add_argument("--plot", type=Path, metavar="FILE.png",
                        help="write a residual plot (PNG); with --across-temperature, scale, misalignment "
                             "and bias against T (default: beside -o, NAME-across-temperature.png)")


def _iso_date(text: str) -> datetime.date:
    try:
        return datetime.date.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a date; give YYYY-MM-DD") from None


def mag_field(args: argparse.Namespace) -> tuple[float | None, float | None, str]:
    """The field magnitude and dip for --method mag: --field, or the World Magnetic Model at
    --latitude/--longitude/--height/--date, else neither (the data's own magnitude).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (``field``, ``latitude``, ``longitude``, ``height``, ``date``).

    Returns
    -------
    tuple
        (magnitude in microtesla or None, the model's dip in deg or None, where they came from).

    Raises
    ------
    StationError
        --field with the model's options, or half of a place.
    """
    place = args.longitude is not None or args.date is not None
    if args.field is not None:
        if place:
            raise StationError("give either --field or --latitude/--longitude/--date, not both")
        return float(args.field), None, f"given: --field {args.field:g} uT"
    if place or args.latitude is not None:
        if args.latitude is None or args.longitude is None:
            raise StationError("the World Magnetic Model needs both --latitude and --longitude (and "
                               "--height, --date if known); or give the field's magnitude with --field UT")
        from station.engines.magnetometer.geomagnetic import field_at

        model = field_at(args.latitude, args.longitude, args.height,
                         args.date or datetime.datetime.now(datetime.UTC).date())
        return model.magnitude_ut, model.dip_deg, model.describe()
    return None, None, "the data's own"


def run_mag(args: argparse.Namespace) -> int:
    """--method mag: fit the magnetometer, merge the 'mag' section into --output, print the summary."""
    from rich.console import Console

    from station.acquisition.autopilot_log import log_notes
    from station.acquisition.capture import read_capture
    from station.common.files import output_set
    from station.common.text import PATH_CHARS
    from station.console.log_notes import print_log_notes
    from station.console.mag_summary import mag_report_dict, print_mag_report
    from station.console.markup import markup_safe
    from station.engines.magnetometer.calibration import MagCapture, MagSettings, calibrate_mag
    from station.errors import InputFileError
    from station.export.params.file import merge_sections, name_unit, open_for_unit
    from station.export.params.magnetometer import mag_section
    from station.export.params.sections import MAG

    field, dip, field_source = mag_field(args)  # refuse bad options before reading a long capture
    with PhaseLine(sys.stderr) as phase:
        phase.show(f"reading {args.input}")
        capture = read_capture(args.input, args.instance)
        print_log_notes(args.input, log_notes(capture))
        if capture.mag is None:
            raise InputFileError(args.input, "has no magnetometer columns (mx, my, mz): capture from a "
                                 "unit that reports its magnetometer, or calibrate the accelerometer and "
                                 "gyroscope with --method free or turntable")
        device = name_unit(capture.device, args.serial)
        params = open_for_unit(args.output, device, replace=args.replace) if args.output else None
        accel = params.accel if params is not None else None
        # the down direction in the calibrated accelerometer's axes; without an accel section the
        # engine estimates the accelerometer from the still poses
        acc = accel.correct(capture.acc) if accel is not None else capture.acc
        phase.show("fitting the magnetometer")
        cal = calibrate_mag(MagCapture(capture.t, capture.mag, acc, capture.gyro),
                            MagSettings(field_ut=field, model_dip_deg=dip, estimate_accel=accel is None))
    outputs = {}
    with output_set():  # the section and its plot together, or neither
        if args.output:
            merge_sections(args.output, device, {MAG: mag_section(cal, field_source)},
                           capture=args.input, replace=args.replace)
            outputs[str(args.output)] = "mag section written" + (
                " (accelerometer corrected with its accel section)" if accel is not None
                else " (accelerometer estimated from the still poses)" if cal.accel_estimated else "")
        if args.plot:
            from station.plots.magnetometer import plot_mag

            plot_mag(cal, capture.t, capture.mag, args.plot,
                     f"imu-station calibrate --method mag {args.input.name}")
            outputs[str(args.plot)] = "written"
    if args.json:
        import json

        result = mag_report_dict(cal, str(args.input), field_source)
        result["outputs"] = outputs
        json.dump(result, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
        return ExitCode.OK
    console = Console(file=sys.stdout, width=140)
    print_mag_report(cal, field_source, console)
    for path, what in outputs.items():
        console.print(f"{markup_safe(path, PATH_CHARS)}: {what}")
    return ExitCode.OK


def local_gravity(args: argparse.Namespace) -> float:
    """g from --gravity, or WGS-84 normal gravity from --latitude and --height, else standard gravity.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (``gravity``, ``latitude``, ``height``).

    Returns
    -------
    float
        Local gravity, m/s^2.

    Raises
    ------
    StationError
        Both --gravity and --latitude, or either outside its range.
    """
    from station.engines.shared.earth import normal_gravity

    if args.gravity is not None and args.latitude is not None:
        raise StationError("give either --gravity or --latitude/--height, not both")
    if args.gravity is not None:
        check_range("--gravity", args.gravity, MIN_GRAVITY, MAX_GRAVITY, unit="m/s^2",
                    what="local gravity on Earth,")
        return float(args.gravity)
    if args.latitude is not None:
        check_range("--latitude", args.latitude, -90.0, 90.0, unit="degrees")
        return normal_gravity(args.latitude, args.height)
    return STANDARD_GRAVITY


def calibrate_capture(capture: Capture, args: argparse.Namespace) -> CalibrationReport:
    """Run the chosen method on a capture (the CLI's composition of engine and options).

    Parameters
    ----------
    capture : Capture
        The capture read from INPUT.
    args : argparse.Namespace
        The parsed options.

    Returns
    -------
    CalibrationReport
        Both triads with their 1-sigma, per-pose residuals and warnings.
    """
    # each method's engine loads only when it runs (the other costs 20 ms of start-up)
    gravity = local_gravity(args)
    has_labels = capture.step is not None and any(str(s).strip() for s in capture.step)
    method = args.method if args.method != "auto" else ("turntable" if has_labels else "free")
    # the rate the device says it runs at, unless the user states one
    rate = args.rate if args.rate is not None else capture.device.get("rate_hz")
    rate = float(rate) if rate is not None else None
    if method == "turntable":
        from station.engines.calibration.turntable import (
            TurntableCapture,
            TurntableSettings,
            calibrate_turntable,
        )

        latitude = None if args.no_earth_rate else args.latitude
        return calibrate_turntable(TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step, rate),
                                   TurntableSettings(gravity=gravity, latitude_deg=latitude))
    from station.engines.calibration.free import FreeCapture, FreeSettings, calibrate_free

    settings = FreeSettings.imu_tk() if args.imu_tk else FreeSettings(window_s=args.window)
    settings = dataclasses.replace(settings, gravity=gravity, convention=args.convention)
    if args.gyro_bias is not None:
        settings = dataclasses.replace(settings, gyro_bias=args.gyro_bias)
    data = FreeCapture(capture.t, capture.acc, capture.gyro, initial_still_s=args.initial_still, rate_hz=rate)
    return calibrate_free(data, settings)


def report_dict(report: CalibrationReport, source: str) -> dict[str, Any]:
    """The report as the JSON ``--json`` prints: method, gravity, both triads, poses, warnings."""
    from station.export.params.file import sensor_to_dict, to_plain

    out: dict[str, Any] = {"source": source, "method": report.method, "gravity": report.gravity}
    for name in ("accel", "gyro"):
        cal = getattr(report, name)
        out[name] = sensor_to_dict(cal) if cal is not None else None
    out["poses"] = report.poses
    out["warnings"] = report.warnings
    details = {k: v for k, v in report.details.items() if k not in ("accel_correction", "gyro_correction")}
    out["details"] = details
    return to_plain(out)


def _fmt(value: float, sd: float | None) -> str:
    import numpy as np

    if sd is None or not np.isfinite(sd) or sd == 0:
        return f"{value:.7g}"
    return f"{value:.7g} ± {sd:.2g}"


def print_report(report: CalibrationReport, out: IO[str]) -> None:
    """Every parameter with its 1-sigma, the per-pose residuals and the warnings, as plain-text tables."""
    import numpy as np

    from station.common.table import format_table
    from station.common.text import printable, printable_message

    blocks = [f"{report.method} calibration, g = {report.gravity:.6f} m/s^2"]
    numbers = (False, True, True, True)
    for name, unit in (("accel", "raw per m/s^2"), ("gyro", "raw per rad/s")):
        cal = getattr(report, name)
        if cal is None:
            continue
        sd = cal.stddev
        rows = [["scale K", *[_fmt(cal.scale[i], sd.get("scale", [None] * 3)[i]) for i in range(3)]]]
        mis = cal.misalignment
        mis_sd = np.asarray(sd.get("misalignment", np.zeros((3, 3))))
        for i, row in enumerate("xyz"):
            rows.append([f"misalignment S, row {row}",
                         *[("0" if i == j else _fmt(mis[i, j], mis_sd[i, j])) for j in range(3)]])
        bias_sd = np.asarray(sd.get("bias", [None] * 3))
        rows.append(["bias b", *[_fmt(cal.bias[i], bias_sd[i]) for i in range(3)]])
        if cal.extra.get("g_sensitivity") is not None:  # rad/s per m/s^2: bias change = G f
            g_sens = np.asarray(cal.extra["g_sensitivity"])
            g_sd = np.asarray(sd.get("g_sensitivity", np.full((3, 3), np.nan)))
            for i, row in enumerate("xyz"):
                rows.append([f"g-sensitivity G, row {row} (rad/s per m/s^2)",
                             *[_fmt(g_sens[i, j], g_sd[i, j]) for j in range(3)]])
        title = f"{name}: {cal.method} (forward model raw = M true + b; scale in {unit})"
        blocks += ["", format_table(title, ("parameter", "x", "y", "z"), rows, numbers)]
        blocks.append(f"{name} residual RMS: {cal.residual_rms:.4g} ({cal.extra.get('residual', '')})")
    trials = report.details.get("trials")
    if trials:
        chosen = report.details.get("chosen_multiplier")
        rows = [[f"{tr['multiplier']:g}" + (" *" if tr["multiplier"] == chosen else ""), str(tr["intervals"]),
                 "too few" if tr["cost"] is None else f"{tr['cost']:.6g}"] for tr in trials]
        blocks += ["", format_table("static-interval detection (threshold = k x still-period variance)",
                                    ("k", "intervals", "cost"), rows, (True, True, True))]
    if report.poses:
        rows = []
        for p in report.poses:
            if "angle_error_deg" in p:
                value = f"angle error {p['angle_error_deg']:+.4f} deg"
            elif "norm_error" in p:
                value = f"|a| - g {p['norm_error']:+.5f} m/s^2"
            else:
                value = f"|a| - g {p['residual']:+.5f} m/s^2"
                if p.get("gyro_residual") is not None:
                    value += f", gyro {p['gyro_residual']:.4f}"
            rows.append([printable(p["label"]), f"{p['t0']:.1f}..{p['t1']:.1f}", value])
        blocks += ["", format_table("per-pose residuals", ("step", "t (s)", "residual"), rows,
                                    (False, True, False))]
    blocks += [f"warning: {printable_message(w)}" for w in report.warnings]
    out.write("\n".join(blocks) + "\n")


def write_plot(path: Path, report: CalibrationReport, source: str) -> None:
    """PNG of the calibrated gravity magnitude per static pose (and the angle error per rotation)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from station.common.files import atomic_open

    statics = [p for p in report.poses if p.get("kind", "static") == "static"]
    rotations = [p for p in report.poses if "angle_error_deg" in p]
    fig, axes = plt.subplots(2 if rotations else 1, 1, figsize=(9, 6 if rotations else 3.5), squeeze=False)
    ax = axes[0, 0]
    # |a| - g per hold (turntable) or per interval (free): measured minus model, as every residual
    values = [float(p["norm_error"] if "norm_error" in p else p["residual"]) for p in statics]
    ax.bar(range(len(values)), values, color="tab:blue")
    ax.set_xticks(range(len(values)), [p["label"] for p in statics], rotation=90, fontsize=7)
    ax.set_ylabel("|a| - g (m/s^2)")
    ax.set_title(f"imu-station calibrate {source}: calibrated gravity magnitude per static pose")
    ax.axhline(0, color="k", lw=0.5)
    if rotations:
        ax2 = axes[1, 0]
        ax2.bar(range(len(rotations)), [p["angle_error_deg"] for p in rotations], color="tab:orange")
        ax2.set_xticks(range(len(rotations)), [p["label"] for p in rotations])
        ax2.set_ylabel("angle error (deg)")
        ax2.axhline(0, color="k", lw=0.5)
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    """Calibrate the capture, merge the sections into --output, print the report (or JSON)."""
    from station.acquisition.autopilot_log import log_notes
    from station.acquisition.capture import read_capture
    from station.common.files import output_set
    from station.common.text import PATH_CHARS, printable
    from station.console.log_notes import print_log_notes
    from station.export.params.file import merge_sections, name_unit, open_for_unit

    if args.across_temperature:
        return run_across_temperature(args)
    if len(args.input) > 1:
        if args.method != "mag" and _board_files(args.input) is not None:
            return run_board(args)
        raise StationError(f"{len(args.input)} captures given: one is calibrated at a time; give one per "
                           "soak temperature with --across-temperature (turntable method), or one per IMU "
                           "of a board (each with its '# instance: k' metadata line)")
    args.input = args.input[0]
    if args.method == "mag":
        return run_mag(args)
    if args.instance is None and _log_imus(args.input) > 1:
        return run_board(args)
    local_gravity(args)  # refuse bad options before reading a long capture
    with PhaseLine(sys.stderr) as phase:
        phase.show(f"reading {args.input}")
        capture = read_capture(args.input, args.instance)
        print_log_notes(args.input, log_notes(capture))
        device = name_unit(capture.device, args.serial)
        if args.output:
            open_for_unit(args.output, device, replace=args.replace)  # refuse before the fit
        phase.show("calibrating")
        report = calibrate_capture(capture, args)
    outputs = {}
    with output_set():  # the sections and their plot together, or neither
        if args.output:
            merge_sections(args.output, device, {"accel": report.accel, "gyro": report.gyro},
                           capture=args.input, replace=args.replace)
            written = "accel and gyro sections" if report.gyro is not None else "accel section"
            outputs[str(args.output)] = f"{written} written"
        if args.plot:
            write_plot(args.plot, report, args.input.name)
            outputs[str(args.plot)] = "written"
    if args.json:
        import json  # only --json needs it (2-4 ms of start-up)

        result = report_dict(report, str(args.input))
        result["outputs"] = outputs
        json.dump(result, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
        return ExitCode.OK
    print_report(report, sys.stdout)
    for path, what in outputs.items():
        print(f"{printable(path, PATH_CHARS)}: {what}")
    return ExitCode.OK


def _log_imus(path: Path) -> int:
    """How many IMUs the autopilot log ``path`` holds (0: not a log)."""
    from station.acquisition.autopilot_log import is_autopilot_log, open_log

    return len(open_log(path).imus) if is_autopilot_log(path) else 0


def _board_files(paths: list[Path]) -> dict[int, Path] | None:
    """The captures of one board's IMUs by their instance (a CSV's '# instance: k' line, an HDF5 file's
    device attribute), or None where one names none."""
    from station.acquisition.capture import read_capture
    from station.acquisition.capture_csv import read_csv_device

    out: dict[int, Path] = {}
    for path in paths:
        name = str(path).lower()
        if name.endswith((".csv", ".csv.gz")):
            device = read_csv_device(path)
        elif name.endswith((".h5", ".hdf5")):
            device = read_capture(path).device  # its device attribute is read with the samples
        else:
            return None
        text = str(device.get("instance", "")).strip()
        if not text.isdigit():
            return None
        if int(text) in out:
            raise StationError(f"{out[int(text)]} and {path} are both IMU instance {text}: give one capture "
                               "per IMU of the board")
        out[int(text)] = path
    return dict(sorted(out.items()))


def _board_captures(args: argparse.Namespace) -> tuple[dict[int, Capture], dict[int, Path]]:
    """Every IMU of the board, by instance: a log's IMUs, or the capture files named by instance."""
    from station.acquisition.autopilot_log import open_log
    from station.acquisition.capture import read_capture
    from station.console.log_notes import print_log_notes

    if isinstance(args.input, Path):  # one log with several IMUs
        if args.instance is not None:
            raise StationError("--instance picks one IMU; leave it out to calibrate every IMU of the board")
        log = open_log(args.input)
        captures = log.captures()
        print_log_notes(args.input, log.notes())
        return captures, dict.fromkeys(captures, args.input)
    if args.instance is not None:
        raise StationError("--instance picks an IMU of a PX4 or ArduPilot log; the captures of a board name "
                           "theirs in their '# instance:' lines: leave --instance out")
    files = _board_files(args.input) or {}
    return {k: read_capture(path) for k, path in files.items()}, files


def _board_unit(captures: dict[int, Capture], files: dict[int, Path]) -> dict[str, Any]:
    """The first IMU's unit, after checking that every capture names the same board (its serial, less a
    log's '-imu<k>')."""
    import re

    first = min(captures)
    boards = {k: re.sub(r"-imu\d+$", "", str(c.device["serial"])) for k, c in captures.items()
              if c.device.get("serial")}
    if len(set(boards.values())) > 1:
        named = ", ".join(f"{files[k]} {boards[k]}" for k in boards)
        raise StationError(f"the captures name different units ({named}): the IMUs calibrated together are "
                           "one board's")
    return dict(captures[first].device)


def run_board(args: argparse.Namespace) -> int:
    """Several IMUs of one board: calibrate each as a single capture is, then each one's rotation relative
    to the first from the first's still poses and turns; merge the first's sections and 'imus' into
    --output, print every IMU's report and the rotations (or JSON)."""
    from station.common.files import output_set
    from station.common.text import PATH_CHARS, printable
    from station.console.board_summary import print_rotations, rotation_dict
    from station.engines.calibration.imu_board import BoardImu, board_rotations
    from station.errors import EngineInputError
    from station.export.params.file import merge_sections, name_unit, open_for_unit
    from station.export.params.imus import IMUS, first_entry, other_entry

    local_gravity(args)  # refuse bad options before reading long captures
    with PhaseLine(sys.stderr) as phase:
        names = args.input if isinstance(args.input, Path) else ", ".join(str(p) for p in args.input)
        phase.show(f"reading {names}")
        captures, files = _board_captures(args)
        device = name_unit(_board_unit(captures, files), args.serial)
        if args.output:
            open_for_unit(args.output, device, replace=args.replace)  # refuse before the fits
        reports = {}
        for k, capture in captures.items():
            phase.show(f"calibrating IMU {k}")
            try:
                reports[k] = calibrate_capture(capture, args)
            except EngineInputError as exc:
                raise EngineInputError(f"IMU {k} ({files[k]}): {exc}") from None
        methods = {r.method for r in reports.values()}
        if len(methods) > 1:
            raise StationError(f"the IMUs' captures call for different methods "
                               f"({', '.join(sorted(methods))}): give every IMU's capture with the same step "
                               "labels, or none")
        phase.show("rotations between the IMUs")
        first = min(captures)
        imus = [BoardImu(k, c.t, c.acc, c.gyro, reports[k]) for k, c in captures.items()]
        rotations = board_rotations(imus, args.convention)
    entries = [first_entry(first, captures[first].device)]
    for k, rot in rotations.items():
        details = {"rotation_residual_rms": rot.residual_rms,
                   "rotation_from": f"{rot.poses} still poses, {rot.turns} turns"}
        entries.append(other_entry(k, captures[k].device, reports[k].accel, reports[k].gyro, rot.to_first,
                                   rot.sigma, details))
    outputs = {}
    with output_set():
        if args.output:
            merge_sections(args.output, device, {"accel": reports[first].accel, "gyro": reports[first].gyro,
                                                 IMUS: entries}, capture=files[first], replace=args.replace)
            outputs[str(args.output)] = (f"accel and gyro sections (IMU {first}) and the imus section "
                                         f"({len(entries)} IMUs) written")
        if args.plot:
            write_plot(args.plot, reports[first], files[first].name)
            outputs[str(args.plot)] = f"written (IMU {first})"
    if args.json:
        import json

        result = {"imus": [{"instance": k, **report_dict(reports[k], str(files[k]))} for k in reports],
                  "rotations": [rotation_dict(k, rot) for k, rot in rotations.items()], "outputs": outputs}
        json.dump(result, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
        return ExitCode.OK
    for k, report in reports.items():
        sys.stdout.write(f"=== IMU {k} ({printable(files[k], PATH_CHARS)}) ===\n")
        print_report(report, sys.stdout)
        sys.stdout.write("\n")
    print_rotations(first, rotations, sys.stdout)
    for path, what in outputs.items():
        print(f"{printable(path, PATH_CHARS)}: {what}")
    return ExitCode.OK


def _soak_of(path: Path, args: argparse.Namespace) -> tuple[Any, dict[str, Any], list[str]]:
    """Read one soak's capture and calibrate it as a single turntable capture is: the soak, the unit's
    device info, and warnings (a capture whose temperature moved)."""
    import numpy as np

    from station.acquisition.autopilot_log import log_notes
    from station.acquisition.capture import read_capture
    from station.console.log_notes import print_log_notes
    from station.engines.thermal.intrinsics_fit import SoakCalibration
    from station.errors import EngineInputError, InputFileError

    capture = read_capture(path, args.instance)
    print_log_notes(path, log_notes(capture))
    temp = None if capture.temp is None else np.asarray(capture.temp, float)
    if temp is None or not np.any(np.isfinite(temp)):
        raise InputFileError(path, "has no temperature: each capture of a calibration "
                             "across temperature is placed by its mean temperature; capture from a unit that "
                             "reports it, or add the chamber's reading as a 'temp' column", column="temp")
    try:
        report = calibrate_capture(capture, args)
    except EngineInputError as exc:
        raise EngineInputError(f"{path}: {exc}") from None
    warnings = [f"{path}: {w}" for w in report.warnings]
    spread = float(np.nanmax(temp) - np.nanmin(temp))
    if spread > MAX_SOAK_SPREAD_DEGC:
        warnings.append(f"{path}: the temperature moved {spread:.1f} degC during the capture (the unit had "
                        "not settled); it is placed at its mean")
    return SoakCalibration(float(np.nanmean(temp)), report, path.name), capture.device, warnings


def run_across_temperature(args: argparse.Namespace) -> int:
    """--across-temperature: calibrate each capture, fit across temperature, merge the accel, gyro and
    thermal sections into --output, print the soaks and figures (or JSON), write the plot."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from station.common.files import output_set, sha256_file
    from station.common.text import PATH_CHARS
    from station.console.across_temperature import across_dict, print_across
    from station.console.markup import markup_safe
    from station.engines.thermal.intrinsics_fit import MIN_SOAKS, fit_across_temperature
    from station.export.params.file import merge_sections, name_unit, open_for_unit

    if args.method not in ("auto", "turntable"):
        raise StationError(f"--across-temperature calibrates labelled turntable captures; --method "
                           f"{args.method} cannot be used with it (leave --method out, or give --method "
                           "turntable)")
    args.method = "turntable"
    if len(args.input) < MIN_SOAKS:
        raise StationError(f"--across-temperature needs captures at {MIN_SOAKS} or more soak temperatures "
                           f"(5 or more to choose the curves' order); {len(args.input)} given")
    local_gravity(args)  # refuse bad options before reading long captures
    soaks, warnings, device, had_thermal = [], [], None, False
    err = sys.stderr
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=Console(file=err), transient=True, disable=not err.isatty()) as progress:
        task = progress.add_task("calibrating each soak", total=len(args.input))
        for path in args.input:
            progress.update(task, description=f"calibrating {markup_safe(path, PATH_CHARS)}")
            soak, info, notes = _soak_of(path, args)
            unit = name_unit(info, args.serial)
            if device is None:
                device = unit
                if args.output:  # refuse another unit's file before the fits
                    had_thermal = open_for_unit(args.output, device, replace=args.replace).thermal is not None
            elif unit.get("serial") and device.get("serial") and unit["serial"] != device["serial"]:
                raise StationError(f"{path} is unit {unit['serial']}, {args.input[0]} unit "
                                   f"{device['serial']}: a calibration across temperature is of one unit")
            soaks.append(soak)
            warnings += notes
            progress.advance(task)
        progress.update(task, description="fitting across temperature")
        result = fit_across_temperature(soaks)
    result.warnings[:0] = warnings
    result.thermal.extra["across_temperature"]["soaks"] = [
        {"capture": str(path), "sha256": sha256_file(path), "temp": soak.temp}
        for path, soak in zip(args.input, soaks, strict=True)]
    plot = args.plot
    if plot is None and args.output:
        plot = args.output.with_name(args.output.name.split(".")[0] + "-across-temperature.png")
    outputs = {}
    with output_set():  # the sections and their plot together, or neither
        if args.output:
            merge_sections(args.output, device, {"accel": result.accel, "gyro": result.gyro,
                                                 "thermal": result.thermal}, replace=args.replace)
            written = ("accel, gyro and thermal sections" if result.gyro is not None
                       else "accel and thermal sections")
            replaced = "; the thermal section it held before is replaced" if had_thermal else ""
            t_ref = result.thermal.reference_temp
            outputs[str(args.output)] = f"{written} written (T_ref {t_ref:g} degC){replaced}"
        if plot is not None:
            from station.plots.across_temperature import plot_across_temperature

            names = " ".join(p.name for p in args.input)
            plot_across_temperature(result, plot, f"imu-station calibrate --across-temperature {names}")
            outputs[str(plot)] = "plot of scale, misalignment and bias against temperature written"
    if args.json:
        import json

        out = across_dict(result, [str(p) for p in args.input])
        out["outputs"] = outputs
        json.dump(out, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
        return ExitCode.OK
    console = Console(file=sys.stdout, width=160)
    print_across(result, console)
    for path, what in outputs.items():
        console.print(f"{markup_safe(path, PATH_CHARS)}: {what}")
    if not outputs:
        console.print("nothing written: give -o PARAMS.yaml for the sections, --plot FILE.png for the plot")
    return ExitCode.OK
