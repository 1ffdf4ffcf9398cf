"""A unit's calibration certificate: one self-contained HTML page (styles inline, plots inline SVG).

It holds the unit, the station and its version, the date, the operator or station id, the method
and sequence, the SHA-256 of every file the calibration rests on, every parameter with its 1-sigma
in the units people read, each measurement against its limit, and the plots of the sections the
parameter file has. What the file or the record lacks is said on the page, not silently left out.
"""

from __future__ import annotations

import datetime as _dt
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import station
from station.common.files import atomic_write_text, sha256_file
from station.engines.magnetometer.calibration import WARN_COVERAGE
from station.errors import StationError
from station.export.params.file import SECTIONS, ParamsFile
from station.factory.records import Measurement, RunRecord
from station.plots import certificate as cert_plots
from station.plots.certificate import Samples
from station.report import parameters
from station.report.attachments import CERTIFICATE_NAME, PARAMS_ATTACHMENT
from station.report.datasheet import datasheet_rows
from station.report.equipment import ambient, equipment
from station.report.html import number, render, with_sigma
from station.report.layout import grouped, sequence_of
from station.report.thermal_table import coefficient_tables, thermal_rows

REPORTED_SECTIONS = (*SECTIONS, "mag", "characterisation")
"""The parameter file's sections a certificate shows; one absent is named as absent."""


@dataclass
class CaptureFile:
    """A capture given to the certificate: where it is, its SHA-256 and its samples."""

    path: str
    sha256: str
    samples: Samples


@dataclass
class Certificate:
    """Everything a certificate is made from; :func:`render_certificate` turns it into the page.

    ``params`` may be None (a record whose parameter file is gone); ``measurements`` are judged
    against their limits already (a factory record's, or a plan's); ``notes`` are what the page
    says is missing or wrong (absent sections, missing attachments).
    """

    params: ParamsFile | None
    params_path: str = ""
    params_sha256: str = ""
    record: RunRecord | None = None
    measurements: list[Measurement] = field(default_factory=list)
    captures: list[CaptureFile] = field(default_factory=list)
    station: str = ""
    operator: str = ""
    plan: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    on_stage: Callable[[str], None] | None = None
    """Told what long step starts (an Allan curve of hours of samples), for a progress line."""

    def stage(self, text: str) -> None:
        """Report a long step to :attr:`on_stage`, if anyone listens."""
        if self.on_stage is not None:
            self.on_stage(text)


def _utc_now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _when(stamp: str) -> str:
    """A stored UTC time (``2026-11-26T16:47:21.151209Z``) as people read it; as given when it is not one."""
    try:
        moment = _dt.datetime.fromisoformat(stamp.replace("Z", "+00:00"))
    except ValueError:
        return stamp or "not recorded"
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=_dt.UTC)
    return moment.astimezone(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _section_capture(cert: Certificate, section: str) -> CaptureFile | None:
    """The given capture the section was computed from: the one whose SHA-256 its ``sources`` entry names."""
    if cert.params is None:
        return None
    wanted = (cert.params.sources.get(section) or {}).get("sha256")
    return next((c for c in cert.captures if wanted and c.sha256 == wanted), None)


def _data_files(cert: Certificate) -> list[dict[str, str]]:
    """Every file the calibration rests on, with its SHA-256 and whether it is at hand and intact."""
    files: list[dict[str, str]] = []
    if cert.params_path:
        files.append({"what": "parameter file", "path": cert.params_path, "sha256": cert.params_sha256,
                      "state": "read" if cert.params is not None else (
                          "unreadable" if Path(cert.params_path).exists() else "missing")})
    if cert.params is not None:
        for section, source in cert.params.sources.items():
            if source.get("sha256"):
                given = any(c.sha256 == source["sha256"] for c in cert.captures)
                files.append({"what": f"capture of section {section}",
                              "path": str(source.get("capture", "")), "sha256": str(source["sha256"]),
                              "state": "given, matches" if given else "named"})
    if cert.record is not None:
        problems = " ".join(cert.record.verify())
        for a in cert.record.attachments():
            path = str(Path(cert.record.files_dir) / a.path)
            if a.name == CERTIFICATE_NAME or path == cert.params_path:  # itself; the parameter file is listed
                continue
            state = "missing" if f"{path}: missing" in problems else (
                "altered" if f"{path}: SHA-256" in problems else "intact")
            files.append({"what": a.name, "path": path, "sha256": a.sha256, "state": state})
    listed = {f["sha256"] for f in files}
    files += [{"what": "capture given", "path": c.path, "sha256": c.sha256, "state": "given"}
              for c in cert.captures if c.sha256 not in listed]
    return files


def _sections(cert: Certificate) -> list[dict[str, Any]]:
    """The parameter tables, section by section, in the order of the spec: each row a quantity with its
    x, y, z cells (value \u00b1 1-sigma), the notes gathered below the table."""
    params = cert.params
    if params is None:
        return []
    out = []
    held = params.other.get("imus")
    imus: list[dict[str, Any]] = held if isinstance(held, list) else []
    first = f", IMU {imus[0]['instance']}" if len(imus) > 1 else ""
    for name in ("accel", "gyro"):
        cal = getattr(params, name)
        if cal is not None:
            section = ParamsFile(accel=cal).to_dict()["accel"]
            out.append({"name": name, "title": f"{parameters.SENSOR_NAMES[name]} ({name}){first}",
                        "method": cal.method, **grouped(parameters.sensor_rows(name, section))})
    out += _board_sections(imus)
    mag = params.other.get("mag")
    if isinstance(mag, dict):
        out.append({"name": "mag", "title": "magnetometer (mag)",
                    "method": " \u00b7 ".join(str(v) for v in (mag.get("method"), f"frame {mag.get('frame')}")
                                               if v and v != "frame None"),
                    **grouped(parameters.mag_rows(mag))})
    if params.noise:
        out.append({"name": "noise", "title": "noise terms (noise, Allan deviation)",
                    "method": str(params.noise.get("method") or ""),
                    **grouped(parameters.noise_rows(params.noise))})
        kalibr = parameters.kalibr_rows(params.noise)
        if kalibr:
            out.append({"name": "kalibr",
                        "title": "filter noise parameters (Kalibr imu.yaml, VINS-Fusion, ORB-SLAM3)",
                        "method": "continuous-time densities in the units those tools read",
                        **grouped(kalibr)})
    if params.thermal is not None:
        out.append({"name": "thermal", "title": "temperature compensation (thermal)",
                    "method": str(params.thermal.extra.get("method") or ""),
                    **grouped(thermal_rows(params.thermal))})
    return out


def _board_sections(imus: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A board's other IMUs (the file's ``imus``): each one's rotation relative to the first with its
    1-sigma, then its accelerometer and gyroscope tables."""
    out: list[dict[str, Any]] = []
    if len(imus) < 2:
        return out
    first = int(imus[0]["instance"])
    for k, entry in enumerate(imus[1:], start=1):
        instance = int(entry["instance"])
        out.append({"name": f"imus{k}-rotation",
                    "title": f"IMU {instance} relative to IMU {first} (imus[{k}])",
                    "method": str(entry.get("rotation_from") or ""),
                    **grouped(parameters.rotation_rows(entry, first))})
        for name in ("accel", "gyro"):
            if isinstance(entry.get(name), dict):
                out.append({"name": f"imus{k}-{name}",
                            "title": f"{parameters.SENSOR_NAMES[name]} ({name}), IMU {instance}",
                            "method": str(entry[name].get("method") or ""),
                            **grouped(parameters.sensor_rows(name, entry[name]))})
    return out


def _datasheet(params: ParamsFile | None) -> tuple[list[dict[str, Any]], list[str]]:
    """The unit's datasheet figures (``station.report.datasheet``): per axis value and 1-sigma or interval,
    and what measured them as numbered notes (a long source in a cell wrapped it over many lines)."""
    if params is None:
        return [], []
    rows: list[dict[str, Any]] = []
    sources: list[str] = []
    for row in datasheet_rows(params.to_dict()):
        cells = []
        for value, unc in zip(row.values, row.uncertainty, strict=True):
            if value is None:
                cells.append(number(None))
            elif isinstance(unc, list | tuple):
                cells.append(f"{number(value)} [{number(unc[0])}, {number(unc[1])}]")
            else:
                cells.append(with_sigma(value, unc))
        source = row.measured_by + (f" [{row.interval}]" if row.interval else "")
        if source not in sources:
            sources.append(source)
        rows.append({"figure": row.figure, "unit": row.unit, "cells": cells,
                     "source": sources.index(source) + 1})
    return rows, sources


def _mag_warnings(mag: Any) -> list[str]:
    """What ``calibrate --method mag`` warned of that the section still shows: a coverage below the
    engine's warning level (the missing directions need the capture; the CLI printed them)."""
    if not isinstance(mag, dict) or not isinstance(mag.get("coverage"), int | float):
        return []
    if mag["coverage"] >= WARN_COVERAGE:
        return []
    leans = ("the fit leans on the dip constraint" if mag.get("frame") == "accel"
             else "the soft iron is poorly determined without a gravity reference")
    return [f"magnetometer: the field directions cover {mag['coverage']:.0%} of the sphere "
            f"(below {WARN_COVERAGE:.0%}): {leans}"]


def _plots(cert: Certificate) -> tuple[list[dict[str, Any]], list[str]]:
    """The plots the parameter file and the captures allow, and a note for each one they do not."""
    params = cert.params
    plots: list[dict[str, Any]] = []
    notes: list[str] = []
    if params is None:
        return plots, notes
    if params.accel is not None:
        labelled = _section_capture(cert, "accel") or next(
            (c for c in cert.captures if cert_plots.pose_residuals(c.samples, params)), None)
        residuals = cert_plots.pose_residuals(labelled.samples, params) if labelled is not None else []
        if residuals:
            plots.append({"title": "Residuals per pose", "svg": cert_plots.residuals_svg(residuals),
                          "caption": f"from {labelled.path}" if labelled else ""})
        else:
            notes.append("residuals per pose: give the calibration's labelled capture (--capture FILE)")
    if params.noise and any(isinstance(params.noise.get(s), dict) for s in ("gyro", "accel")):
        still = _section_capture(cert, "noise")
        if still is not None:
            cert.stage(f"Allan deviation of {still.path} ({len(still.samples)} samples)")
        curve = cert_plots.measured_allan(still.samples) if still is not None else None
        if curve is not None and still is not None:
            caption = f"measured curve with its 68 % interval from {still.path}"
        else:
            caption = "model only: the curve needs the still capture the noise section names (--capture)"
        plots.append({"title": "Allan deviation", "svg": cert_plots.allan_svg(params.noise, curve),
                      "caption": caption})
    if params.thermal is not None and (params.thermal.accel is not None or params.thermal.gyro is not None):
        sweep = _section_capture(cert, "thermal")
        if sweep is not None:
            cert.stage(f"block means of the temperature sweep {sweep.path}")
        points = cert_plots.thermal_points(sweep.samples, params) if sweep is not None else {}
        if points and sweep is not None:
            caption = (f"the fitted model as firmware evaluates it; dots: {cert_plots.THERMAL_BLOCK_S:g} s "
                       f"block means of {sweep.path}, each pose's constant removed")
        else:
            caption = "the fitted model as firmware evaluates it (the sweep the thermal section names, given "
            caption += "with --capture, adds its block means)"
        plots.append({"title": "Bias against temperature", "svg": cert_plots.thermal_svg(params, points),
                      "caption": caption})
    if params.thermal is not None and (params.thermal.scale or params.thermal.misalignment):
        plots.append({"title": "Scale factor and misalignment against temperature",
                      "svg": cert_plots.intrinsics_svg(params),
                      "caption": "the calibration across temperature as the thermal section holds it, about "
                                 f"{params.thermal.reference_temp:g} degC; dashed where T is clamped"})
    campaign = (params.other.get("characterisation") or {}).get("across_temperature") or {}
    if campaign.get("turn_on"):
        plots.append({"title": "Turn-on repeatability across temperature",
                      "svg": cert_plots.turn_on_svg(campaign),
                      "caption": "1-sigma of the turn-on bias over the power-ups at each soak of the "
                                 "campaign"})
    mag = params.other.get("mag")
    if isinstance(mag, dict):
        source = _section_capture(cert, "mag") or next(
            (c for c in cert.captures if c.samples.mag is not None), None)
        if source is not None and source.samples.mag is not None:
            plots.append({"title": "Magnetometer coverage and corrected sphere",
                          "svg": cert_plots.mag_svg(mag, source.samples.mag),
                          "caption": f"from {source.path}"})
        else:
            notes.append("magnetometer sphere: give the magnetometer capture (--capture FILE)")
    return plots, notes


def _unit(cert: Certificate) -> dict[str, str]:
    device: dict[str, Any] = {}
    if cert.record is not None:
        device.update({k: v for k, v in cert.record.device.items() if v is not None})
        device.setdefault("serial", cert.record.serial)
    if cert.params is not None:
        device.update({k: v for k, v in cert.params.device.items() if v is not None})
    return {k: str(device.get(k) or "not known") for k in ("serial", "model", "firmware")}


def revision(cert: Certificate) -> str:
    """The certificate's revision: the first 12 hex digits of the SHA-256 of what it certifies (the
    parameter file's bytes, else the factory record's run id), so the same calibration always gives
    the same revision and any change to it a new one."""
    if cert.params_sha256:
        return cert.params_sha256[:12]
    if cert.record is not None:
        return cert.record.run_id[:12]
    return "none"


def _roles(cert: Certificate) -> dict[str, str]:
    """Each given capture's path to the sections computed from it (``accel and gyro``)."""
    roles: dict[str, list[str]] = {}
    if cert.params is not None:
        for section, source in cert.params.sources.items():
            wanted = source.get("sha256")
            match = next((c for c in cert.captures if wanted and c.sha256 == wanted), None)
            if match is not None:
                roles.setdefault(match.path, []).append(section)
    return {path: " and ".join(sections) for path, sections in roles.items()}


def certificate_context(cert: Certificate) -> dict[str, Any]:
    """The template's variables: unit, run, files, results, parameter tables, plots and what is absent.

    Parameters
    ----------
    cert : Certificate

    Returns
    -------
    dict
    """
    params = cert.params
    notes = list(cert.notes)
    if params is not None:
        present = {s for s in REPORTED_SECTIONS if getattr(params, s, None) or params.other.get(s)}
        absent = [s for s in REPORTED_SECTIONS if s not in present]
        if absent:
            notes.append("the parameter file has no section " + ", ".join(absent))
    warnings = _mag_warnings(params.other.get("mag") if params is not None else None)
    plots, plot_notes = _plots(cert)
    notes += plot_notes
    judged = [m for m in cert.measurements if m.outcome in ("PASS", "FAIL")]
    if not judged:
        notes.append("no measurement was judged against limits (give --plan PLAN.yaml, or --db for a "
                     "factory record)")
    record = cert.record
    methods = [f"{s}: {getattr(params, s).method}" for s in ("accel", "gyro")
               if params is not None and getattr(params, s) is not None and getattr(params, s).method]
    calibrated = (record.end or record.start) if record is not None else (params.created if params else "")
    if record is not None:
        verdict = record.outcome
    elif judged:
        verdict = "FAIL" if any(m.outcome == "FAIL" for m in judged) else "PASS"
    else:
        verdict = "NOT JUDGED"
    plan = cert.plan or (record.plan if record is not None else {})
    labelled = _section_capture(cert, "accel") or _section_capture(cert, "gyro")
    sequence = plan.get("sequence") or (sequence_of(labelled.samples) if labelled is not None else "")
    station_id = cert.station or (record.station if record is not None else "")
    datasheet, datasheet_sources = _datasheet(params)
    unit = _unit(cert)
    return {
        "unit": unit,
        "station": station_id or f"{socket.gethostname()} (host name; --station names the station)",
        "operator": cert.operator or "",
        "version": station.__version__,
        "revision": revision(cert),
        "calibrated": _when(calibrated),
        "issued": _utc_now(),
        "run_id": record.run_id if record is not None else "",
        "reason": record.reason if record is not None else "",
        "plan": plan,
        "methods": methods,
        "sequence": sequence,
        "files": _data_files(cert),
        "measurements": judged,
        "other_measurements": [m for m in cert.measurements if m.outcome not in ("PASS", "FAIL")],
        "verdict": verdict,
        "sections": _sections(cert),
        "thermal_tables": coefficient_tables(params.thermal if params is not None else None),
        "datasheet": datasheet,
        "datasheet_sources": datasheet_sources,
        "equipment": equipment(record, plan, params.other.get("mag") if params is not None else None),
        "ambient": ambient(record, cert.captures, _roles(cert)),
        "warnings": warnings,
        "plots": plots,
        "notes": notes,
    }


def render_certificate(cert: Certificate) -> str:
    """The certificate as one self-contained HTML page.

    Parameters
    ----------
    cert : Certificate

    Returns
    -------
    str
        HTML5 with its styles inline and every plot an inline ``<svg>``; no network resource.
    """
    return render("certificate.html.j2", **certificate_context(cert))


def write_certificate(cert: Certificate, path: str | Path) -> list[str]:
    """Write the certificate's HTML to ``path`` atomically.

    Returns
    -------
    list of str
        What the page says it does not show (absent sections, missing files, plots without data).

    Raises
    ------
    StationError
        Neither a parameter file nor a record to certify.
    """
    if cert.params is None and cert.record is None:
        raise StationError("a certificate needs a parameter file or a factory record")
    context = certificate_context(cert)
    atomic_write_text(path, render("certificate.html.j2", **context))
    return list(context["warnings"]) + list(context["notes"])


def capture_file(path: str | Path, samples: Samples) -> CaptureFile:
    """A capture given to the certificate, hashed.

    Parameters
    ----------
    path : str or Path
        The capture file (its bytes are hashed).
    samples : Samples
        Its samples as read.

    Returns
    -------
    CaptureFile
    """
    return CaptureFile(str(path), sha256_file(path), samples)


def from_record(record: RunRecord, captures: list[CaptureFile] | None = None) -> Certificate:
    """The certificate of a factory record: its parameter file (if still there), measurements and files.

    Parameters
    ----------
    record : RunRecord
        The run's record (measurements with the plan's limits, attachments with SHA-256).
    captures : list of CaptureFile, optional
        The record's captures as read (the raw capture gives the residuals per pose).

    Returns
    -------
    Certificate
        ``notes`` name the attachments that are gone or altered; without its parameter file the
        certificate shows the record's measurements alone.
    """
    notes = [f"attachment {p}" for p in record.verify()]
    params = None
    params_path, params_sha = "", ""
    attached = next((a for a in record.attachments() if a.name == PARAMS_ATTACHMENT), None)
    if attached is None:
        notes.append("the record lists no parameter file (the run ended before its export phase)")
    else:
        path = Path(record.files_dir) / attached.path
        params_path, params_sha = str(path), attached.sha256
        if record.attachment_file(attached) is not None and path.is_file():  # never a path out of the folder
            try:
                params = ParamsFile.load(path)
            except StationError as exc:
                notes.append(f"the parameter file cannot be read: {exc}")
    measurements = [m for m in record.measurements().values()
                    if isinstance(m.value, int | float) or m.outcome in ("PASS", "FAIL")]
    return Certificate(params, params_path, params_sha, record=record, measurements=measurements,
                       captures=list(captures or []), notes=notes)
