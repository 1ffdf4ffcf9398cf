"""``imu-station apply``: correct a capture with a parameter file, as firmware will."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from station.console.options import add_instance_option, add_output_option
from station.errors import ExitCode

if TYPE_CHECKING:
    from station.acquisition.capture import Capture
    from station.export.params.file import ParamsFile

NAME = "apply"
HELP = "apply a parameter file (matrix, bias, thermal, g-sensitivity, mag) to every sample of a capture"
DESCRIPTION = """\
Correct every sample of INPUT with every section of PARAMS that is present, the way the firmware
export computes it:

    acc  = M_a^-1 (raw_a - b_a - B_a(T, dT))
    gyro = M_g^-1 (raw_g - b_g - B_g(T, dT) - G acc)
    mag  = M_m^-1 (raw_m - b_m)

B is the thermal bias of the 'thermal' section (zero without one, or where the temperature is
unknown). dT is the input's 'dtemp' column when it has one, else it is estimated from 'temp' with the
dT filter stored in the thermal section. G is the gyro's g-sensitivity (rad/s per m/s^2; zero
without one), at the corrected specific force acc. M_m and b_m are the 'mag' section's soft and
hard iron (microtesla; the field comes out in the axes the section's 'frame' names). The output is
a capture CSV with the input's columns (t, ax..gz, temp, dtemp, mx..mz, step as present), written
atomically.

exit codes: 0 done, 4 unusable parameter file or input."""
EPILOG = """\
example:
  imu-station apply unit.yaml raw.csv -o corrected.csv"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the apply command's options to ``parser``."""
    parser.add_argument("params", type=Path, metavar="PARAMS",
                        help="parameter file (YAML) written by the station")
    parser.add_argument("input", type=Path, metavar="INPUT",
                        help="capture CSV (.csv, .csv.gz), capture file (.h5), or a PX4 (.ulg) or ArduPilot "
                             "(.bin) log")
    add_instance_option(parser)
    add_output_option(parser, required=True, metavar="OUTPUT.csv", help="corrected capture CSV to write")


def _matrix_how(params: ParamsFile, triad: str, has_temp: bool) -> str:
    """How the triad's section is applied: its constant matrix, or M(T) where the thermal section has the
    triad's scale or misalignment polynomials (``station.engines.thermal.intrinsics`` equation (1))."""
    if getattr(params, triad) is None:
        return "absent (identity)"
    thermal = params.thermal
    drifts = [] if thermal is None else [
        name for name, entries in (("scale", thermal.scale), ("misalignment", thermal.misalignment))
        if triad in entries]
    if thermal is None or not drifts:
        return "matrix and bias"
    what = " and ".join(f"thermal.{d}" for d in drifts)
    if not has_temp:
        return f"matrix and bias; {what} not applied: the input has no temperature column"
    return (f"matrix M(T) at each sample's temperature ({what}, T_ref {thermal.reference_temp:g} degC) "
            "and bias")


def apply_params(params: ParamsFile, capture: Capture) -> tuple[Capture, dict[str, str]]:
    """The corrected capture and how each section was applied.

    Parameters
    ----------
    params : ParamsFile
        The parameter file; absent sections leave their triad as it is.
    capture : Capture
        The raw capture.

    Returns
    -------
    Capture
        The corrected capture, with the input's columns.
    dict of str to str
        Per section (accel, gyro, g-sensitivity, thermal, mag), how it was applied.
    """
    from station.acquisition.capture import Capture
    from station.engines.shared.correction import apply_calibration, apply_mag
    from station.engines.thermal.model import estimate_dtemp
    from station.export.params.sections import g_sensitivity, mag_calibration

    dtemp = capture.dtemp
    g_matrix = g_sensitivity(params)
    mag_cal = mag_calibration(params)
    how = {
        "accel": _matrix_how(params, "accel", capture.temp is not None),
        "gyro": _matrix_how(params, "gyro", capture.temp is not None),
        "g-sensitivity": "removed at the corrected specific force" if g_matrix is not None else "absent",
    }
    if params.thermal is None:
        how["thermal"] = "absent"
    elif capture.temp is None:
        how["thermal"] = "not applied: the input has no temperature column"
    elif dtemp is not None:
        how["thermal"] = "applied with the input's dtemp column"
    else:
        dtemp = estimate_dtemp(capture.t, capture.temp, params.thermal.dtemp_filter)
        filt = params.thermal.dtemp_filter
        how["thermal"] = f"applied with dT estimated by the file's filter ({filt.kind}, tau {filt.tau_s:g} s)"
    if mag_cal is None:
        how["mag"] = "absent" + (" (the input's field is copied)" if capture.mag is not None else "")
    elif capture.mag is None:
        how["mag"] = "not applied: the input has no mx, my, mz columns"
    else:
        how["mag"] = f"soft and hard iron, field in {mag_cal.extra.get('frame', 'sensor')} axes"
    acc, gyro = apply_calibration(capture.acc, capture.gyro, capture.temp, dtemp, params.accel, params.gyro,
                                  params.thermal, g_matrix)
    mag = None if capture.mag is None else apply_mag(capture.mag, mag_cal)
    out = Capture(t=capture.t, acc=acc, gyro=gyro, temp=capture.temp, dtemp=capture.dtemp, step=capture.step,
                  device=capture.device, source=capture.source, mag=mag)
    return out, how


def run(args: argparse.Namespace) -> int:
    """Correct the capture, write it, and say how each section was applied."""
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from station.acquisition.autopilot_log import log_notes
    from station.acquisition.capture import read_capture, require_finite
    from station.acquisition.capture_csv import write_csv
    from station.common.text import PATH_CHARS, printable
    from station.console.log_notes import print_log_notes
    from station.console.markup import markup_safe
    from station.export.params.file import ParamsFile

    params = ParamsFile.load(args.params)
    quiet = not sys.stderr.isatty()
    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                  console=Console(file=sys.stderr), transient=True, disable=quiet) as progress:
        task = progress.add_task(f"reading {markup_safe(args.input, PATH_CHARS)}", total=None)
        capture = read_capture(args.input, args.instance)
        print_log_notes(args.input, log_notes(capture))
        # a NaN would come out as a NaN corrected sample, unnoticed; temperature counts once a thermal
        # section uses it (without one, temp and dtemp are copied as they are)
        used = ("t", "acc", "gyro", *(("temp", "dtemp") if params.thermal is not None else ()))
        require_finite(capture, args.input, used, "every corrected sample is computed from it; cut the "
                       "rows without one")
        progress.update(task, description="correcting")
        corrected, how = apply_params(params, capture)
        progress.update(task, description=f"writing {markup_safe(args.output, PATH_CHARS)}")
        write_csv(args.output, corrected)
    for section, what in how.items():
        print(f"{section}: {what}")
    print(f"{printable(args.output, PATH_CHARS)}: {len(corrected)} samples written")
    return ExitCode.OK
