"""Records waiting for their database: a run's outcome never depends on the database being writable.

When the record database is locked past its wait, read-only, damaged or unreachable at the end of a
run, the record is kept in the files folder as ``pending-records/<run id>.json`` (beside the
runs' own folders, where ``record.json`` is kept too) and the run's exit code stays the unit's
outcome. ``imu-station records sync`` stores every pending record, and so does the next run that
stores its own; a stored record's file is removed. Storing twice is harmless: a record replaces
the one with its run id.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from station.common.files import atomic_write_text
from station.common.text import printable
from station.factory.record_checks import MAX_RECORD_CHARS, BadRecord
from station.factory.records import RecordStore, RecordStoreError, RunRecord

PENDING_DIR = "pending-records"


@dataclass
class Pending:
    """A record kept pending: where its file is, and why the database did not take it."""

    path: Path
    reason: str


@dataclass
class Synced:
    """What a sync did: records stored, and one line for each pending file refused (left in place)."""

    stored: list[str]
    refused: list[str]


def pending_dir(files_root: Path) -> Path:
    """The folder of pending records under the files folder ``files_root``."""
    return Path(files_root) / PENDING_DIR


def pending_files(files_root: Path) -> list[Path]:
    """The pending records' files (named ``*.json``), oldest first; :func:`sync` reads regular files
    alone and refuses the others by name."""
    folder = pending_dir(files_root)
    if not folder.is_dir():
        return []
    found = []
    for path in folder.glob("*.json"):
        with contextlib.suppress(OSError):
            found.append((path.lstat().st_mtime_ns, path.name, path))
    return [p for _, _, p in sorted(found)]


def spool(record: RunRecord, files_root: Path) -> Path:
    """Keep ``record`` pending: written whole (atomically) as ``pending-records/<run id>.json``.

    Parameters
    ----------
    record : RunRecord
        The finished record.
    files_root : Path
        The files folder of the database the record belongs in.

    Returns
    -------
    Path
        The pending file.
    """
    path = pending_dir(files_root) / f"{record.run_id}.json"
    atomic_write_text(path, json.dumps(record.to_dict(), indent=1, allow_nan=False) + "\n")
    return path


def _read(path: Path) -> RunRecord:
    """The pending record in ``path``; BadRecord for a file that is not one (never a FIFO or device)."""
    where = printable(path, 1000)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    except OSError as exc:
        raise BadRecord(f"{where}: cannot be read ({exc.strerror})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise BadRecord(f"{where}: not a regular file")
        data = fh.read(MAX_RECORD_CHARS + 1)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise BadRecord(f"{where}: the record is not UTF-8 text") from None
    return RunRecord.from_json(text, where)


def sync(store: RecordStore, files_root: Path) -> Synced:
    """Store every pending record of ``files_root`` in ``store`` and remove its file.

    Parameters
    ----------
    store : RecordStore
        The database, opened for writing.
    files_root : Path
        Its files folder.

    Returns
    -------
    Synced
        The run ids stored; one line per file that is not a record (left where it is).

    Raises
    ------
    RecordStoreError
        The database would not take a record (the rest stay pending).
    """
    done = Synced([], [])
    for path in pending_files(files_root):
        try:
            record = _read(path)
        except BadRecord as exc:
            done.refused.append(f"{exc}; left pending, the others are stored")
            continue
        store.save(record)
        with contextlib.suppress(FileNotFoundError):  # another station's run stored it at the same time
            path.unlink()
        done.stored.append(record.run_id)
    return done


def keep(record: RunRecord, target: RecordStore | str, files_root: Path) -> Pending | None:
    """Store ``record`` in the database, then the records pending there; if the database does not take
    it, keep it pending instead.

    Parameters
    ----------
    record : RunRecord
        The finished run's record.
    target : RecordStore or str
        The record database, open or by its URL (opened for this record alone, so a database that
        was unwritable during the run is tried afresh).
    files_root : Path
        Its files folder, where a pending record is kept.

    Returns
    -------
    Pending or None
        None when the record is stored; else where it is kept and why.
    """
    try:
        if isinstance(target, RecordStore):
            _store(target, record, files_root)
        else:
            with RecordStore.open(target) as store:
                _store(store, record, files_root)
    except RecordStoreError as exc:
        return Pending(spool(record, files_root), str(exc))
    return None


def _store(store: RecordStore, record: RunRecord, files_root: Path) -> None:
    store.save(record)
    with contextlib.suppress(RecordStoreError):  # those that still fail stay pending for the next time
        sync(store, files_root)
