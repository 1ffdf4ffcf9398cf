"""The fleet report: every measurement across the records a query selects, against the plan's limits.

Per measurement: n, mean, sample standard deviation, Cpk (:mod:`station.report.spc`), a histogram
against the limits and the individuals control chart in time order with its moving-range limits,
points beyond them flagged. Per station and per day: n, mean, range and failures, with the
measurement each group departs furthest from the fleet on. Outlier units are listed with links to
their certificates. The database does the selection, the join and the ordering
(:meth:`~station.factory.records.RecordStore.measurement_values`); numpy does the rest.
"""

from __future__ import annotations

import math
import os
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np

import station
from station.errors import StationError
from station.factory.records import RecordStore, utc_now
from station.plots.fleet_chart import chart_svg
from station.report.html import render
from station.report.spc import Capability, ControlChart, capability, individuals_chart

MAX_OUTLIERS = 200
"""Outlier units listed on the page (all of them are in --json)."""
SHIFT_FLAG = 0.5
"""A group's mean this many fleet standard deviations from the fleet's mean is flagged."""


@dataclass
class Series:
    """One measurement across the selected runs, in time order, in the unit of its latest run.

    ``values``, ``runs`` (positions in :attr:`Fleet.runs`) and ``fails`` (judged FAIL when measured)
    are parallel arrays; ``other_unit`` counts the values left out for being in another unit (a plan
    that changed the limit's unit).
    """

    name: str
    unit: str
    low: float | None
    high: float | None
    values: np.ndarray
    runs: np.ndarray
    fails: np.ndarray
    other_unit: int = 0

    @property
    def failed(self) -> int:
        """How many of the values were judged FAIL when they were measured."""
        return int(self.fails.sum())


@dataclass
class Fleet:
    """The statistics of a selection: the runs in start order (``run_id``, ``serial``, ``station``,
    ``start``), and per measurement its series, capability and control chart."""

    runs: list[tuple[str, str, str, str]]
    series: dict[str, Series]
    capability: dict[str, Capability]
    charts: dict[str, ControlChart]
    query: dict[str, Any]

    @property
    def limited(self) -> list[str]:
        """The measurements with limits (the ones charted), by name."""
        return [n for n, s in self.series.items() if s.low is not None or s.high is not None]


def _series(name: str, rows: list[tuple]) -> Series:
    """One measurement's rows ``(unit, value, low, high, run, failed)`` as a series in run order."""
    order = np.argsort(np.fromiter((r[4] for r in rows), dtype=np.int64, count=len(rows)), kind="stable")
    unit, _, low, high, _, _ = rows[order[-1]]  # the latest run's unit and limits: the plan in force now
    kept = [rows[i] for i in order if rows[i][0] == unit]
    return Series(name, unit, low, high,
                  np.fromiter((r[1] for r in kept), dtype=float, count=len(kept)),
                  np.fromiter((r[4] - 1 for r in kept), dtype=np.int64, count=len(kept)),
                  np.fromiter((r[5] for r in kept), dtype=bool, count=len(kept)),
                  len(rows) - len(kept))


def collect(store: RecordStore, query: dict[str, Any]) -> Fleet:
    """Read the selection's measurements and compute every statistic the report shows.

    Parameters
    ----------
    store : RecordStore
        SQLite or PostgreSQL.
    query : dict
        The filters: ``serial``, ``since``, ``until``, ``station``, ``outcome`` (None: any).

    Returns
    -------
    Fleet

    Raises
    ------
    StationError
        No record with a numeric measurement matches the filters.
    """
    runs = [(str(a), str(b), str(c), str(d)) for a, b, c, d in store.run_rows(**query)]
    by_name: dict[str, list[tuple]] = defaultdict(list)
    for name, unit, value, low, high, run, failed in store.measurement_values(**query):
        by_name[name].append((unit, value, low, high, run, failed))
    if not by_name:
        shown = ", ".join(f"--{k} {v}" for k, v in query.items() if v is not None)
        raise StationError(f"no record with a numeric measurement matches {shown or 'in the database'}; "
                           "widen the filters ('imu-station records' lists what is there)")
    series = {name: _series(name, by_name[name]) for name in sorted(by_name)}
    caps = {n: capability(s.values, s.low, s.high) for n, s in series.items()}
    charts = {n: individuals_chart(s.values) for n, s in series.items()}
    return Fleet(runs, series, caps, charts, dict(query))


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def breakdown(fleet: Fleet, by: str) -> dict[str, dict[str, dict[str, Any]]]:
    """Per station (or UTC day) and measurement: n, mean, min, max, FAIL count, and the shift of the
    group's mean from the fleet's in fleet standard deviations (None where the std is zero).

    Parameters
    ----------
    fleet : Fleet
    by : str
        ``station`` or ``day``.

    Returns
    -------
    dict
        Group -> measurement name -> statistics.
    """
    names, code = np.unique(np.array([r[2] if by == "station" else r[3][:10] for r in fleet.runs]),
                            return_inverse=True)
    groups = [str(g) for g in names]
    out: dict[str, dict[str, dict[str, Any]]] = {g: {} for g in groups}
    for name, s in fleet.series.items():
        g = code[s.runs]
        n = np.bincount(g, minlength=len(groups))
        total = np.bincount(g, weights=s.values, minlength=len(groups))
        fails = np.bincount(g, weights=s.fails.astype(float), minlength=len(groups))
        lo = np.full(len(groups), np.inf)
        hi = np.full(len(groups), -np.inf)
        np.minimum.at(lo, g, s.values)
        np.maximum.at(hi, g, s.values)
        cap = fleet.capability[name]
        spread = cap.std if math.isfinite(cap.std) and cap.std > 0 else None
        for k in np.flatnonzero(n):
            mean = float(total[k] / n[k])
            out[groups[k]][name] = {"n": int(n[k]), "mean": mean, "min": float(lo[k]), "max": float(hi[k]),
                                    "failed": int(fails[k]),
                                    "shift_sigma": None if spread is None else (mean - cap.mean) / spread}
    return out


def outliers(fleet: Fleet) -> list[dict[str, Any]]:
    """Runs with a measurement outside its limits or beyond its control limits, in time order."""
    found: dict[int, dict[str, list[str]]] = defaultdict(lambda: {"failed": [], "beyond": []})
    for name, s in fleet.series.items():
        chart = fleet.charts[name]
        for k in np.flatnonzero(chart.beyond):
            found[int(s.runs[k])]["beyond"].append(name)
        for k in np.flatnonzero(s.fails):
            found[int(s.runs[k])]["failed"].append(name)
    out = []
    for i in sorted(found):
        run_id, serial, station_id, start = fleet.runs[i]
        out.append({"run_id": run_id, "serial": serial, "station": station_id, "start": start,
                    "failed": found[i]["failed"], "beyond_control": found[i]["beyond"]})
    return out


def fleet_json(fleet: Fleet) -> dict[str, Any]:
    """The statistics as ``--json`` prints them.

    Returns
    -------
    dict
        ``{"measurements": {NAME: {"n", "mean", "std", "cpk", "unit", "low", "high", "failed",
        "center", "lcl", "ucl", "beyond"}}, "records", "by_station", "by_day", "outliers", "query"}``;
        a statistic that is not defined is null.
    """
    measurements = {}
    for name, s in fleet.series.items():
        cap, chart = fleet.capability[name], fleet.charts[name]
        measurements[name] = {
            "n": cap.n, "mean": _finite(cap.mean), "std": _finite(cap.std),
            "cpk": _finite(cap.cpk), "unit": s.unit, "low": s.low, "high": s.high, "failed": s.failed,
            "center": _finite(chart.center), "lcl": _finite(chart.lcl), "ucl": _finite(chart.ucl),
            "beyond": int(chart.beyond.sum()), "other_unit": s.other_unit}
    return {"schema": "imu-station/fleet-report/1", "generated": utc_now(), "query": fleet.query,
            "records": len(fleet.runs), "measurements": measurements,
            "by_station": breakdown(fleet, "station"), "by_day": breakdown(fleet, "day"),
            "outliers": outliers(fleet)}


def measurement_svg(fleet: Fleet, name: str) -> str:
    """Histogram against the limits beside the individuals chart (see :mod:`station.plots.fleet_chart`)."""
    s, chart = fleet.series[name], fleet.charts[name]
    return chart_svg(s.values, chart.beyond, s.low, s.high, (chart.center, chart.lcl, chart.ucl),
                     s.unit)


def _link(path: Path | None, out_dir: Path) -> str:
    if path is None:
        return ""
    try:
        rel = os.path.relpath(path, out_dir)
    except ValueError:  # another drive (Windows): the absolute path
        return path.resolve().as_uri()
    return quote(Path(rel).as_posix())


def fleet_context(fleet: Fleet, certificates: dict[str, Path], out_dir: Path) -> dict[str, Any]:
    """The fleet page's variables.

    Parameters
    ----------
    fleet : Fleet
    certificates : dict of str to Path
        Run id to its certificate's file (see :meth:`RecordStore.attachment_paths`).
    out_dir : Path
        The page's folder: links to certificates are relative to it.

    Returns
    -------
    dict
    """
    stats = fleet_json(fleet)
    listed = stats["outliers"][:MAX_OUTLIERS]
    for o in listed:
        path = certificates.get(o["run_id"])
        o["href"] = _link(path, out_dir) if path is not None and path.exists() else ""
    breakdowns = {}
    for by in ("station", "day"):
        table = []
        for group, per in sorted(stats[f"by_{by}"].items()):
            shifted = sorted(((abs(v["shift_sigma"]), n, v["shift_sigma"]) for n, v in per.items()
                              if v["shift_sigma"] is not None and n in fleet.limited), reverse=True)[:3]
            table.append({"group": group, "runs": max(v["n"] for v in per.values()),
                          "failed": sum(v["failed"] for v in per.values()),
                          "shifted": [{"name": n, "sigma": sig, "flag": abs(sig) > SHIFT_FLAG}
                                      for _, n, sig in shifted]})
        breakdowns[by] = table
    return {
        "version": station.__version__, "generated": stats["generated"], "query": fleet.query,
        "records": len(fleet.runs), "first": fleet.runs[0][3], "last": fleet.runs[-1][3],
        "stations": sorted({r[2] for r in fleet.runs}),
        "failing_runs": sum(1 for o in stats["outliers"] if o["failed"]),
        "measurements": [{"name": n, **stats["measurements"][n], "svg": measurement_svg(fleet, n)}
                         for n in fleet.limited],
        "unlimited": [{"name": n, **stats["measurements"][n]} for n in fleet.series
                      if n not in fleet.limited],
        "breakdowns": breakdowns, "outliers": listed,
        "more_outliers": max(0, len(stats["outliers"]) - MAX_OUTLIERS),
    }


def render_fleet(fleet: Fleet, certificates: dict[str, Path], out_dir: Path) -> str:
    """The fleet report as one self-contained HTML page (see :func:`fleet_context`)."""
    return render("fleet.html.j2", **fleet_context(fleet, certificates, out_dir))
