"""Records: SQLite (WAL) and a real PostgreSQL server started here: round trip, queries, concurrency,
hashes."""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import socket
import sqlite3
import subprocess
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from station.errors import StationError
from station.factory.records import Attachment, Measurement, Phase, RecordStore, RunRecord, sha256_file


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def private_postgres() -> Iterator[str]:
    """A private PostgreSQL cluster (initdb + pg_ctl in a temp dir, a free port), stopped afterwards;
    skips the test where no server binaries or no psycopg are installed."""
    bins = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb")) or ([shutil.which("initdb")]
                                                                       if shutil.which("initdb") else [])
    if not bins:
        pytest.skip("no PostgreSQL server binaries (Debian: apt-get install postgresql)")
    pytest.importorskip("psycopg", reason="psycopg is not installed (pip install 'imu-station[postgres]')")
    bindir = Path(bins[-1]).parent
    tmp = Path(tempfile.mkdtemp(prefix="imu-pg-"))
    prefix: list[str] = []
    if os.geteuid() == 0:  # postgres refuses to run as root
        nobody = pwd.getpwnam("nobody")
        os.chown(tmp, nobody.pw_uid, nobody.pw_gid)
        prefix = ["runuser", "-u", "nobody", "--"]
    port = _free_port()
    data = tmp / "data"
    subprocess.run([*prefix, str(bindir / "initdb"), "-D", str(data), "-U", "postgres", "-A", "trust",
                    "--no-sync", "-E", "UTF8"], check=True, capture_output=True)
    options = f"-p {port} -k {tmp} -c listen_addresses=127.0.0.1 -c fsync=off"
    subprocess.run([*prefix, str(bindir / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(tmp / "log"),
                    "-w", "start"], check=True, capture_output=True)
    try:
        yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
    finally:
        subprocess.run([*prefix, str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
                       capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.fixture(scope="module")
def postgres_url() -> Iterator[str]:
    with private_postgres() as url:
        yield url


def make_record(serial: str, start: str, files: Path, outcome: str = "PASS", bias: float = 0.01) -> RunRecord:
    files.mkdir(parents=True, exist_ok=True)
    capture = files / "capture.csv"
    capture.write_text(f"t,ax\n0,{bias}\n")
    record = RunRecord(serial=serial, station="st-1", plan={"name": "p", "sha256": "ab" * 32}, start=start,
                       files_dir=str(files))
    record.phases = [
        Phase("connect", start, start, measurements=[Measurement("device.serial", serial, outcome="PASS")]),
        Phase("calibrate", start, start, measurements=[
            Measurement("accel.bias.x", bias, "m/s^2", -0.5, 0.5, "PASS" if abs(bias) <= 0.5 else "FAIL"),
            Measurement("gyro.residual_rms", 1e-4, "rad/s")],
            attachments=[Attachment("raw capture", "capture.csv", sha256_file(capture),
                                    capture.stat().st_size, "text/csv")]),
    ]
    record.finish(outcome, "" if outcome == "PASS" else "outside limits: accel.bias.x")
    record.start = start
    return record


def check_store(store: RecordStore, tmp_path: Path) -> None:
    a1 = make_record("A1", "2026-11-20T08:00:00.000000Z", tmp_path / "a1")
    a2 = make_record("A1", "2026-11-21T09:00:00.000000Z", tmp_path / "a2", "FAIL", bias=0.7)
    b1 = make_record("B7", "2026-11-21T23:59:59.500000Z", tmp_path / "b1")
    for r in (a2, b1, a1):
        store.save(r)
    store.save(a1)  # saving again replaces, never duplicates
    assert store.table_counts() == {"runs": 3, "phases": 6, "measurements": 9, "attachments": 3}
    history = store.query(serial="A1")
    assert [r.run_id for r in history] == [a1.run_id, a2.run_id]
    assert history[0].to_dict() == a1.to_dict()  # lossless round trip
    assert history[1].exit_code == 1 and history[1].measurements()["accel.bias.x"].outcome == "FAIL"
    assert [r.serial for r in store.query(since="2026-11-21")] == ["A1", "B7"]
    assert [r.serial for r in store.query(until="2026-11-21")] == ["A1", "A1", "B7"]  # the whole day
    assert [r.serial for r in store.query(since="2026-11-21T10:00:00Z")] == ["B7"]
    assert [r.serial for r in store.query(until="2026-11-20")] == ["A1"]
    assert [r.serial for r in store.query(outcome="fail")] == ["A1"]
    assert store.query(serial="nobody") == []
    rows = store.rows("SELECT name, value, low, high, unit FROM measurements WHERE run_id = ? AND name = ?",
                      (a2.run_id, "accel.bias.x"))
    assert rows == [("accel.bias.x", 0.7, -0.5, 0.5, "m/s^2")]
    text = store.rows("SELECT text_value FROM measurements WHERE run_id = ? AND name = ?",
                      (b1.run_id, "device.serial"))
    assert text == [("B7",)]
    with pytest.raises(StationError, match="--since"):
        store.query(since="yesterday")


def test_sqlite_store(tmp_path: Path) -> None:
    with RecordStore.open(tmp_path / "db" / "records.sqlite") as store:
        check_store(store, tmp_path)
    conn = sqlite3.connect(tmp_path / "db" / "records.sqlite")
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    conn.close()


def test_postgres_store(postgres_url: str, tmp_path: Path) -> None:
    import psycopg

    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("CREATE DATABASE records_unit")
    url = postgres_url.rsplit("/", 1)[0] + "/records_unit"
    with RecordStore.open(url) as store:
        assert store.is_postgres
        check_store(store, tmp_path)


def concurrent_writers(url: str, tmp_path: Path, n: int = 8) -> None:
    errors: list[BaseException] = []

    def write(i: int) -> None:
        try:
            with RecordStore.open(url) as store:
                store.save(make_record(f"U{i}", f"2026-11-22T00:00:{i:02d}.000000Z", tmp_path / f"u{i}"))
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=write, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    with RecordStore.open(url) as store:
        assert sorted(r.serial for r in store.query()) == sorted(f"U{i}" for i in range(n))
        assert store.table_counts()["measurements"] == 3 * n


def test_sqlite_concurrent_writers(tmp_path: Path) -> None:
    concurrent_writers(str(tmp_path / "c.sqlite"), tmp_path)


def test_postgres_concurrent_writers_create_tables_once(postgres_url: str, tmp_path: Path) -> None:
    import psycopg

    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("CREATE DATABASE records_many")
    concurrent_writers(postgres_url.rsplit("/", 1)[0] + "/records_many", tmp_path)


def test_verify_finds_altered_and_missing_files(tmp_path: Path) -> None:
    record = make_record("A1", "2026-11-20T08:00:00.000000Z", tmp_path / "a")
    assert record.verify() == []
    (tmp_path / "a" / "capture.csv").write_text("t,ax\n0,0.02\n")
    assert "SHA-256 differs" in record.verify()[0]
    (tmp_path / "a" / "capture.csv").unlink()
    assert "missing" in record.verify()[0]


def test_refuses_other_schema_and_bad_urls(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite"
    with RecordStore.open(path) as store:
        store.conn.execute("UPDATE meta SET value = 'imu-station/record/0' WHERE key = 'schema'")
    with pytest.raises(StationError, match="imu-station/record/0"):
        RecordStore.open(path)
    with pytest.raises(StationError, match="cannot connect"):
        RecordStore.open(f"postgresql://nobody@127.0.0.1:{_free_port()}/none")
    (tmp_path / "a-file").write_text("")
    with pytest.raises(StationError, match="cannot open"):
        RecordStore.open(tmp_path / "a-file" / "x.sqlite")
