"""Test records, modelled on OpenHTF's: one record per unit run, phases, measurements, attachments.

A :class:`RunRecord` holds the unit (serial), the station, start and end, the outcome (PASS,
FAIL, ABORTED, TIMEOUT, ERROR), and its phases; each :class:`Phase` holds measurements (value,
limits, unit, outcome) and attachments (files kept beside the record, with their SHA-256).

Records are stored in SQLite (WAL mode, so several station processes write one file) or in
PostgreSQL (``postgresql://...``, through psycopg: the optional extra ``postgres``), in the
tables ``runs``, ``phases``, ``measurements`` and ``attachments``; ``runs.record`` also keeps the
whole record as JSON, which is what queries return.
"""

from __future__ import annotations

import datetime as _dt
import json
import sqlite3
import time
import uuid
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from station.common.files import sha256_file
from station.errors import ExitCode, StationError

SCHEMA = "imu-station/record/1"
OUTCOMES = ("PASS", "FAIL", "ABORTED", "TIMEOUT", "ERROR")
EXIT_CODES = {"PASS": ExitCode.OK, "FAIL": ExitCode.OUT_OF_LIMITS, "ABORTED": ExitCode.ABORTED,
              "ERROR": ExitCode.DEVICE, "TIMEOUT": ExitCode.TIMEOUT}


def utc_now() -> str:
    """Now in UTC, ISO 8601 with microseconds: sorts as text, in SQLite and PostgreSQL alike."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


@dataclass
class Measurement:
    """One measured value; ``low``/``high`` in ``unit``; outcome PASS, FAIL or UNSET (no limits)."""

    name: str
    value: float | str | None
    unit: str = ""
    low: float | None = None
    high: float | None = None
    outcome: str = "UNSET"
    doc: str = ""


@dataclass
class Attachment:
    """A file kept beside the record: ``path`` relative to the record's directory."""

    name: str
    path: str
    sha256: str
    size: int
    mimetype: str = "application/octet-stream"


@dataclass
class Phase:
    """One phase of a unit's run (OpenHTF's sense): its times, outcome, measurements and files."""

    name: str
    start: str = field(default_factory=utc_now)
    end: str = ""
    outcome: str = "PASS"  # PASS, FAIL, SKIP, ERROR
    measurements: list[Measurement] = field(default_factory=list)
    attachments: list[Attachment] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass
class RunRecord:
    """Everything about one unit's run. ``files_dir`` is where its attachments are."""

    serial: str
    station: str
    plan: dict[str, Any]
    run_id: str = field(default_factory=lambda: uuid.uuid4().hex)
    start: str = field(default_factory=utc_now)
    end: str = ""
    outcome: str = "ERROR"
    exit_code: int = int(ExitCode.DEVICE)
    reason: str = ""
    device: dict[str, Any] = field(default_factory=dict)
    files_dir: str = ""
    phases: list[Phase] = field(default_factory=list)
    schema: str = SCHEMA

    def finish(self, outcome: str, reason: str = "") -> None:
        """Close the record with ``outcome`` (one of ``OUTCOMES``), its exit code, ``reason`` and end time."""
        if outcome not in OUTCOMES:
            raise ValueError(f"outcome {outcome!r} is not one of {OUTCOMES}")
        self.outcome = outcome
        self.exit_code = int(EXIT_CODES[outcome])  # a plain int in the JSON and the databases
        self.reason = reason
        self.end = utc_now()

    def measurements(self) -> dict[str, Measurement]:
        """Every measurement of every phase, by name."""
        return {m.name: m for p in self.phases for m in p.measurements}

    def attachments(self) -> list[Attachment]:
        """Every file attached in every phase, in order."""
        return [a for p in self.phases for a in p.attachments]

    def to_dict(self) -> dict[str, Any]:
        """The record as plain data (the JSON written beside the files)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunRecord:
        """Read a record written by :meth:`to_dict`; refuses another schema (StationError)."""
        if d.get("schema") != SCHEMA:
            raise StationError(f"a stored record has schema {d.get('schema')!r}, this station reads "
                               f"{SCHEMA!r}")
        phases = [Phase(**{**p, "measurements": [Measurement(**m) for m in p["measurements"]],
                           "attachments": [Attachment(**a) for a in p["attachments"]]}) for p in d["phases"]]
        return cls(**{**d, "phases": phases})

    def verify(self) -> list[str]:
        """Problems with the attachments on disk (missing, or a SHA-256 that differs); empty when intact."""
        problems = []
        for a in self.attachments():
            path = Path(self.files_dir) / a.path
            if not path.exists():
                problems.append(f"{path}: missing")
            elif sha256_file(path) != a.sha256:
                problems.append(f"{path}: SHA-256 differs from the record's")
        return problems


_DDL = [
    """CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)""",
    """CREATE TABLE IF NOT EXISTS runs (
        run_id TEXT PRIMARY KEY, serial TEXT NOT NULL, station TEXT NOT NULL, plan_name TEXT NOT NULL,
        plan_sha256 TEXT NOT NULL, start_utc TEXT NOT NULL, end_utc TEXT NOT NULL, outcome TEXT NOT NULL,
        exit_code INTEGER NOT NULL, reason TEXT NOT NULL, files_dir TEXT NOT NULL, record TEXT NOT NULL)""",
    """CREATE INDEX IF NOT EXISTS runs_serial ON runs (serial, start_utc)""",
    """CREATE INDEX IF NOT EXISTS runs_start ON runs (start_utc)""",
    """CREATE TABLE IF NOT EXISTS phases (
        run_id TEXT NOT NULL, idx INTEGER NOT NULL, name TEXT NOT NULL, outcome TEXT NOT NULL,
        start_utc TEXT NOT NULL, end_utc TEXT NOT NULL, PRIMARY KEY (run_id, idx))""",
    """CREATE TABLE IF NOT EXISTS measurements (
        run_id TEXT NOT NULL, phase TEXT NOT NULL, name TEXT NOT NULL, value DOUBLE PRECISION,
        text_value TEXT, unit TEXT NOT NULL, low DOUBLE PRECISION, high DOUBLE PRECISION,
        outcome TEXT NOT NULL, PRIMARY KEY (run_id, name))""",
    """CREATE TABLE IF NOT EXISTS attachments (
        run_id TEXT NOT NULL, phase TEXT NOT NULL, name TEXT NOT NULL, path TEXT NOT NULL,
        sha256 TEXT NOT NULL, size BIGINT NOT NULL, mimetype TEXT NOT NULL, PRIMARY KEY (run_id, name))""",
]


def _date_bound(text: str, end: bool, what: str) -> str:
    """``2026-11-22`` (the whole day for --until) or an ISO date-time, as the stored UTC text form."""
    try:
        if len(text) == 10:
            day = _dt.date.fromisoformat(text)
            moment = _dt.datetime.combine(day, _dt.time.max if end else _dt.time.min, _dt.UTC)
        else:
            moment = _dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
            if moment.tzinfo is None:
                moment = moment.replace(tzinfo=_dt.UTC)
    except ValueError:
        raise StationError(f"{what} {text!r}: give a date (2026-11-22) or a date and time "
                           "(2026-11-22T08:30:00Z)") from None
    return moment.astimezone(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _filters(serial: str | None, since: str | None, until: str | None, station: str | None,
             outcome: str | None, prefix: str = "") -> tuple[list[str], list[Any]]:
    """The WHERE terms (with ``?`` placeholders) and parameters of a query's filters on ``runs``."""
    where: list[str] = []
    params: list[Any] = []
    for column, value in (("serial", serial), ("station", station),
                          ("outcome", outcome.upper() if outcome is not None else None)):
        if value is not None:
            where.append(f"{prefix}{column} = ?")
            params.append(value)
    if since is not None:
        where.append(f"{prefix}start_utc >= ?")
        params.append(_date_bound(since, False, "--since"))
    if until is not None:
        where.append(f"{prefix}start_utc <= ?")
        params.append(_date_bound(until, True, "--until"))
    return where, params


def _enable_wal(conn: sqlite3.Connection, wait_s: float = 30.0) -> None:
    """Switch to write-ahead logging. While another station creates the same new database, the switch
    can fail at once with "database is locked" (SQLite does not call the busy handler for it), so it is
    retried until ``wait_s`` has passed."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            conn.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


class RecordStore:
    """Where records go: ``RecordStore.open('records.sqlite')`` or ``open('postgresql://...')``."""

    def __init__(self, conn: Any, placeholder: str, url: str):
        self.conn = conn
        self.ph = placeholder
        self.url = url

    @classmethod
    def open(cls, url: str | Path) -> RecordStore:
        """The store at ``url``: ``postgresql://...``, ``sqlite:///path`` or a path of a SQLite file."""
        url = str(url)
        if url.startswith(("postgresql://", "postgres://")):
            return cls._open_postgres(url)
        path = Path(url.removeprefix("sqlite:///")) if url.startswith("sqlite:///") else Path(url)
        return cls._open_sqlite(path)

    @classmethod
    def _open_sqlite(cls, path: Path) -> RecordStore:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            conn = sqlite3.connect(path, timeout=30.0, isolation_level=None)
            conn.execute("PRAGMA busy_timeout=30000")
            _enable_wal(conn)
        except (sqlite3.Error, OSError) as exc:
            raise StationError(f"--db {path}: cannot open the SQLite record database: {exc}") from None
        store = cls(conn, "?", str(path))
        store._create()
        return store

    @classmethod
    def _open_postgres(cls, url: str) -> RecordStore:
        try:
            import psycopg
        except ImportError:
            raise StationError("--db postgresql://...: psycopg is not installed; install the extra: "
                               "pip install 'imu-station[postgres]'") from None
        try:
            conn = psycopg.connect(url, autocommit=True, connect_timeout=10)
        except psycopg.Error as exc:
            shown = url.split("@")[-1]
            raise StationError(f"--db postgresql://...@{shown}: cannot connect: {exc}".strip()) from None
        store = cls(conn, "%s", url)
        store._create()
        return store

    @property
    def is_postgres(self) -> bool:
        """True for a PostgreSQL store (its SQL placeholders differ)."""
        return self.ph == "%s"

    def _sql(self, text: str) -> str:
        return text.replace("?", self.ph)

    def _create(self) -> None:
        with self._transaction() as cur:
            if self.is_postgres:
                # Several stations may create the tables at once: serialise on an advisory lock.
                cur.execute("SELECT pg_advisory_xact_lock(8080808)")
            for statement in _DDL:
                cur.execute(statement)
            cur.execute(self._sql("SELECT value FROM meta WHERE key = ?"), ("schema",))
            row = cur.fetchone()
            if row is None:
                cur.execute(self._sql("INSERT INTO meta (key, value) VALUES (?, ?)"), ("schema", SCHEMA))
            elif row[0] != SCHEMA:
                raise StationError(f"--db {self.url}: holds records of schema {row[0]!r}, this station "
                                   f"writes {SCHEMA!r}; use another database")

    def _transaction(self) -> Any:
        store = self

        class _Tx:
            def __enter__(self) -> Any:
                if store.is_postgres:
                    self.tx = store.conn.transaction()
                    self.tx.__enter__()
                    self.cur = store.conn.cursor()
                else:
                    self.cur = store.conn.cursor()
                    self.cur.execute("BEGIN IMMEDIATE")
                return self.cur

            def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
                if store.is_postgres:
                    self.cur.close()
                    self.tx.__exit__(exc_type, exc, tb)
                else:
                    store.conn.execute("COMMIT" if exc_type is None else "ROLLBACK")
                    self.cur.close()

        return _Tx()

    def save(self, record: RunRecord) -> None:
        """Insert (or replace) one record with its phases, measurements and attachments, atomically."""
        self.save_many([record])

    def save_many(self, records: Iterable[RunRecord]) -> None:
        """Insert (or replace) records in one transaction: all of them or none (an import, a benchmark)."""
        runs, phases, measurements, attachments = [], [], [], []
        for record in records:
            runs.append((record.run_id, record.serial, record.station, str(record.plan.get("name", "")),
                         str(record.plan.get("sha256", "")), record.start, record.end, record.outcome,
                         record.exit_code, record.reason, record.files_dir,
                         json.dumps(record.to_dict(), allow_nan=False)))
            for idx, phase in enumerate(record.phases):
                phases.append((record.run_id, idx, phase.name, phase.outcome, phase.start, phase.end))
                for m in phase.measurements:
                    number = m.value if isinstance(m.value, int | float) else None
                    text = m.value if isinstance(m.value, str) else None
                    measurements.append((record.run_id, phase.name, m.name, number, text, m.unit, m.low,
                                         m.high, m.outcome))
                attachments += [(record.run_id, phase.name, a.name, a.path, a.sha256, a.size, a.mimetype)
                                for a in phase.attachments]
        with self._transaction() as cur:
            for table in ("attachments", "measurements", "phases", "runs"):
                cur.executemany(self._sql(f"DELETE FROM {table} WHERE run_id = ?"), [(r[0],) for r in runs])
            cur.executemany(self._sql(
                "INSERT INTO runs (run_id, serial, station, plan_name, plan_sha256, start_utc, end_utc, "
                "outcome, exit_code, reason, files_dir, record) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"),
                runs)
            cur.executemany(self._sql("INSERT INTO phases (run_id, idx, name, outcome, start_utc, end_utc) "
                                      "VALUES (?, ?, ?, ?, ?, ?)"), phases)
            cur.executemany(self._sql(
                "INSERT INTO measurements (run_id, phase, name, value, text_value, unit, low, high, "
                "outcome) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)"), measurements)
            cur.executemany(self._sql(
                "INSERT INTO attachments (run_id, phase, name, path, sha256, size, mimetype) "
                "VALUES (?, ?, ?, ?, ?, ?, ?)"), attachments)

    def query(self, serial: str | None = None, since: str | None = None, until: str | None = None,
              station: str | None = None, outcome: str | None = None) -> list[RunRecord]:
        """Records in start order; ``since``/``until`` are dates or ISO date-times (UTC when unzoned)."""
        where, params = _filters(serial, since, until, station, outcome)
        sql = "SELECT record FROM runs" + (" WHERE " + " AND ".join(where) if where else "")
        sql += " ORDER BY start_utc, run_id"
        return [RunRecord.from_dict(json.loads(row[0])) for row in self.rows(sql, params)]

    def run_rows(self, serial: str | None = None, since: str | None = None, until: str | None = None,
                 station: str | None = None, outcome: str | None = None) -> list[tuple]:
        """The runs the filters select, in start order, without their JSON: ``(run_id, serial, station,
        start_utc)``. The filters are those of :meth:`query`."""
        where, params = _filters(serial, since, until, station, outcome)
        sql = "SELECT run_id, serial, station, start_utc FROM runs" + (" WHERE " + " AND ".join(where)
                                                                       if where else "")
        sql += " ORDER BY start_utc, run_id"
        return self.rows(sql, params)

    def measurement_values(self, serial: str | None = None, since: str | None = None,
                           until: str | None = None, station: str | None = None,
                           outcome: str | None = None) -> list[tuple]:
        """Every numeric measurement of the runs the filters select, each naming its run by position.

        The fleet report reads these rows rather than the records' JSON: one join, small rows, no
        parsing per record. Rows come in no particular order.

        Parameters
        ----------
        serial, since, until, station, outcome
            The filters of :meth:`query`.

        Returns
        -------
        list of tuple
            ``(name, unit, value, low, high, run, failed)``: ``run`` is the run's 1-based position in
            :meth:`run_rows` (start order), ``failed`` 1 when it was judged FAIL, else 0.
        """
        where, params = _filters(serial, since, until, station, outcome)
        sql = ("WITH sel AS (SELECT run_id, ROW_NUMBER() OVER (ORDER BY start_utc, run_id) AS pos FROM runs"
               + (" WHERE " + " AND ".join(where) if where else "") + ") "
               "SELECT m.name, m.unit, m.value, m.low, m.high, sel.pos, "
               "CASE WHEN m.outcome = 'FAIL' THEN 1 ELSE 0 END "
               "FROM measurements m JOIN sel ON sel.run_id = m.run_id WHERE m.value IS NOT NULL")
        return self.rows(sql, params)

    def attachment_paths(self, name: str, serial: str | None = None, since: str | None = None,
                         until: str | None = None, station: str | None = None,
                         outcome: str | None = None) -> dict[str, Path]:
        """Where the attachment called ``name`` of each selected run is (e.g. its certificate).

        Parameters
        ----------
        name : str
            The attachment's name.
        serial, since, until, station, outcome
            The filters of :meth:`query`.

        Returns
        -------
        dict of str to Path
            Run id to the file's path (its record's files folder joined with the attachment's path).
        """
        where, params = _filters(serial, since, until, station, outcome, prefix="r.")
        sql = ("SELECT r.run_id, r.files_dir, a.path FROM attachments a JOIN runs r ON r.run_id = a.run_id "
               "WHERE a.name = ?" + "".join(f" AND {w}" for w in where))
        return {run_id: Path(files_dir) / path for run_id, files_dir, path in self.rows(sql, [name, *params])}

    def table_counts(self) -> dict[str, int]:
        """Rows per table (consistency checks)."""
        cur = self.conn.cursor()
        try:
            out = {}
            for table in ("runs", "phases", "measurements", "attachments"):
                cur.execute(f"SELECT COUNT(*) FROM {table}")
                out[table] = int(cur.fetchone()[0])
            return out
        finally:
            cur.close()

    def rows(self, sql: str, params: Iterable[Any] = ()) -> list[tuple]:
        """Raw rows of a read query written with ``?`` placeholders (for reports and tests)."""
        cur = self.conn.cursor()
        try:
            cur.execute(self._sql(sql), tuple(params))
            return [tuple(r) for r in cur.fetchall()]
        finally:
            cur.close()

    def close(self) -> None:
        """Close the database connection."""
        self.conn.close()

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
