"""``imu-station export``: a unit's parameter file in the form a firmware or an autopilot loads."""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import socket
from pathlib import Path
from typing import Any

from station.errors import StationError
from station.export import ardupilot, c_export, json_export, px4
from station.export.autopilot import AutopilotExport
from station.export.blob import SERIAL_SIZE, STATION_ID_SIZE, build_blob, fixed_utf8
from station.export.loss_plot import plot_losses
from station.export.params_file import ParamsFile
from station.files import atomic_write_bytes, atomic_write_text

NAME = "export"
HELP = "write a calibration for firmware: C header + blob, PX4, ArduPilot, JSON or YAML"
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
dT terms, thermal segments) with the error it leaves at the six calibration poses."""
EPILOG = """\
examples:
  imu-station export unit.yaml --format c -o firmware/calib
  imu-station export unit.yaml --format px4 -o unit.params --device-id 1310988
  imu-station export unit.yaml --format ardupilot -o unit.param --json"""

FORMATS = ("c", "bin", "json", "yaml", "px4", "ardupilot")
DEFAULT_NAMES = {"bin": "imu_calib.bin", "json": "imu_calib.json", "yaml": "imu_calib.yaml",
                 "px4": "imu_calib.params", "ardupilot": "imu_calib.param"}
INT32_MAX = 2**31 - 1


def _device_id(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer (decimal or 0x hex)") from None
    if not 0 <= value <= INT32_MAX:
        raise argparse.ArgumentTypeError(f"{value} is outside 0..{INT32_MAX}, the autopilots' int32 range")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("params", metavar="PARAMS", help="the unit's parameter file (YAML)")
    parser.add_argument("-f", "--format", required=True, choices=FORMATS, help="what to write")
    parser.add_argument("-o", "--output", required=True, metavar="PATH",
                        help="directory for 'c'; file for the others (a directory gets imu_calib.<ext>)")
    parser.add_argument("--station-id", default=None, metavar="ID",
                        help="this station's name, stored in the blob and headers (default: host name)")
    parser.add_argument("--device-id", type=_device_id, default=None, metavar="N",
                        help="px4/ardupilot: the sensor's device id (CAL_ACCn_ID, TC_An_ID / INS_ACC_ID); "
                        "also the gyro's unless --gyro-device-id")
    parser.add_argument("--gyro-device-id", type=_device_id, default=None, metavar="N",
                        help="px4/ardupilot: the gyro's device id when it differs from the accel's")
    parser.add_argument("--instance", type=int, default=0, metavar="N",
                        help="px4/ardupilot: sensor instance, 0-based (px4 CAL_ACC0 / ardupilot first IMU); "
                        "default 0")
    parser.add_argument("--plot", metavar="FILE.png",
                        help="px4/ardupilot: PNG of the offset the target subtracts against ours, "
                        "over temperature")
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout")


def _export_time() -> int:
    """Now, or SOURCE_DATE_EPOCH when set, so a build can regenerate identical files."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch:
        try:
            return int(epoch)
        except ValueError:
            raise StationError(f"SOURCE_DATE_EPOCH={epoch!r} is not a number of seconds; "
                               "unset it or fix it") from None
    return int(_dt.datetime.now(_dt.UTC).timestamp())


def _iso(seconds: int) -> str:
    return _dt.datetime.fromtimestamp(seconds, _dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _file_target(output: str, fmt: str) -> Path:
    path = Path(output)
    return path / DEFAULT_NAMES[fmt] if path.is_dir() else path


def _write_autopilot(args: argparse.Namespace, params: ParamsFile, station_id: str,
                     exported: str) -> tuple[Path, AutopilotExport]:
    try:
        if args.format == "px4":
            result = px4.build_px4(params, args.instance, args.device_id, args.gyro_device_id)
            text = px4.render_px4(result, params, station_id, exported)
        else:
            result = ardupilot.build_ardupilot(params, args.instance, args.device_id, args.gyro_device_id)
            text = ardupilot.render_ardupilot(result, params, station_id, exported)
    except ValueError as exc:
        raise StationError(f"--instance: {exc}") from None
    if not result.params:
        raise StationError(f"{args.params}: no accel, gyro or thermal section, nothing to export; run "
                           "'imu-station calibrate' or 'imu-station thermal' first")
    path = _file_target(args.output, args.format)
    atomic_write_text(path, text)
    return path, result


def _print_text(report: dict[str, Any]) -> None:
    for path in report["files"]:
        print(f"wrote {path}")
    if "parameters" in report:
        print(f"{len(report['parameters'])} {report['target']} parameters")
    limits = report.get("limitations") or []
    if limits:
        print(f"what {report['target']} cannot hold, and the error it leaves:")
        for lim in limits:
            size = f"{lim['size']:10.3g} {lim['unit']:<6}"
            print(f"  {lim['triad']:<5} {lim['what']:<26} {size} {lim['detail']}")
    for name, e in (report.get("pose_errors") or {}).items():
        poses = ", ".join(f"{p} {v:.3g}" for p, v in zip(e["poses"], e["at_reference"], strict=True))
        print(f"  {name} error at the six poses at {e['reference_temp']:g} degC ({e['unit']}): {poses}; "
              f"worst over {e['temperature_range'][0]:g}..{e['temperature_range'][1]:g} degC: "
              f"{e['over_temperature']:.3g}")
    for note in report.get("notes") or []:
        print(f"note: {note}")


def run(args: argparse.Namespace) -> int:
    params = ParamsFile.load(args.params)
    empty = params.accel is None and params.gyro is None and params.thermal is None
    if empty and args.format not in ("json", "yaml"):
        raise StationError(f"{args.params}: no accel, gyro or thermal section, nothing to export; run "
                           "'imu-station calibrate' or 'imu-station thermal' first")
    station_id = args.station_id if args.station_id is not None else socket.gethostname()
    exported_utc = _export_time()
    exported = _iso(exported_utc)
    report: dict[str, Any] = {"format": args.format, "params": str(args.params), "station_id": station_id,
                              "exported": exported, "files": []}
    if args.format == "c":
        out_dir = Path(args.output)
        if out_dir.exists() and not out_dir.is_dir():
            raise StationError(f"{out_dir}: is a file; --format c writes three files into a directory")
        report["files"] = [str(p) for p in c_export.write_c_export(params, out_dir, station_id, exported_utc)]
    elif args.format == "bin":
        path = _file_target(args.output, "bin")
        atomic_write_bytes(path, build_blob(params, station_id, exported_utc))
        report["files"] = [str(path)]
    elif args.format in ("json", "yaml"):
        path = _file_target(args.output, args.format)
        render = json_export.render_json if args.format == "json" else json_export.render_yaml
        atomic_write_text(path, render(params, station_id, exported))
        report["files"] = [str(path)]
    else:
        path, result = _write_autopilot(args, params, station_id, exported)
        report["files"] = [str(path)]
        if args.plot:
            plot_losses(params, result, args.plot)
            report["files"].append(str(args.plot))
        report.update(result.to_dict())
    autopilot_only = [name for name, given in (("--device-id", args.device_id is not None),
                                               ("--gyro-device-id", args.gyro_device_id is not None),
                                               ("--plot", args.plot is not None)) if given]
    if args.format not in ("px4", "ardupilot") and autopilot_only:
        names = ", ".join(autopilot_only)
        report.setdefault("notes", []).append(f"{names}: for px4 and ardupilot only; ignored")
    if args.format in ("c", "bin"):
        for what, text, size in (("station id", station_id, STATION_ID_SIZE),
                                 ("unit serial", str(params.device.get("serial", "")), SERIAL_SIZE)):
            if len(text.encode("utf-8")) >= size:
                kept = fixed_utf8(text, size, what).decode("utf-8")
                note = f"the {what} is cut to {size - 1} bytes in the blob: {kept!r}"
                report.setdefault("notes", []).append(note)
    if args.json:
        print(json.dumps(report, indent=2, allow_nan=False))
    else:
        _print_text(report)
    return 0
