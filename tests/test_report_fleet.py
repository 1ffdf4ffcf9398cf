"""The fleet report (``imu-station records report``) on SQLite and PostgreSQL: its statistics against an
independent computation from the records (the statistics module), a failing unit shown as failing and
linked to its certificate, the page well-formed, self-contained and rendered by Chromium (and its PDF
by pdftoppm) to something not blank; an empty selection refused with a clear message."""

from __future__ import annotations

import json
import math
import statistics
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from fleet_records import OFF_STATION, fleet_records
from report_helpers import check_page, chromium, cli, not_blank, pdf_pages, screenshot
from test_factory_records import private_postgres

from station.factory.records import RecordStore, RunRecord
from station.report.fleet import collect, fleet_json
from station.report.spc import D2_SPAN_TWO, capability, individuals_chart

N = 240
QUERY = {"serial": None, "since": None, "until": None, "station": None, "outcome": None}


def expected(records: list[RunRecord]) -> dict[str, dict]:
    """Per measurement, from the records themselves with the statistics module: n, mean, stdev, Cpk,
    the individuals chart's limits and which runs lie beyond them."""
    series: dict[str, list] = defaultdict(list)
    for i, r in enumerate(sorted(records, key=lambda r: (r.start, r.run_id))):
        for m in r.measurements().values():
            if isinstance(m.value, float):
                series[m.name].append((i, m.value, m.low, m.high))
    out = {}
    for name, rows in series.items():
        x = [v for _, v, _, _ in rows]
        low, high = rows[-1][2], rows[-1][3]
        mean, sd = statistics.fmean(x), statistics.stdev(x)
        sides = ([(high - mean) / (3 * sd)] if high is not None and sd > 0 else []) + (
            [(mean - low) / (3 * sd)] if low is not None and sd > 0 else [])
        cpk = min(sides) if sides else None  # no limits, or no spread: the index is not defined
        mr = statistics.fmean(abs(b - a) for a, b in zip(x, x[1:], strict=False))
        ucl, lcl = mean + 3 * mr / 1.128, mean - 3 * mr / 1.128
        out[name] = {"n": len(x), "mean": mean, "std": sd, "cpk": cpk, "ucl": ucl, "lcl": lcl,
                     "beyond": sum(1 for v in x if v > ucl or v < lcl)}
    return out


def check_stats(stats: dict, records: list[RunRecord]) -> None:
    truth = expected(records)
    assert set(stats["measurements"]) == set(truth)
    for name, want in truth.items():
        got = stats["measurements"][name]
        assert got["n"] == want["n"], name
        assert got["mean"] == pytest.approx(want["mean"], rel=1e-9, abs=1e-12), name
        if want["std"] > 0:
            assert got["std"] == pytest.approx(want["std"], rel=1e-9), name
            assert got["ucl"] == pytest.approx(want["ucl"], rel=1e-9), name
            assert got["lcl"] == pytest.approx(want["lcl"], rel=1e-9), name
            assert got["beyond"] == want["beyond"], name
        if want["cpk"] is None:
            assert got["cpk"] is None, name
        else:
            assert got["cpk"] == pytest.approx(want["cpk"], rel=1e-9), name
    # per station: the counts and means the records give
    by_station: dict[str, list[float]] = defaultdict(list)
    for r in records:
        by_station[r.station].append(r.measurements()["accel.bias.x"].value)  # type: ignore[arg-type]
    for station, values in by_station.items():
        got = stats["by_station"][station]["accel.bias.x"]
        assert got["n"] == len(values)
        assert got["mean"] == pytest.approx(statistics.fmean(values), rel=1e-9)
        assert got["min"] == min(values) and got["max"] == max(values)
    # the off-centre station is the one the report says is furthest from the fleet
    shifts = {s: v["accel.bias.x"]["shift_sigma"] for s, v in stats["by_station"].items()}
    assert max(shifts, key=lambda s: shifts[s]) == OFF_STATION
    days = {r.start[:10] for r in records}
    assert set(stats["by_day"]) == days
    failing = {r.serial for r in records if r.outcome == "FAIL"}
    assert {o["serial"] for o in stats["outliers"] if o["failed"]} == failing


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[RunRecord]]:
    """A SQLite record database of a synthetic line, each record with a certificate beside it."""
    work = tmp_path_factory.mktemp("fleet")
    records = fleet_records(N, seed=5, files_root=work / "files")
    with RecordStore.open(work / "line.sqlite") as store:
        store.save_many(records)
    return work, records


def test_capability_and_chart_against_hand_computation() -> None:
    x = np.array([1.0, 2.0, 4.0, 3.0, 10.0, 2.0])
    cap = capability(x, None, 12.0)  # one-sided: CPU alone
    assert cap.cpk == pytest.approx((12.0 - statistics.fmean(x)) / (3 * statistics.stdev(x)))
    assert capability(x, 0.0, 12.0).cpk == pytest.approx(min(12.0 - x.mean(), x.mean()) / (3 * x.std(ddof=1)))
    assert capability(x, None, None).cpk is None
    assert math.isnan(capability(np.ones(4), 0.0, 2.0).cpk)  # no spread: undefined, not infinite
    chart = individuals_chart(x)
    mr = np.abs(np.diff(x)).mean()
    assert chart.ucl == pytest.approx(x.mean() + 3 * mr / D2_SPAN_TWO)
    outside = [i for i, v in enumerate(x) if v > chart.ucl or v < chart.lcl]
    assert list(np.flatnonzero(chart.beyond)) == outside


def test_sqlite_statistics_match_an_independent_computation(line) -> None:
    work, records = line
    with RecordStore.open(work / "line.sqlite") as store:
        stats = fleet_json(collect(store, QUERY))
    assert stats["records"] == N
    assert sum(r.outcome == "FAIL" for r in records) >= 2  # the line has failing units
    check_stats(stats, records)


def test_postgres_gives_the_same_statistics(line) -> None:
    psycopg = pytest.importorskip("psycopg", reason="psycopg is not installed (the 'postgres' extra)")
    _, records = line
    with private_postgres() as url:
        with psycopg.connect(url, autocommit=True) as conn:
            conn.execute("CREATE DATABASE fleet")
        with RecordStore.open(url.rsplit("/", 1)[0] + "/fleet") as store:
            store.save_many(records)
            stats = fleet_json(collect(store, QUERY))
            some = fleet_json(collect(store, {**QUERY, "station": OFF_STATION,
                                              "since": records[40].start[:10]}))
    check_stats(stats, records)
    chosen = [r for r in records if r.station == OFF_STATION and r.start[:10] >= records[40].start[:10]]
    assert some["records"] == len(chosen)
    check_stats(some, chosen)


def test_records_report_page_json_and_pdf(line, tmp_path: Path) -> None:
    chromium()  # --pdf needs it: skipped, saying so, where it is not installed
    work, records = line
    done = cli("records", "report", "--db", str(work / "line.sqlite"), "-o", str(tmp_path / "fleet.html"),
               "--pdf", str(tmp_path / "fleet.pdf"), "--json", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    stats = json.loads(done.stdout)
    check_stats(stats, records)
    text = check_page(tmp_path / "fleet.html")
    failing = next(r for r in records if r.outcome == "FAIL")
    failed_name = next(m.name for m in failing.measurements().values() if m.outcome == "FAIL")
    # the failing unit is listed as failing, with its failing measurement and a link to its certificate
    row = next(part for part in text.split("<tr") if f"<td>{failing.serial}</td>" in part)
    assert 'class="flag"' in row and failed_name in row
    href = row.split('href="')[1].split('"')[0]
    assert (tmp_path / href).resolve() == (Path(failing.files_dir) / "certificate.html").resolve()
    assert text.count("<svg") == sum(1 for m in stats["measurements"].values() if m["low"] is not None
                                     or m["high"] is not None)
    not_blank(screenshot(tmp_path / "fleet.html", tmp_path))
    pages = pdf_pages(tmp_path / "fleet.pdf", tmp_path)
    assert len(pages) >= 2
    not_blank(pages[0])


def test_filters_select_and_an_empty_selection_is_refused(line, tmp_path: Path) -> None:
    work, records = line
    db = str(work / "line.sqlite")
    done = cli("records", "report", "--db", db, "--station", OFF_STATION, "--json", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["records"] == sum(1 for r in records if r.station == OFF_STATION)
    done = cli("records", "report", "--db", db, "--since", "2031-01-01", "-o", "x.html", cwd=tmp_path)
    assert done.returncode == 4
    assert "no record" in done.stderr and "--since 2031-01-01" in done.stderr and "widen" in done.stderr
    assert not (tmp_path / "x.html").exists()
    done = cli("records", "report", "--db", db, cwd=tmp_path)
    assert done.returncode == 4 and "-o FILE.html" in done.stderr
    done = cli("records", "--db", db, "-o", "x.html", cwd=tmp_path)
    assert done.returncode == 4 and "records report" in done.stderr
    # no Chromium: the page is written, the PDF refused with what to install
    done = cli("records", "report", "--db", db, "-o", "page.html", "--pdf", "page.pdf", cwd=tmp_path,
               env={"IMU_STATION_CHROMIUM": "no-such-browser"})
    assert done.returncode == 4 and "apt-get install chromium" in done.stderr
    assert (tmp_path / "page.html").exists() and not (tmp_path / "page.pdf").exists()
