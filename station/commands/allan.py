"""``imu-station allan``: Allan deviation of a still recording and the IMU noise terms filters need."""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from station.console.options import (
    EKF_RATE_HZ,
    INFLATE,
    NOISE_EXPORT_FORMATS,
    RATE_HZ,
    add_instance_option,
    add_output_option,
    add_replace_option,
    number,
)
from station.engines.allan.terms import TERMS
from station.errors import EngineInputError, ExitCode

if TYPE_CHECKING:
    from rich.progress import Progress

NAME = "allan"
HELP = "Allan deviation of a still recording: noise terms (N, K, B, Q, R), Kalibr/VINS/ORB-SLAM3 values"
DESCRIPTION = """\
Compute the overlapping Allan deviation of every axis (gx gy gz ax ay az) of a still recording and
identify the IEEE 952 noise terms: N white noise (angle/velocity random walk), K rate random walk,
B bias instability, Q quantization, R rate ramp. N and K are always fitted; B, Q and R only where the
curve shows them. A term the record cannot show is null, with the reason (for example K when the
white-noise and random-walk lines cross beyond a twentieth of the record). Where those terms do not
describe the curve within its 68 % interval (or 10 %), every combination of them with up to three
Gauss-Markov processes (GM), the sensor's output filter and sinusoids is fitted and the simplest that
does is reported, with the range of tau where it holds (valid_tau). The Kalibr, VINS and ORB-SLAM3
values are the N and K equivalent to the whole model over --horizon.

INPUT is a capture CSV, a station capture file (.h5), a ROS 1/ROS 2 bag with sensor_msgs/Imu
(header stamps are used; needs the 'ros' extra) or a PX4 (.ulg) or ArduPilot (.bin) log (--instance
picks its IMU; what was converted is printed on stderr). Timestamps are checked: gaps, repeated and
out-of-order stamps are reported; a record missing more than --max-missing of its samples is refused.
Records of any length are processed in bounded memory (temporary files of 48 bytes per sample).

exit codes: 0 done, 4 unusable input or options."""
EPILOG = """\
examples:
  imu-station allan still.csv -o unit.yaml --plot allan.png --curve allan.csv
  imu-station allan imu.bag --topic /imu/data --kalibr imu.yaml --vins vins.yaml --json
  imu-station allan still.csv --gm gm.yaml --gm-rate 200 --horizon 600
  imu-station allan bench.ulg --instance 1 --kalibr imu.yaml"""


MAX_PER_DECADE = 1000  # beyond this the cluster sizes repeat: every integer m is already there


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the allan command's options to ``parser``."""
    parser.add_argument("input", type=Path, metavar="INPUT",
                        help="capture CSV (.csv, .csv.gz), capture file (.h5), ROS bag (.bag, ROS 2 dir) or "
                             "PX4/ArduPilot log (.ulg, .bin)")
    add_output_option(parser, metavar="PARAMS",
                      help="parameter file to write the 'noise' section into (other sections are kept; "
                           "of the same unit)")
    add_replace_option(parser)
    parser.add_argument("--curve", type=Path, metavar="FILE.csv",
                        help="write the curve: tau, gx..az, n, then EDF and 68%% interval columns per axis")
    parser.add_argument("--plot", type=Path, metavar="FILE.png", help="write the log-log plot as PNG")
    parser.add_argument("--kalibr", type=Path, metavar="FILE.yaml", help="write Kalibr's imu.yaml")
    parser.add_argument("--vins", type=Path, metavar="FILE.yaml", help="write VINS-Fusion's IMU noise lines")
    parser.add_argument("--orbslam3", type=Path, metavar="FILE.yaml", help="write the ORB-SLAM3 IMU lines")
    parser.add_argument("--openvins", type=Path, metavar="FILE.yaml",
                        help="write OpenVINS' kalibr_imu_chain.yaml")
    parser.add_argument("--ekf2", type=Path, metavar="FILE.params",
                        help="write PX4 EKF2's IMU noise (EKF2_GYR_NOISE, .._ACC_.., .._GYR_B_.., "
                             ".._ACC_B_..) as a QGroundControl .params file")
    parser.add_argument("--ekf3", type=Path, metavar="FILE.param",
                        help="write ArduPilot EKF3's IMU noise (EK3_GYRO_P_NSE, .._ACC_.., .._GBIAS_.., "
                             ".._ABIAS_..) as a .param file")
    parser.add_argument("--inflate", type=INFLATE, default=1.0, metavar="K",
                        help="multiply every value of the estimator files (Kalibr .. EKF3) by K, 1..1000 "
                             "(default 1, the still bench values; Kalibr: 10 or more for low-cost MEMS, "
                             "OpenVINS: 10-20); the factor and why is printed")
    parser.add_argument("--ekf-rate", type=EKF_RATE_HZ, metavar="HZ",
                        help="the --ekf2/--ekf3 filter's prediction rate (default PX4 100 Hz, ArduPilot "
                             "83.3 Hz)")
    parser.add_argument("--horizon", type=number(float, 0.0, 1e9, low_open=True, unit="s"), metavar="S",
                        help="time scale (s) over which the Kalibr/VINS/ORB-SLAM3 N and K cover the whole "
                             "noise model, from the sample period (default: each axis's valid_tau end); a "
                             "record that does not resolve K is asked for 20 horizons (default 100 s)")
    parser.add_argument("--gm", type=Path, metavar="FILE.yaml",
                        help="write N, K and the Gauss-Markov terms for EKF-style process noise, continuous "
                             "and discrete-time")
    parser.add_argument("--gm-rate", type=RATE_HZ, metavar="HZ",
                        help="filter rate of the --gm discrete-time terms (default: the record's rate)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    parser.add_argument("--topic", help="IMU topic of a ROS bag holding several (default: the only one)")
    add_instance_option(parser)
    parser.add_argument("--rostopic", help="rostopic for Kalibr's imu.yaml (default: --topic or /imu0)")
    parser.add_argument("--rate", type=RATE_HZ, metavar="HZ",
                        help="nominal sample rate (default: from the median timestamp step)")
    parser.add_argument("--max-missing", type=_fraction, default=0.001, metavar="FRACTION",
                        help="refuse records whose gaps miss more than this fraction of samples (0.001)")
    parser.add_argument("--per-decade", type=number(int, 1, MAX_PER_DECADE), default=10, metavar="N",
                        help=f"cluster sizes per decade of tau, 10 to {MAX_PER_DECADE} (default 10)")
    parser.add_argument("--terms", type=_terms, default=None, metavar="T,T",
                        help=f"noise terms the record must resolve on every axis, among {','.join(TERMS)}; "
                             "a record too short for them is refused (default: N and K on at least one axis "
                             "of each sensor, what Kalibr, VINS and ORB-SLAM3 take)")
    parser.add_argument("--force", action="store_true",
                        help="keep what a record too short for --terms shows (its missing terms null)")
    parser.add_argument("--workdir", type=Path, metavar="DIR",
                        help="folder for the temporary cumulative sums (default: the system's temp folder)")


def _fraction(text: str) -> float:
    """A fraction of the samples, in [0, 1)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number: give a fraction in [0, 1)") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"{text} is outside the allowed range, a fraction in [0, 1)")
    return value


def _terms(text: str) -> tuple[str, ...]:
    """``N,K``: noise terms among TERMS."""
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    unknown = [t for t in names if t not in TERMS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"{text!r}: give terms among {','.join(TERMS)}, e.g. N,K")
    return names


def _length(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 7200:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"


DEFAULT_TERMS = ("N", "K")


def refuse_short_record(noise: list, terms: tuple[str, ...] | None, duration_s: float, source: str,
                        horizon_s: float | None = None) -> None:
    """Refuse a record too short for the terms asked for, with the length it needs.

    ``terms`` (``--terms``) must be resolved on every axis; without it N and K on at least one axis
    of each sensor (the filters' files take the largest axis; a correlated bias often hides K on
    one axis for far longer than a bench records). The length asked for K is one that does not move
    as the record grows: 20 times the horizon (``--horizon``, default ``K_HORIZON_S``), the record that
    resolves every random walk adding as much as the white noise within it
    (:func:`station.engines.allan.fit.k_record_length`).

    Raises
    ------
    EngineInputError
        Naming the terms, the axes, the record's length and the length needed (exit 4).
    """
    from station.engines.allan.fit import K_HORIZON_S, missing_terms
    from station.export.params import noise as noise_file

    horizon = K_HORIZON_S if horizon_s is None else horizon_s
    missing = missing_terms(noise, terms or DEFAULT_TERMS, duration_s, horizon)
    if terms is None:
        axes_of = Counter(a.axis[0] for a in noise)  # the sensor is the axis name's first letter: g.., a..
        missing_of = Counter((m.axis[0], m.term) for m in missing)
        missing = [m for m in missing if missing_of[m.axis[0], m.term] == axes_of[m.axis[0]]]
    if not missing:
        return
    parts = []
    for term in dict.fromkeys(m.term for m in missing):
        of_term = [m for m in missing if m.term == term]
        first = of_term[0]
        # the level of the first axis's sensor, in its unit (a gyroscope's and an accelerometer's differ)
        sensor = "gyro" if first.axis.startswith("g") else "accel"
        matters = [m.matters_above for m in of_term
                   if m.matters_above is not None and m.axis[0] == first.axis[0]]
        unit = noise_file.UNITS[sensor][term][0]
        level = f"a {sensor} K of {max(matters):.2g} {unit} or more" if matters else "a random walk"
        if term != "K":
            length = "it needs a longer record (this one shows no sign of it)"
        elif first.needed_s is not None:
            length = (f"it needs a still record of at least {_length(first.needed_s)}: 20 times the "
                      f"{horizon:g} s horizon, which resolves {level}, as much as the white noise within "
                      "the horizon")
        else:
            length = (f"the record is 20 times the {horizon:g} s horizon or longer, so K is below what "
                      f"matters within it ({level} would show); take N alone (--terms N) or a longer "
                      "--horizon")
        axes = ", ".join(m.axis for m in of_term)
        parts.append(f"{term} ({noise_file.NAMES[term]}) is not resolved on {axes} "
                     f"({first.axis}: {first.reason}); {length}")
    raise EngineInputError(
        f"{source}: the record ({_length(duration_s)}) is too short for the terms asked for "
        f"({','.join(terms or DEFAULT_TERMS)}): {'; '.join(parts)}. Record longer, ask for fewer terms "
        "(--terms), or keep what it shows with --force")


def _progress(err: IO[str]) -> Progress:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=Console(file=err), transient=True, disable=not err.isatty())


def analyse(args: argparse.Namespace, err: IO[str]) -> dict[str, Any]:
    """Read, integrate, compute and fit; write every requested file; return the JSON-able result.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options.
    err : text stream
        Where the progress bars are drawn (when it is a terminal).

    Returns
    -------
    dict
        ``noise``: the parameter file's noise section; ``outputs``: each file written and what.

    Raises
    ------
    EngineInputError
        Too few points per decade, or a record missing more than --max-missing of its samples.
    """
    # the engines load here, not when --help is asked for
    from station.acquisition.allan_source import AXES, capture_chunks, integrate_stream
    from station.common.files import atomic_write_text, output_set
    from station.console.log_notes import print_log_notes
    from station.engines.allan.deviation import allan_curve, cluster_sizes
    from station.engines.allan.fit import identify_noise
    from station.engines.allan.solver import solver_ready
    from station.export.params import noise as noise_file
    from station.export.params.file import merge_sections, name_unit, open_for_unit, to_plain

    if args.per_decade < 10:
        raise EngineInputError(f"--per-decade {args.per_decade}: use at least 10 points per decade")
    chunks, device, size = capture_chunks(args.input, args.topic, args.instance)
    print_log_notes(args.input, getattr(chunks, "notes", ()), err)
    device = name_unit(device, args.serial)
    if args.output:
        open_for_unit(args.output, device, replace=args.replace)  # refuse before hours of computing
    with _progress(err) as progress:
        reading = progress.add_task("reading", total=None)
        record = integrate_stream(chunks, str(args.input), rate_hz=args.rate, workdir=args.workdir,
                                  device=device, on_rows=lambda n: progress.advance(reading, n))
        with record:
            timing = record.timing
            if timing.missing_fraction > args.max_missing:
                raise EngineInputError(
                    f"{args.input}: {'; '.join(timing.problems())}. The Allan deviation needs evenly spaced "
                    "samples: cut the record at the gap, or accept it with --max-missing "
                    f"{min(0.99, 2 * timing.missing_fraction):.3g}")
            m = cluster_sizes(record.n_samples, per_decade=args.per_decade)
            computing = progress.add_task("Allan deviation", total=None)
            curve = allan_curve(record.phase, record.rate_hz, AXES, m,
                                on_progress=lambda done, total: progress.update(computing, completed=done,
                                                                                total=total))
            if not solver_ready():  # say why this run waits: numba compiles the solver, once
                progress.console.print("compiling the noise model's solver, once per installation (about "
                                       "half a minute; ./scripts/setup does it ahead)")
            curve, noise = identify_noise(curve, record.phase)  # the likelihood of K reads the sums again
    if not args.force:
        try:
            refuse_short_record(noise, args.terms, curve.duration_s, str(args.input), args.horizon)
        except EngineInputError as refused:
            if not args.plot:
                raise
            # the curve of a refused record still shows what it resolves and how far it falls short:
            # its plot is written alone (no other file of the set: they would hold the refused terms)
            from station.plots.allan import write_png

            title = f"imu-station allan {args.input.name} (refused: too short)"
            write_png(args.plot, curve, noise, title=title)
            raise EngineInputError(f"{refused} (the plot is written to {args.plot})") from None
    source = {"source": str(args.input), "input_bytes": size, "timing": timing.as_dict(),
              "timing_problems": timing.problems()}
    section = to_plain(noise_file.noise_section(noise, curve, source, horizon_s=args.horizon))
    outputs: dict[str, str] = {}
    rostopic = args.rostopic or args.topic or "/imu0"
    requests = {fmt: getattr(args, fmt) for fmt in NOISE_EXPORT_FORMATS if getattr(args, fmt)}
    estimators = {}
    if requests:
        from station.export.writers import noise_exports

        estimators = noise_exports(section, device, requests, inflate=args.inflate, ekf_rate_hz=args.ekf_rate,
                                   rostopic=rostopic)
    texts = {path: estimator.text for path, estimator in estimators.items()}
    if args.gm:
        from station.export.estimators.gauss_markov import gm_yaml

        texts[args.gm] = gm_yaml(section, args.gm_rate)
    # one set: a new Kalibr file never stands beside the old parameter file, whatever interrupts
    with output_set():
        for path, text in texts.items():
            atomic_write_text(path, text)
            outputs[str(path)] = "written"
        if args.curve:
            noise_file.write_curve_csv(args.curve, curve)
            outputs[str(args.curve)] = "written"
        if args.plot:
            from station.plots.allan import write_png

            write_png(args.plot, curve, noise, title=f"imu-station allan {args.input.name}")
            outputs[str(args.plot)] = "written"
        if args.output:
            merge_sections(args.output, device, {"noise": section}, capture=args.input, replace=args.replace)
            outputs[str(args.output)] = "noise section written"
    result: dict[str, Any] = {"noise": section, "outputs": outputs}
    if estimators:
        result["estimators"] = {str(path): estimator.to_dict() for path, estimator in estimators.items()}
    return result


def run(args: argparse.Namespace) -> int:
    """Analyse the recording and print the noise terms (or the JSON result)."""
    from station.export.params import noise as noise_file

    result = analyse(args, sys.stderr)
    section = result["noise"]
    if args.json:
        json.dump(result, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
        return ExitCode.OK
    rec = section["record"]
    print(f"{rec['source']}: {rec['samples']} samples at {rec['rate_hz']:.6g} Hz, "
          f"{rec['duration_s'] / 3600:.3g} h; tau {rec['tau_range_s'][0]:.3g} .. "
          f"{rec['tau_range_s'][1]:.4g} s")
    for problem in rec["timing_problems"]:
        print(f"warning: {problem}")
    for line in noise_file.summary_lines(section):
        print(line)
    for path, what in result["outputs"].items():
        print(f"{path}: {what}")
    _print_estimators(result.get("estimators") or {})
    return ExitCode.OK


def _print_estimators(estimators: dict[str, dict[str, Any]]) -> None:
    """Each estimator file's values and notes, then the inflation factor and its reason (once: one factor)."""
    from station.export.estimators.noise_export import value_lines

    for path, estimator in estimators.items():
        *values, inflation = value_lines(estimator)
        print(f"{path}: {values[0]}")
        print("\n".join([*values[1:], *(f"note: {note}" for note in estimator.get("notes") or [])]))
    if estimators:
        print(inflation)
