"""``imu-station export``: a unit's parameter file in the form a firmware or an autopilot loads."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from station.console.options import (
    EKF_RATE_HZ,
    EXPORT_FORMATS,
    EXPORT_MAX_INSTANCE,
    INFLATE,
    NOISE_EXPORT_FORMATS,
    add_output_option,
    describe_range,
    number,
)
from station.errors import ExitCode, StationError

NAME = "export"
HELP = ("write a calibration for firmware (C header + blob, PX4, ArduPilot, JSON, YAML) or the noise values "
        "for an estimator")
DESCRIPTION = """\
Write the unit's parameter file (from 'calibrate', 'allan', 'thermal') in a form firmware loads.

  c          imu_calib.h, imu_calib.c and imu_calib.bin into the directory -o: C99 that computes
             what 'imu-station apply' computes, the blob it loads, and the unit's parameters
             linked in as a const initializer
  bin        the CRC-checked parameter blob alone
  json, yaml the parameter file as a JSON or YAML document with an 'export' block
  px4        a QGroundControl .params file (CAL_ACCn_*, CAL_GYROn_*, TC_An_*, TC_Gn_*)
  ardupilot  an ArduPilot .param file (INS_ACCOFFS_*, INS_ACCSCAL_*, INS_GYROFFS_*, INS_TCALn_*)

For px4 and ardupilot the command prints what the target cannot hold (misalignment, gyro scale,
dT terms, thermal segments) with the error it leaves at the six calibration poses.

From the 'noise' section ('allan'), the noise values an estimator takes (largest axis):
  ekf2       PX4 EKF2 .params: EKF2_GYR_NOISE, EKF2_ACC_NOISE, EKF2_GYR_B_NOISE, EKF2_ACC_B_NOISE,
             N / sqrt(dt) and K / sqrt(dt) for the filter's step dt (10 ms; --ekf-rate)
  ekf3       ArduPilot EKF3 .param: EK3_GYRO_P_NSE, EK3_ACC_P_NSE, EK3_GBIAS_P_NSE, EK3_ABIAS_P_NSE
             (dt 12 ms)
  openvins   OpenVINS kalibr_imu_chain.yaml (continuous densities N and K)
  kalibr, vins, orbslam3  as 'allan --kalibr/--vins/--orbslam3'
Every value is multiplied by --inflate K (default 1, as measured), and the factor is printed with
its reason every time: a still bench record underestimates vibration, temperature and misalignment
in flight (Kalibr: 10x or more for low-cost MEMS; OpenVINS: 10-20x)."""
EPILOG = """\
examples:
  imu-station export unit.yaml --format c -o firmware/calib
  imu-station export unit.yaml --format px4 -o unit.params --device-id 1310988
  imu-station export unit.yaml --format ardupilot -o unit.param --json
  imu-station export unit.yaml --format ekf2 -o ekf2_noise.params --inflate 10"""

INT32_MAX = 2**31 - 1
DEVICE_ID = number(int, 0, INT32_MAX, unit="the autopilots' int32 range")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the export command's options to ``parser``."""
    parser.add_argument("params", metavar="PARAMS", help="the unit's parameter file (YAML)")
    parser.add_argument("-f", "--format", required=True, choices=(*EXPORT_FORMATS, *NOISE_EXPORT_FORMATS),
                        help="what to write")
    add_output_option(parser, required=True, metavar="PATH", type=str,
                      help="directory for 'c'; file for the others (a directory gets imu_calib.<ext>)")
    parser.add_argument("--station-id", default=None, metavar="ID",
                        help="this station's name, stored in the blob and headers (default: host name)")
    parser.add_argument("--device-id", type=DEVICE_ID, default=None, metavar="N",
                        help="px4/ardupilot: the sensor's device id (CAL_ACCn_ID, TC_An_ID / INS_ACC_ID); "
                        "also the gyro's unless --gyro-device-id")
    parser.add_argument("--gyro-device-id", type=DEVICE_ID, default=None, metavar="N",
                        help="px4/ardupilot: the gyro's device id when it differs from the accel's")
    parser.add_argument("--instance", type=int, default=0, metavar="N",
                        help="px4/ardupilot: sensor instance, 0-based (px4 CAL_ACC0 / ardupilot first IMU), "
                        + ", ".join(f"{fmt} {describe_range(0, high)}"
                                    for fmt, high in EXPORT_MAX_INSTANCE.items())
                        + "; default 0")
    parser.add_argument("--plot", metavar="FILE.png",
                        help="px4/ardupilot: PNG of the offset the target subtracts against ours, "
                        "over temperature")
    parser.add_argument("--inflate", type=INFLATE, default=1.0, metavar="K",
                        help="noise formats: multiply every noise value written by K, 1..1000 (default 1, "
                        "the still bench values; Kalibr: 10 or more for low-cost MEMS, OpenVINS: 10-20)")
    parser.add_argument("--ekf-rate", type=EKF_RATE_HZ, default=None, metavar="HZ",
                        help="ekf2/ekf3: the filter's prediction rate (default PX4 100 Hz, EKF2_PREDICT_US "
                        "10000; ArduPilot 83.3 Hz, EKF_TARGET_DT 12 ms)")
    parser.add_argument("--rostopic", default="/imu0", metavar="TOPIC",
                        help="kalibr/openvins: the IMU topic written (default /imu0)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")


def _refuse_own_input(params: str, output: str, fmt: str) -> None:
    """Refuse an output that would replace the parameter file it is made from."""
    from station.export.writers import DEFAULT_NAMES

    source, out = Path(params), Path(output)
    targets = [out / name for name in (*DEFAULT_NAMES.values(), "imu_calib.h", "imu_calib.c")] \
        if out.is_dir() else [out]
    if source.exists() and any(t.exists() and t.samefile(source) for t in targets):
        raise StationError(f"-o {output} would overwrite the parameter file {params} it exports; "
                           "give another output path")


def run(args: argparse.Namespace) -> int:
    """Export the parameter file and print the report (text, or JSON with ``--json``)."""
    from station.common.files import output_set
    from station.export.params.file import ParamsFile
    from station.export.writers import AUTOPILOTS, MAX_INSTANCE, report_lines, write_export

    # The range depends on --format, so it is checked here rather than by argparse.
    high = MAX_INSTANCE.get(args.format, max(MAX_INSTANCE.values()))
    if not 0 <= args.instance <= high:
        raise StationError(f"--instance {args.instance} is outside the allowed range, "
                           f"{describe_range(0, high)}"
                           + (f" for {args.format}" if args.format in AUTOPILOTS else ""))
    _refuse_own_input(args.params, args.output, args.format)
    params = ParamsFile.load(args.params)
    # one set: a new header never stands beside an older unit's blob, whatever interrupts
    with output_set():
        result = write_export(params, args.format, args.output, source=args.params,
                              station_id=args.station_id, instance=args.instance, device_id=args.device_id,
                              gyro_device_id=args.gyro_device_id, plot=args.plot, inflate=args.inflate,
                              ekf_rate_hz=args.ekf_rate, rostopic=args.rostopic)
    report = result.report()
    autopilot_only = [name for name, given in (("--device-id", args.device_id is not None),
                                               ("--gyro-device-id", args.gyro_device_id is not None),
                                               ("--plot", args.plot is not None)) if given]
    if args.format not in AUTOPILOTS and autopilot_only:
        report.setdefault("notes", []).insert(0, f"{', '.join(autopilot_only)}: for px4 and ardupilot only; "
                                                 "ignored")
    noise_only = [name for name, given in (("--inflate", args.inflate != 1.0),
                                           ("--ekf-rate", args.ekf_rate is not None),
                                           ("--rostopic", args.rostopic != "/imu0")) if given]
    if args.format not in NOISE_EXPORT_FORMATS and noise_only:
        report.setdefault("notes", []).insert(0, f"{', '.join(noise_only)}: for the noise formats only; "
                                                 "ignored")
    if args.json:
        print(json.dumps(report, indent=2, allow_nan=False))
    else:
        print("\n".join(report_lines(report)))
    return ExitCode.OK
