"""Synthetic factory records for the fleet report's tests and benchmark: a plan's measurements with limits,
several stations (one of them off-centre) over several days, some units outside the limits."""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np

from station.factory.records import Attachment, Measurement, Phase, RunRecord

# name -> (unit, low, high, mean, std): roughly what the simulated line measures
MEASUREMENTS: dict[str, tuple[str, float | None, float | None, float, float]] = {
    **{f"accel.bias.{a}": ("mg", -80.0, 80.0, 0.0, 20.0) for a in "xyz"},
    **{f"accel.scale_error.{a}": ("%", -3.0, 3.0, 0.3, 0.6) for a in "xyz"},
    **{f"accel.misalignment.{a}": ("deg", -2.0, 2.0, 0.0, 0.3) for a in ("xy", "xz", "yx", "yz", "zx", "zy")},
    "accel.residual_rms": ("m/s^2", None, 0.02, 0.004, 0.002),
    **{f"gyro.bias.{a}": ("deg/s", -2.0, 2.0, 0.0, 0.4) for a in "xyz"},
    **{f"gyro.scale_error.{a}": ("%", -3.0, 3.0, 0.1, 0.5) for a in "xyz"},
    **{f"gyro.misalignment.{a}": ("deg", -2.0, 2.0, 0.0, 0.3) for a in ("xy", "xz", "yx", "yz", "zx", "zy")},
    "link.lost_fraction": ("", None, 0.001, 0.0, 0.0),
}
STATIONS = ("line-a-1", "line-a-2", "line-a-3", "line-b-1")
OFF_STATION = "line-a-3"
"""This station's accelerometer x bias sits 1.5 of the fleet's std off (the report should show it)."""
START = _dt.datetime(2026, 11, 1, 6, 0, tzinfo=_dt.UTC)
FAILING_EVERY = 97
"""Every this many units one has an accelerometer x bias of 95 mg, beyond the 80 mg limit."""


def fleet_records(n: int, seed: int = 1, files_root: Path | None = None) -> list[RunRecord]:
    """``n`` records in time order (every 7 minutes from 1 November 2026), judged against the limits.

    With ``files_root`` each record gets a folder there and an attachment list naming a certificate
    (``certificate.html``, written as a small page) so the report can link to it.
    """
    rng = np.random.default_rng(seed)
    names = list(MEASUREMENTS)
    means = np.array([MEASUREMENTS[k][3] for k in names])
    stds = np.array([MEASUREMENTS[k][4] for k in names])
    values = means + stds * rng.standard_normal((n, len(names)))
    station_of = rng.integers(0, len(STATIONS), n)
    off = np.array([STATIONS[s] == OFF_STATION for s in station_of])
    values[off, names.index("accel.bias.x")] += 1.5 * stds[names.index("accel.bias.x")]
    values[FAILING_EVERY // 2::FAILING_EVERY, names.index("accel.bias.x")] = 95.0
    records = []
    for i in range(n):
        start = (START + _dt.timedelta(minutes=7 * i)).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        serial = f"U{i:06d}"
        measured = []
        for j, name in enumerate(names):
            unit, low, high, _, _ = MEASUREMENTS[name]
            value = float(abs(values[i, j])) if name == "link.lost_fraction" else float(values[i, j])
            ok = (low is None or value >= low) and (high is None or value <= high)
            measured.append(Measurement(name, value, unit, low, high, "PASS" if ok else "FAIL"))
        measured.append(Measurement("capture.samples", float(rng.integers(13000, 14000))))
        files_dir, attachments = "", []
        if files_root is not None:
            folder = files_root / serial
            folder.mkdir(parents=True, exist_ok=True)
            page = folder / "certificate.html"
            page.write_text(f"<!DOCTYPE html><title>{serial}</title><p>{serial}</p>\n")
            files_dir = str(folder)
            attachments = [Attachment("calibration certificate", page.name, "0" * 64, 1, "text/html")]
        record = RunRecord(serial=serial, station=STATIONS[station_of[i]],
                           plan={"name": "test-line", "sha256": "ab" * 32, "sequence": "six-position"},
                           start=start, files_dir=files_dir)
        record.phases = [Phase("calibrate", start, start, measurements=measured, attachments=attachments)]
        failed = [m.name for m in measured if m.outcome == "FAIL"]
        record.finish("FAIL" if failed else "PASS", f"outside limits: {', '.join(failed)}" if failed else "")
        record.start = start
        records.append(record)
    return records
