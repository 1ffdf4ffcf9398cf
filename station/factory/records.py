"""Test records, modelled on OpenHTF's: one record per unit run, phases, measurements, attachments.

A :class:`RunRecord` holds the unit (serial), the station, start and end, the outcome (PASS,
FAIL, ABORTED, TIMEOUT, ERROR), and its phases; each :class:`Phase` holds measurements (value,
limits, unit, outcome) and attachments (files kept beside the record, with their SHA-256).

Records are stored in SQLite (WAL mode, so several station processes write one file) or in
PostgreSQL (``postgresql://...``, through psycopg: the optional extra ``postgres``), in the
tables ``runs``, ``phases``, ``measurements`` and ``attachments``; ``runs.record`` also keeps the
whole record as JSON, which is what queries return.

A store opened ``readonly`` (every command that only reads) never takes a write lock, and a
writer's store takes one only to create the tables of a new database; a lock held by another
process is waited for a bounded time (:data:`READ_WAIT_S`, :data:`WRITE_WAIT_S`, or
``$IMU_STATION_DB_WAIT``), then reported in one line. A damaged file, a file that is not a
database, or a database of another table layout is refused in one line naming the file; a row
whose JSON is not a record is refused in one line naming its run, and the other rows are read.

Why this module is long: the record's dataclasses and the store that writes and reads them are one
schema, kept in one place so the tables and the JSON cannot drift apart.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import sqlite3
import time
import urllib.parse
import uuid
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from station.common.files import sha256_file
from station.common.text import printable
from station.errors import ExitCode, StationError
from station.factory.record_checks import BadRecord, attachment_problem, build, hash_problem, parse_json
from station.factory.store_errors import (
    RecordStoreError,
    RecordsUnavailable,
    db_error,
    is_db_error,
    wait_s,
)

__all__ = ["Attachment", "BadRecord", "Measurement", "Phase", "RecordStore", "RecordStoreError",
           "RecordsUnavailable", "RunRecord", "sha256_file", "utc_now"]

SCHEMA = "imu-station/record/1"
OUTCOMES = ("PASS", "FAIL", "ABORTED", "TIMEOUT", "ERROR")
EXIT_CODES = {"PASS": ExitCode.OK, "FAIL": ExitCode.OUT_OF_LIMITS, "ABORTED": ExitCode.ABORTED,
              "ERROR": ExitCode.DEVICE, "TIMEOUT": ExitCode.TIMEOUT}
READ_WAIT_S = 5.0
"""How long a command that only reads waits for another process's lock before saying so."""
WRITE_WAIT_S = 30.0
"""How long a run waits for another process's lock before keeping its record pending."""
log = logging.getLogger("imu_station.records")
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
    def from_dict(cls, d: dict[str, Any], where: str = "a stored record") -> RunRecord:
        """Read a record written by :meth:`to_dict`, every field checked against its type.

        Parameters
        ----------
        d : dict
            The record as plain data.
        where : str
            What to name in an error (the database row, the file).

        Raises
        ------
        BadRecord
            Another schema, a field missing or of another type (a reader refuses the row).
        """
        if not isinstance(d, dict) or d.get("schema") != SCHEMA:
            shown = printable(d.get("schema"), 60) if isinstance(d, dict) else type(d).__name__
            raise BadRecord(f"{where}: schema {shown!r}, this station reads {SCHEMA!r}")
        record: RunRecord = build(cls, d, where)
        return record

    @classmethod
    def from_json(cls, text: object, where: str) -> RunRecord:
        """:meth:`from_dict` of the JSON text ``text`` (a database row, a spooled file); BadRecord."""
        return cls.from_dict(parse_json(text, where), where)

    def attachment_file(self, a: Attachment, root: Path | None = None) -> Path | None:
        """Where the attachment ``a`` is, if it may be read: a path inside the record's files folder
        (inside ``root`` too, when given); None for an absolute path, ``..`` or a link out of it."""
        return None if attachment_problem(self.files_dir, a.path, root) else Path(self.files_dir) / a.path

    def verify(self, root: Path | None = None) -> list[str]:
        """Problems with the attachments on disk (missing, not readable as the record's, or a SHA-256
        that differs); empty when intact. Only regular files inside the record's files folder (and
        ``root``, when given) are read, never more bytes than recorded (:mod:`record_checks`)."""
        problems = []
        for a in self.attachments():
            path = Path(self.files_dir) / a.path
            problem = attachment_problem(self.files_dir, a.path, root) or hash_problem(path, a.size, a.sha256)
            if problem:
                problems.append(f"{printable(path, 1000)}: {problem}")
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


def _number(value: object, optional: bool = False) -> bool:
    return (value is None and optional) or (isinstance(value, int | float) and not isinstance(value, bool))


def _measurement_row_ok(row: tuple) -> bool:
    """A measurement row as the station writes it: text name and unit, a number, numbers or nulls for
    the limits (a foreign or hand-edited row may hold text anywhere)."""
    name, unit, value, low, high = row[:5]
    return isinstance(name, str) and isinstance(unit, str) and _number(value) and _number(low, True) \
        and _number(high, True)


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


def _enable_wal(conn: sqlite3.Connection, wait_s: float) -> None:
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


# The columns of each table as _DDL creates them: a database without them is another program's.
_COLUMNS = {
    "meta": {"key", "value"},
    "runs": {"run_id", "serial", "station", "plan_name", "plan_sha256", "start_utc", "end_utc", "outcome",
             "exit_code", "reason", "files_dir", "record"},
    "phases": {"run_id", "idx", "name", "outcome", "start_utc", "end_utc"},
    "measurements": {"run_id", "phase", "name", "value", "text_value", "unit", "low", "high", "outcome"},
    "attachments": {"run_id", "phase", "name", "path", "sha256", "size", "mimetype"},
}
class RecordStore:
    """Where records go: ``RecordStore.open('records.sqlite')`` or ``open('postgresql://...')``."""

    def __init__(self, conn: Any, placeholder: str, url: str, wait: float = 0.0):
        self.conn = conn
        self.ph = placeholder
        self.url = url
        self.wait = wait
        self.refused: list[str] | None = None
        """Where the lines of refused rows go when a query is given no list of its own (else the log)."""

    @classmethod
    def open(cls, url: str | Path, readonly: bool = False, wait: float | None = None) -> RecordStore:
        """The store at ``url``: ``postgresql://...``, ``sqlite:///path`` or a path of a SQLite file.

        Parameters
        ----------
        url : str or Path
            The database.
        readonly : bool
            Only read: never create, never take a write lock (SQLite opens the file read-only).
        wait : float, optional
            Seconds to wait for another process's lock; default :func:`wait_s` of
            :data:`READ_WAIT_S` or :data:`WRITE_WAIT_S`.

        Raises
        ------
        RecordsUnavailable
            Locked past the wait, read-only for a writer, or unreachable.
        RecordStoreError
            Not a file, damaged, not a database, another table layout or schema.
        """
        url = str(url)
        wait = wait_s(READ_WAIT_S if readonly else WRITE_WAIT_S) if wait is None else wait
        if url.startswith(("postgresql://", "postgres://")):
            return cls._open_postgres(url, readonly, wait)
        path = Path(url.removeprefix("sqlite:///")) if url.startswith("sqlite:///") else Path(url)
        return cls._open_sqlite(path, readonly, wait)

    @classmethod
    def _open_sqlite(cls, path: Path, readonly: bool, wait: float) -> RecordStore:
        shown = printable(path, 1000)
        if path.exists() and not path.is_file():
            raise RecordStoreError(f"--db {shown}: not a file; give the SQLite file 'imu-station run' wrote "
                                   "(or set IMU_STATION_DB)")
        try:
            if readonly:
                conn = cls._connect_readonly(path, wait)
            else:
                path.parent.mkdir(parents=True, exist_ok=True)
                conn = sqlite3.connect(path, timeout=wait, isolation_level=None)
            conn.execute(f"PRAGMA busy_timeout={int(wait * 1000)}")
        except (sqlite3.Error, OSError) as exc:
            raise db_error(exc, shown, wait, "open") from None
        store = cls(conn, "?", str(path), wait)
        try:
            with store._errors("open"):
                if store._layout() == "empty":
                    if readonly:
                        raise RecordStoreError(f"--db {shown}: holds no record table; give the database "
                                               "'imu-station run' wrote")
                    _enable_wal(conn, wait)
                    store._create()
                else:
                    store._check_schema()
                    if not readonly and conn.execute("PRAGMA journal_mode").fetchone()[0] != "wal":
                        _enable_wal(conn, wait)
        except BaseException:
            conn.close()
            raise
        return store

    @staticmethod
    def _connect_readonly(path: Path, wait: float) -> sqlite3.Connection:
        uri = "file:" + urllib.parse.quote(str(path.resolve())) + "?mode=ro"
        try:
            return sqlite3.connect(uri, uri=True, timeout=wait, isolation_level=None)
        except sqlite3.OperationalError:
            # A folder this process cannot write (a read-only share) cannot hold the WAL index a reader
            # needs; with no WAL file beside, everything is in the file and can be read as immutable.
            if Path(f"{path}-wal").exists() or not path.is_file():
                raise
            return sqlite3.connect(uri + "&immutable=1", uri=True, timeout=wait, isolation_level=None)

    @classmethod
    def _open_postgres(cls, url: str, readonly: bool, wait: float) -> RecordStore:
        try:
            import psycopg
        except ImportError:
            raise StationError("--db postgresql://...: psycopg is not installed; install the extra: "
                               "pip install 'imu-station[postgres]'") from None
        shown = url.split("@")[-1]
        try:
            conn = psycopg.connect(url, autocommit=True, connect_timeout=10)
            if readonly:
                conn.execute("SET default_transaction_read_only = on")
            conn.execute(f"SET lock_timeout = {int(wait * 1000)}")
        except psycopg.Error as exc:
            raise RecordsUnavailable(f"--db postgresql://...@{shown}: cannot connect: {exc}".strip()) \
                from None
        store = cls(conn, "%s", url, wait)
        try:
            with store._errors("open"):
                if readonly:
                    if store._layout() == "empty":
                        raise RecordStoreError(f"--db postgresql://...@{shown}: holds no record table")
                    store._check_schema()
                else:
                    store._layout()  # refuses another program's tables of our names
                    store._create()
        except BaseException:
            conn.close()
            raise
        return store

    @property
    def is_postgres(self) -> bool:
        """True for a PostgreSQL store (its SQL placeholders differ)."""
        return self.ph == "%s"

    def _sql(self, text: str) -> str:
        return text.replace("?", self.ph)

    @property
    def shown(self) -> str:
        """The database as messages name it (a PostgreSQL URL without its user and password)."""
        if self.is_postgres:
            return f"postgresql://...@{self.url.split('@')[-1]}"
        return printable(self.url, 1000)

    def _errors(self, doing: str) -> Any:
        """A context that turns a database's own errors into one line naming the database."""
        store = self

        class _Errors:
            def __enter__(self) -> None:
                return None

            def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> Literal[False]:
                if exc is None or isinstance(exc, StationError) or not is_db_error(exc):
                    return False
                raise db_error(exc, store.shown, store.wait, doing) from None

        return _Errors()

    def _layout(self) -> str:
        """``empty`` (no table at all: a new database), else ``ours``; RecordStoreError for a database
        holding other tables, or ours without their columns."""
        if self.is_postgres:
            rows = self.rows("SELECT table_name, column_name FROM information_schema.columns "
                             "WHERE table_schema = current_schema()")
        else:
            rows = self.rows("SELECT m.name, p.name FROM sqlite_master m JOIN pragma_table_info(m.name) p "
                             "WHERE m.type = 'table'")
        columns: dict[str, set[str]] = {}
        for table, column in rows:
            columns.setdefault(str(table), set()).add(str(column))
        if not columns:
            return "empty"
        lacking = [t for t, cols in _COLUMNS.items() if not cols <= columns.get(t, set())]
        if lacking:
            if self.is_postgres and not set(_COLUMNS) & set(columns):
                return "empty"  # a PostgreSQL database holds other applications' tables beside ours
            raise RecordStoreError(
                f"--db {self.shown}: not a record database of this station (another table layout: "
                f"{', '.join(lacking)} {'differs' if len(lacking) == 1 else 'differ'}); give the database "
                "'imu-station run' wrote")
        return "ours"

    def _check_schema(self) -> None:
        row = self.rows("SELECT value FROM meta WHERE key = ?", ("schema",))
        if row and row[0][0] != SCHEMA:
            raise RecordStoreError(f"--db {self.shown}: holds records of schema "
                                   f"{printable(row[0][0], 60)!r}, this station writes {SCHEMA!r}; use "
                                   "another database")

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
                raise RecordStoreError(f"--db {self.shown}: holds records of schema "
                                       f"{printable(row[0], 60)!r}, this station writes {SCHEMA!r}; use "
                                       "another database")

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
                    try:
                        store.conn.execute("COMMIT" if exc_type is None else "ROLLBACK")
                    except sqlite3.Error:
                        if exc_type is None:
                            raise
                        # the statement's own error says more than a failed rollback of nothing
                    finally:
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
        with self._errors("write"), self._transaction() as cur:
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
              station: str | None = None, outcome: str | None = None,
              refused: list[str] | None = None) -> list[RunRecord]:
        """Records in start order; ``since``/``until`` are dates or ISO date-times (UTC when unzoned).

        A row whose JSON is not a record (:class:`BadRecord`) is left out, with one line naming its
        run appended to ``refused`` (when given, else logged as a warning)."""
        where, params = _filters(serial, since, until, station, outcome)
        sql = "SELECT run_id, record FROM runs" + (" WHERE " + " AND ".join(where) if where else "")
        sql += " ORDER BY start_utc, run_id"
        records = []
        for run_id, text in self.rows(sql, params):
            try:
                records.append(RunRecord.from_json(text, f"{self.shown}: run {printable(run_id, 40)}"))
            except BadRecord as exc:
                self._refuse(exc, refused)
        return records

    def _refuse(self, exc: BadRecord, refused: list[str] | None) -> None:
        """One line for a row that is not a record: into ``refused``, else :attr:`refused`, else the log."""
        line = f"{exc}; refused, the other records are read"
        if refused is None:
            refused = self.refused
        if refused is not None:
            refused.append(line)
        else:
            log.warning("%s", line)

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
                           outcome: str | None = None, refused: list[str] | None = None) -> list[tuple]:
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
            :meth:`run_rows` (start order), ``failed`` 1 when it was judged FAIL, else 0. A row of
            another type (text where a number belongs) is left out, its run named once in
            ``refused`` (when given, else logged as a warning).
        """
        where, params = _filters(serial, since, until, station, outcome)
        sql = ("WITH sel AS (SELECT run_id, ROW_NUMBER() OVER (ORDER BY start_utc, run_id) AS pos FROM runs"
               + (" WHERE " + " AND ".join(where) if where else "") + ") "
               "SELECT m.name, m.unit, m.value, m.low, m.high, sel.pos, "
               "CASE WHEN m.outcome = 'FAIL' THEN 1 ELSE 0 END, m.run_id "
               "FROM measurements m JOIN sel ON sel.run_id = m.run_id WHERE m.value IS NOT NULL")
        kept: list[tuple] = []
        bad: dict[Any, Any] = {}  # run id -> the first measurement refused
        for row in self.rows(sql, params):
            if _measurement_row_ok(row):
                kept.append(row[:7])
            else:
                bad.setdefault(row[7], row[0])
        for run_id, name in bad.items():
            self._refuse(BadRecord(f"{self.shown}: run {printable(run_id, 40)}: measurement "
                                   f"{printable(name, 60)!r} is not a number with numeric limits"), refused)
        return kept

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
            Run id to the file's path (its record's files folder joined with the attachment's path);
            a path leading outside that folder is left out.
        """
        where, params = _filters(serial, since, until, station, outcome, prefix="r.")
        sql = ("SELECT r.run_id, r.files_dir, a.path FROM attachments a JOIN runs r ON r.run_id = a.run_id "
               "WHERE a.name = ?" + "".join(f" AND {w}" for w in where))
        return {str(run_id): Path(files_dir) / path
                for run_id, files_dir, path in self.rows(sql, [name, *params])
                if isinstance(files_dir, str) and isinstance(path, str)
                and not attachment_problem(files_dir, path)}

    def table_counts(self) -> dict[str, int]:
        """Rows per table (consistency checks)."""
        return {table: int(self.rows(f"SELECT COUNT(*) FROM {table}")[0][0])
                for table in ("runs", "phases", "measurements", "attachments")}

    def rows(self, sql: str, params: Iterable[Any] = ()) -> list[tuple]:
        """Raw rows of a read query written with ``?`` placeholders (for reports and tests)."""
        with self._errors("read"):
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
