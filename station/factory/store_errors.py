"""The record store's errors, one line each, and how long it waits for another process's lock.

SQLite and psycopg report a locked, read-only, damaged or foreign database with their own
exceptions and texts; :func:`db_error` turns them into :class:`RecordsUnavailable` (may work
again unchanged: a run keeps its record pending) or :class:`RecordStoreError` (the file itself is
wrong: damaged, not a database), each naming the database and what to do.
"""

from __future__ import annotations

import os
import sqlite3

from station.common.text import printable
from station.errors import StationError

WAIT_ENV = "IMU_STATION_DB_WAIT"
"""Seconds, replacing both waits (a slow shared disk, or a test)."""


class RecordStoreError(StationError):
    """The record database cannot be used: damaged, not a database, another layout, or unreachable."""


class RecordsUnavailable(RecordStoreError):
    """The record database cannot be written or read now (locked, read-only, unreachable); a run
    keeps its record pending beside its files until ``imu-station records sync`` stores it."""


def wait_s(default: float) -> float:
    """``$IMU_STATION_DB_WAIT`` when set, else ``default``: how long to wait for a lock, in seconds."""
    text = os.environ.get(WAIT_ENV)
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= 3600.0:
        raise StationError(f"{WAIT_ENV}={printable(text, 40)}: give seconds from 0 to 3600")
    return value


# Words of SQLite's and psycopg's messages for a database that may work again later, unchanged.
_TRANSIENT = ("locked", "busy", "readonly", "read-only", "unable to open", "disk i/o", "full",
              "connection", "server", "timeout", "could not")


def is_db_error(exc: BaseException) -> bool:
    """True for an error of SQLite or psycopg (which :func:`db_error` turns into one line)."""
    return isinstance(exc, sqlite3.Error) or type(exc).__module__.split(".")[0] == "psycopg"


def db_error(exc: BaseException, shown: str, wait: float, doing: str) -> RecordStoreError:
    """The one-line error for a database's own error while ``doing`` (open, read, write)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    low = text.lower()
    if "locked" in low or "busy" in low or "lock timeout" in low:
        return RecordsUnavailable(f"--db {shown}: the record database is locked by another process; waited "
                                  f"{wait:g} s (${WAIT_ENV} sets the wait); try again when it is done")
    if "readonly" in low or "read-only" in low:
        return RecordsUnavailable(f"--db {shown}: the record database is read-only here ({text}); make it "
                                  "and its folder writable")
    if isinstance(exc, OSError):
        return RecordStoreError(f"--db {shown}: cannot {doing} the record database: {text}")
    if type(exc).__name__ == "OperationalError" or any(w in low for w in _TRANSIENT):
        return RecordsUnavailable(f"--db {shown}: cannot {doing} the record database: {text}")
    return RecordStoreError(f"--db {shown}: the record database is damaged or not a database ({text}); "
                            "restore it from a backup, or recover what is left with "
                            "'sqlite3 FILE .recover | sqlite3 NEW.sqlite'")
