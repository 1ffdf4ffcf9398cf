"""The fleet report over 10,000 records, on SQLite and on PostgreSQL: the target is under 5 s.

Generates N synthetic records (``tests/fleet_records.py``: 26 measurements with limits and one
without, four stations, some units failing), stores them once (``RecordStore.save_many``), then
times what ``imu-station records report -o fleet.html --json`` does after the process has started:
the selection (SQL), every statistic, the page with its 26 charts and the JSON. The peer is
the path ``imu-station records`` takes for the same selection: every record read back from its
JSON (``RecordStore.query``) with no statistic at all. One whole ``records report`` process is timed
too (interpreter start and imports included). PostgreSQL is a private cluster started for the run
(Debian's postgresql server binaries and psycopg); without them that half is skipped, saying why.

    .venv/bin/python benchmarks/fleet_report.py [--records 10000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from fleet_records import fleet_records  # noqa: E402
from timing import median_wall_cpu  # noqa: E402

from station.factory.records import RecordStore  # noqa: E402
from station.report.attachments import CERTIFICATE_NAME  # noqa: E402
from station.report.fleet import collect, fleet_json, render_fleet  # noqa: E402

QUERY = {"serial": None, "since": None, "until": None, "station": None, "outcome": None}
TARGET_S = 5.0


@contextlib.contextmanager
def postgres() -> Iterator[str | None]:
    """A private PostgreSQL database URL, or None (with the reason printed) where none can be started."""
    try:
        import pytest
        from test_factory_records import private_postgres
    except ImportError as exc:
        print(f"PostgreSQL: skipped ({exc})")
        yield None
        return
    try:
        with private_postgres() as url:
            import psycopg

            with psycopg.connect(url, autocommit=True) as conn:
                conn.execute("CREATE DATABASE fleet")
            yield url.rsplit("/", 1)[0] + "/fleet"
    except pytest.skip.Exception as exc:
        print(f"PostgreSQL: skipped ({exc})")
        yield None


def report(url: str, out: Path) -> int:
    """What ``records report -o out --json`` does once its process has started; returns the page's size."""
    with RecordStore.open(url) as store:
        fleet = collect(store, QUERY)
        certificates = store.attachment_paths(CERTIFICATE_NAME, **QUERY)
    page = render_fleet(fleet, certificates, out.parent)
    out.write_text(page, encoding="utf-8")
    json.dumps(fleet_json(fleet), allow_nan=False)
    return len(page)


def peer(url: str) -> int:
    """``imu-station records``'s path for the same selection: every record parsed from its JSON."""
    with RecordStore.open(url) as store:
        return len(store.query())


def measure(name: str, url: str, repeats: int, work: Path) -> float:
    wall, cpu, size = median_wall_cpu(lambda: report(url, work / f"{name}.html"), repeats)
    peer_wall, _, n = median_wall_cpu(lambda: peer(url), repeats)
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "station.cli", "records", "report", "--db", url, "-o",
                           str(work / f"{name}-cli.html"), "--json"], capture_output=True, text=True, env=env,
                          cwd=REPO)
    process = time.perf_counter() - start
    assert done.returncode == 0, done.stderr
    print(f"{name:10s} report {wall:6.2f} s median wall ({cpu:.2f} s CPU), page {size / 1e6:.1f} MB; "
          f"whole process {process:.2f} s; peer (parse {n} records' JSON, no statistics) {peer_wall:.2f} s; "
          f"ratio report/peer {wall / peer_wall:.2f}; target < {TARGET_S:g} s: "
          f"{'met' if process < TARGET_S else 'MISSED'}")
    return wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="imu-fleet-bench-") as tmp:
        work = Path(tmp)
        start = time.perf_counter()
        records = fleet_records(args.records, seed=1, files_root=None)
        print(f"{args.records} records generated in {time.perf_counter() - start:.1f} s")
        with RecordStore.open(work / "fleet.sqlite") as store:
            store.save_many(records)
        measure("SQLite", str(work / "fleet.sqlite"), args.repeats, work)
        with postgres() as url:
            if url is not None:
                with RecordStore.open(url) as store:
                    store.save_many(records)
                measure("PostgreSQL", url, args.repeats, work)


if __name__ == "__main__":
    main()
