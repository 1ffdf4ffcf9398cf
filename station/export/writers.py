"""Every export format behind one call: ``write_export(params, fmt, out) -> ExportResult``.

The writers are kept in a table by format name (:data:`WRITERS`), as python-can keeps its log
writers by file suffix: the ``export`` command, the factory run and the TUI's results screen all
call :func:`write_export`, and a new format is one entry of the table. Each writer writes its
files atomically and returns them; :class:`ExportResult` says what was written and what the
target cannot hold, and renders the report the command prints.

A parameter file may hold any subset of sections: each format writes what it carries
(:data:`CARRIES`) and notes the sections it leaves out; only a file holding none of them is refused.

The estimators' noise files (:data:`NOISE_FORMATS`: Kalibr, VINS-Fusion, ORB-SLAM3, OpenVINS, PX4 EKF2,
ArduPilot EKF3) are written by the same call from the ``noise`` section alone, each value times the
inflation factor (``inflate``, :mod:`station.export.estimators.inflation`), which the report states with
its reason every time; :func:`noise_exports` gives the ``allan`` command the same files from a record.
"""

from __future__ import annotations

import datetime as _dt
import os
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from station.common.files import atomic_write_bytes, atomic_write_text
from station.errors import StationError
from station.export.autopilot import ardupilot, px4
from station.export.autopilot.shared import AutopilotExport, reference_temp, thermal_range
from station.export.estimators import noise_export
from station.export.estimators.noise_export import NOISE_FORMATS, EstimatorExport, build_noise_export
from station.export.firmware import c_source
from station.export.firmware.blob import CARRIED, SERIAL_SIZE, STATION_ID_SIZE, build_blob, fixed_utf8
from station.export.params import json_document
from station.export.params.file import ParamsFile
from station.export.params.sections import left_out, present
from station.plots.autopilot_loss import plot_losses

DEFAULT_NAMES = {"bin": "imu_calib.bin", "json": "imu_calib.json", "yaml": "imu_calib.yaml",
                 "px4": "imu_calib.params", "ardupilot": "imu_calib.param", **noise_export.DEFAULT_NAMES}
"""The file a format writes when ``out`` is a directory (``c`` always writes three into one)."""
AUTOPILOTS = ("px4", "ardupilot")
MAX_EPOCH_S = 253_402_300_799
"""9999-12-31T23:59:59Z, the last second an export date can name."""
MAX_INSTANCE = {"px4": px4.MAX_INSTANCE, "ardupilot": ardupilot.MAX_INSTANCE}
"""The highest sensor instance (0-based) each autopilot has parameters for."""
CARRIES: dict[str, tuple[str, ...] | None] = {"c": CARRIED, "bin": CARRIED, "json": None, "yaml": None,
                                              "px4": (*CARRIED, "imus"), "ardupilot": (*CARRIED, "imus")}
"""The sections each format writes (None: every section, the document is the file itself)."""


@dataclass(frozen=True)
class ExportSettings:
    """What every writer may need besides the parameters: who exports, when, for which sensor.

    Parameters
    ----------
    source : str
        Where the parameters came from (their file), for messages.
    station_id : str
        This station's name, stored in the blob and the headers.
    exported_utc : int
        Export time, seconds since the Unix epoch (UTC).
    instance : int
        px4/ardupilot: the sensor instance, 0-based.
    device_id, gyro_device_id : int, optional
        px4/ardupilot: the accelerometer's and the gyroscope's device ids.
    inflate : float
        Noise formats: the inflation factor of every value written.
    ekf_rate_hz : float, optional
        ekf2/ekf3: the filter's prediction rate (default the autopilot's).
    rostopic : str
        kalibr/openvins: the IMU topic.
    """

    source: str
    station_id: str
    exported_utc: int
    instance: int = 0
    device_id: int | None = None
    gyro_device_id: int | None = None
    inflate: float = 1.0
    ekf_rate_hz: float | None = None
    rostopic: str = "/imu0"

    @property
    def exported(self) -> str:
        """The export time as ISO 8601 UTC, to the second."""
        return _dt.datetime.fromtimestamp(self.exported_utc, _dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


Written = tuple[list[Path], AutopilotExport | None]
Writer = Callable[[ParamsFile, Path, ExportSettings], Written]


@dataclass
class ExportResult:
    """What :func:`write_export` wrote.

    Attributes
    ----------
    format : str
        The format (a key of :data:`WRITERS`).
    params : str
        The parameter file exported, as named by the caller.
    station_id, exported : str
        Who exported, and when (ISO 8601 UTC).
    files : list of Path
        Every file written, the loss plot last when one was asked for.
    autopilot : AutopilotExport, optional
        px4/ardupilot: the parameters, what the target cannot hold and the error it leaves.
    estimator : EstimatorExport, optional
        Noise formats: each value written, its formula and the inflation factor with its reason.
    notes : list of str
        What the caller should know (a station id or serial cut to fit the blob).
    """

    format: str
    params: str
    station_id: str
    exported: str
    files: list[Path] = field(default_factory=list)
    autopilot: AutopilotExport | None = None
    estimator: EstimatorExport | None = None
    notes: list[str] = field(default_factory=list)

    def report(self) -> dict[str, Any]:
        """The JSON-able report: format, params, station_id, exported, files, the autopilot's
        parameters, limitations and pose errors or the estimator's values and inflation, and notes."""
        out: dict[str, Any] = {"format": self.format, "params": self.params, "station_id": self.station_id,
                               "exported": self.exported, "files": [str(p) for p in self.files]}
        if self.autopilot is not None:
            out.update(self.autopilot.to_dict())
        if self.estimator is not None:
            out.update(self.estimator.to_dict())
        if self.notes:
            out["notes"] = list(out.get("notes") or []) + self.notes
        return out


def report_lines(report: dict[str, Any]) -> list[str]:
    """The report of :meth:`ExportResult.report` as the lines the command prints.

    Parameters
    ----------
    report : dict
        The report (:meth:`ExportResult.report`), possibly with notes added by the caller.

    Returns
    -------
    list of str
        The files written, the autopilot's parameters and limitations, the pose errors, an estimator's
        values and the inflation factor with its reason, the notes.
    """
    lines = [f"wrote {path}" for path in report["files"]]
    if "estimator" in report:
        lines += noise_export.value_lines(report)
    if "parameters" in report:
        lines.append(f"{len(report['parameters'])} {report['target']} parameters")
    limits = report.get("limitations") or []
    if limits:
        lines.append(f"what {report['target']} cannot hold, and the error it leaves:")
        for lim in limits:
            size = f"{lim['size']:10.3g} {lim['unit']:<6}"
            lines.append(f"  {lim['triad']:<5} {lim['what']:<26} {size} {lim['detail']}")
    for name, e in (report.get("pose_errors") or {}).items():
        poses = ", ".join(f"{p} {v:.3g}" for p, v in zip(e["poses"], e["at_reference"], strict=True))
        if "temperature_range" not in e:  # the magnetometer: no thermal model, a field of field_norm
            lines.append(f"  {name} error at the six field directions, |B| {e['field_norm']:g} {e['unit']} "
                         f"({e['unit']}): {poses}")
            continue
        lines.append(f"  {name} error at the six poses at {e['reference_temp']:g} degC ({e['unit']}): "
                     f"{poses}; worst over {e['temperature_range'][0]:g}..{e['temperature_range'][1]:g} "
                     f"degC: {e['over_temperature']:.3g}")
    lines += [f"note: {note}" for note in report.get("notes") or []]
    return lines


def export_time() -> int:
    """Now, or SOURCE_DATE_EPOCH when set, so a build can regenerate identical files.

    Returns
    -------
    int
        Seconds since the Unix epoch (UTC).

    Raises
    ------
    StationError
        SOURCE_DATE_EPOCH is set but is not a whole number of seconds from 1970 to 9999.
    """
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch:
        try:
            seconds = int(epoch)
        except ValueError:
            seconds = -1
        if not 0 <= seconds <= MAX_EPOCH_S:
            raise StationError(f"SOURCE_DATE_EPOCH={epoch!r} is not a number of seconds in 0..{MAX_EPOCH_S} "
                               "(1970 to 9999); unset it or fix it")
        return seconds
    return int(_dt.datetime.now(_dt.UTC).timestamp())


def _nothing_to_export(source: str, fmt: str, held: list[str]) -> StationError:
    holds = f"holds only {', '.join(held)}" if held else "holds no section"
    noise = (f" (its noise values for an estimator: --format {', '.join(NOISE_FORMATS)})" if "noise" in held
             else "")
    return StationError(f"{source}: {holds}; --format {fmt} writes the accel, gyro, thermal and mag "
                        "sections, so there is nothing to export; run 'imu-station calibrate' (--method mag "
                        "for the magnetometer) or 'imu-station thermal' first, or export it with --format "
                        f"json or yaml{noise}")


def _file_target(out: Path, fmt: str) -> Path:
    return out / DEFAULT_NAMES[fmt] if out.is_dir() else out


def _write_c(params: ParamsFile, out: Path, settings: ExportSettings) -> Written:
    if out.exists() and not out.is_dir():
        raise StationError(f"{out}: is a file; --format c writes three files into a directory")
    return c_source.write_c_export(params, out, settings.station_id, settings.exported_utc), None


def _write_bin(params: ParamsFile, out: Path, settings: ExportSettings) -> Written:
    path = _file_target(out, "bin")
    atomic_write_bytes(path, build_blob(params, settings.station_id, settings.exported_utc))
    return [path], None


def _write_json(params: ParamsFile, out: Path, settings: ExportSettings) -> Written:
    path = _file_target(out, "json")
    atomic_write_text(path, json_document.render_json(params, settings.station_id, settings.exported))
    return [path], None


def _write_yaml(params: ParamsFile, out: Path, settings: ExportSettings) -> Written:
    path = _file_target(out, "yaml")
    atomic_write_text(path, json_document.render_yaml(params, settings.station_id, settings.exported))
    return [path], None


def _autopilot_writer(fmt: str, build: Callable[..., AutopilotExport],
                      render: Callable[[AutopilotExport, ParamsFile, str, str], str]) -> Writer:
    def write(params: ParamsFile, out: Path, settings: ExportSettings) -> Written:
        device_id, gyro_device_id = settings.device_id, settings.gyro_device_id
        recorded = params.device.get("accel_device_id")
        # A board file's IMUs carry their own ids (station.export.autopilot.board).
        if device_id is None and recorded is not None and "imus" not in params.other:
            # The sensor the file was calibrated from (an autopilot log's IMU): its parameters bind to it.
            device_id = int(recorded)
            gyro = params.device.get("gyro_device_id")
            gyro_device_id = int(gyro) if gyro_device_id is None and gyro is not None else gyro_device_id
        try:
            result = build(params, settings.instance, device_id, gyro_device_id)
        except ValueError as exc:
            raise StationError(str(exc)) from None
        if device_id is not None and settings.device_id is None:
            gyro_id = gyro_device_id if gyro_device_id is not None else device_id
            result.notes.append(f"device ids from {settings.source}'s device section (the log's IMU): "
                                f"accel {device_id}, gyro {gyro_id}")
        if not result.params:
            raise _nothing_to_export(settings.source, fmt, present(params))
        path = _file_target(out, fmt)
        atomic_write_text(path, render(result, params, settings.station_id, settings.exported))
        return [path], result

    return write


WRITERS: dict[str, Writer] = {
    "c": _write_c,
    "bin": _write_bin,
    "json": _write_json,
    "yaml": _write_yaml,
    "px4": _autopilot_writer("px4", px4.build_px4, px4.render_px4),
    "ardupilot": _autopilot_writer("ardupilot", ardupilot.build_ardupilot, ardupilot.render_ardupilot),
}
"""The writer of each format: ``writer(params, out, settings) -> (files, autopilot export or None)``."""
FORMATS = tuple(WRITERS)
"""The formats of the unit's calibration; the estimators' noise files are :data:`NOISE_FORMATS`."""


def _write_noise(params: ParamsFile, fmt: str, out: Path, settings: ExportSettings) -> EstimatorExport:
    """An estimator's noise file from the ``noise`` section, refused without one."""
    result = build_noise_export(fmt, params.noise, params.device, factor=settings.inflate,
                                ekf_rate_hz=settings.ekf_rate_hz, rostopic=settings.rostopic,
                                station_id=settings.station_id, exported=settings.exported,
                                source=settings.source)
    atomic_write_text(_file_target(out, fmt), result.text)
    return result


def noise_exports(noise: dict[str, Any], device: dict[str, Any] | None, requests: dict[str, Path], *,
                  inflate: float = 1.0, ekf_rate_hz: float | None = None, rostopic: str = "/imu0",
                  station_id: str | None = None) -> dict[Path, EstimatorExport]:
    """The estimators' noise files asked of the ``allan`` command, built (not written) from its section.

    Parameters
    ----------
    noise : dict
        The noise section just computed.
    device : dict, optional
        The unit, for the PX4 and ArduPilot headers.
    requests : dict
        Format (:data:`NOISE_FORMATS`) -> the path it goes to.
    inflate, ekf_rate_hz, rostopic :
        As :func:`write_export`'s.
    station_id : str, optional
        This station's name (default: the host name).

    Returns
    -------
    dict
        Path -> :class:`EstimatorExport` (its ``text`` to write, its values and inflation to print).
    """
    exported = ExportSettings(source="", station_id="", exported_utc=export_time()).exported
    station = station_id if station_id is not None else socket.gethostname()
    return {Path(path): build_noise_export(fmt, noise, device, factor=inflate, ekf_rate_hz=ekf_rate_hz,
                                           rostopic=rostopic, station_id=station, exported=exported)
            for fmt, path in requests.items()}


def _cut_notes(params: ParamsFile, station_id: str) -> list[str]:
    notes = []
    for what, text, size in (("station id", station_id, STATION_ID_SIZE),
                             ("unit serial", str(params.device.get("serial", "")), SERIAL_SIZE)):
        if len(text.encode("utf-8")) >= size:
            kept = fixed_utf8(text, size, what).decode("utf-8")
            notes.append(f"the {what} is cut to {size - 1} bytes in the blob: {kept!r}")
    return notes


def write_export(params: ParamsFile, fmt: str, out: str | Path, *, source: str | Path = "<params>",
                 station_id: str | None = None, exported_utc: int | None = None, instance: int = 0,
                 device_id: int | None = None, gyro_device_id: int | None = None,
                 plot: str | Path | None = None, inflate: float = 1.0, ekf_rate_hz: float | None = None,
                 rostopic: str = "/imu0") -> ExportResult:
    """Write ``params`` in format ``fmt`` to ``out``.

    Parameters
    ----------
    params : ParamsFile
        The unit's parameters.
    fmt : str
        One of :data:`FORMATS` (c, bin, json, yaml, px4, ardupilot) or :data:`NOISE_FORMATS` (kalibr,
        vins, orbslam3, openvins, ekf2, ekf3).
    out : str or Path
        A directory for ``c`` (created if missing); for the others a file, or a directory that
        gets the format's default name (:data:`DEFAULT_NAMES`).
    source : str or Path
        Where ``params`` came from, for messages and the report.
    station_id : str, optional
        This station's name (default: the host name).
    exported_utc : int, optional
        Export time in seconds since the epoch (default: :func:`export_time`).
    instance : int
        px4/ardupilot: the sensor instance, 0-based, at most :data:`MAX_INSTANCE` of the format.
    device_id, gyro_device_id : int, optional
        px4/ardupilot: the accelerometer's device id (also the gyroscope's unless ``gyro_device_id``).
    plot : str or Path, optional
        px4/ardupilot: a PNG of the offset the target subtracts against ours, over temperature.
    inflate : float
        Noise formats: the factor (1 to ``inflation.MAX_FACTOR``) every value is multiplied by.
    ekf_rate_hz : float, optional
        ekf2/ekf3: the filter's prediction rate (default PX4's 100 Hz, ArduPilot's 83.3 Hz).
    rostopic : str
        kalibr/openvins: the IMU topic written.

    Returns
    -------
    ExportResult
        The files written, the autopilot's parameters and limitations or the estimator's values with
        the inflation factor and its reason, and notes.

    Raises
    ------
    StationError
        An unknown format, parameters with nothing to export (for a noise format: no noise section, or
        a term it does not show), an inflation factor below 1, an instance the target has no parameters
        for, an output path of the wrong kind, or a file that cannot be written.
    """
    if fmt in NOISE_FORMATS:
        settings = ExportSettings(source=str(source),
                                  station_id=station_id if station_id is not None else socket.gethostname(),
                                  exported_utc=export_time() if exported_utc is None else exported_utc,
                                  inflate=inflate, ekf_rate_hz=ekf_rate_hz, rostopic=rostopic)
        estimator = _write_noise(params, fmt, Path(out), settings)
        return ExportResult(format=fmt, params=settings.source, station_id=settings.station_id,
                            exported=settings.exported, files=[_file_target(Path(out), fmt)],
                            estimator=estimator)
    if fmt not in WRITERS:
        raise StationError(f"unknown export format {fmt!r}; known: {', '.join((*FORMATS, *NOISE_FORMATS))}")
    carried = CARRIES[fmt]
    held = present(params)
    if carried is not None and not set(held) & set(carried):
        raise _nothing_to_export(str(source), fmt, held)
    settings = ExportSettings(source=str(source),
                              station_id=station_id if station_id is not None else socket.gethostname(),
                              exported_utc=export_time() if exported_utc is None else exported_utc,
                              instance=instance, device_id=device_id, gyro_device_id=gyro_device_id)
    files, autopilot = WRITERS[fmt](params, Path(out), settings)
    result = ExportResult(format=fmt, params=settings.source, station_id=settings.station_id,
                          exported=settings.exported, files=list(files), autopilot=autopilot)
    if autopilot is not None and plot is not None:
        if params.accel is None and params.gyro is None:
            result.notes.append(f"--plot {plot}: not written, the file has no accel or gyro offsets to draw")
        else:
            if autopilot.offsets is None:
                raise ValueError("the export carries no offset function to plot")
            plot_losses({"accel": params.accel, "gyro": params.gyro}, params.thermal, autopilot.target,
                        autopilot.offsets, thermal_range(params), reference_temp(params), plot)
            result.files.append(Path(plot))
    if carried is not None:
        skipped = left_out(params, carried, fmt)
        if skipped is not None:
            result.notes.append(skipped)
    if fmt in ("c", "bin"):
        result.notes += _cut_notes(params, settings.station_id)
    return result
