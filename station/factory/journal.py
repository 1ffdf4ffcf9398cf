"""A long run's journal: the completed steps, append-only, each line on the disk before the next step.

``journal.jsonl`` in the run's folder, one JSON object a line (schema ``imu-station/journal/1``)::

    {"type": "begin", "journal": "imu-station/journal/1", "seq": 0, "time": ..., "run_id": ...,
     "start": ..., "serial": ..., "station": ..., "plan": {"path", "sha256", "name"},
     "simulate": {"seed", "grade"} | null, "phases": [the record's first phases]}
    {"type": "step", "seq": 1, "time": ..., "step": "ramp-1", "phase": {a record phase},
     "files": [{"path": "ramp-1.csv", "sha256": ..., "size": ...}], "results": {...}, "unit_c": 21.9}
    ...
    {"type": "end", "seq": n, "time": ..., "outcome": "PASS", "record": "record.json"}

A line is written with one ``write`` and ``fsync``'ed before the step after it begins, so a crash
(``kill -9``, a power cut) leaves every completed step journaled, and at worst a torn last line,
which :meth:`Journal.open` cuts off (keeping the torn bytes in ``journal.torn``). Every file a step
names was closed and fsync'ed before its line was written; :meth:`Journal.verify` checks their
SHA-256 on resume.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from station.errors import InputFileError, StationError
from station.factory.records import sha256_file, utc_now

SCHEMA = "imu-station/journal/1"
NAME = "journal.jsonl"
TORN = "journal.torn"


class JournalError(StationError):
    """A run folder whose journal cannot be resumed from (missing, foreign, ended, files changed)."""


def fsync_dir(folder: Path) -> None:
    """Make a folder's entries (files created or renamed in it) durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def file_entry(folder: Path, path: Path) -> dict[str, Any]:
    """A file a step wrote, as the journal names it: path relative to ``folder``, SHA-256, size."""
    return {"path": str(path.relative_to(folder)), "sha256": sha256_file(path), "size": path.stat().st_size}


class Journal:
    """The journal of one run folder: its entries so far, and appending more.

    Parameters
    ----------
    folder : Path
        The run's folder (the journal is ``folder / NAME``).
    entries : list of dict
        The entries read (or written) so far.
    """

    def __init__(self, folder: Path, entries: list[dict[str, Any]]):
        self.folder = folder
        self.path = folder / NAME
        self.entries = entries
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    @classmethod
    def create(cls, folder: Path, begin: dict[str, Any]) -> Journal:
        """Start the journal of a new run with its ``begin`` entry.

        Raises
        ------
        JournalError
            The folder already has a journal.
        """
        if (folder / NAME).exists():
            raise JournalError(f"{folder / NAME} exists: this folder holds a run already; resume it with "
                               f"--resume {folder}")
        journal = cls(folder, [])
        journal.append({"type": "begin", "journal": SCHEMA, **begin})
        fsync_dir(folder)
        return journal

    @classmethod
    def open(cls, folder: Path) -> Journal:
        """Read a run folder's journal for a resume; a torn last line is cut off (kept in ``journal.torn``).

        Raises
        ------
        JournalError
            No journal, or one that has ended (its run is recorded).
        InputFileError
            A line that is not a journal entry (not the last: a torn last line is expected).
        """
        path = folder / NAME
        if not folder.is_dir():
            raise JournalError(f"{folder}: no such run folder; give the folder the run printed "
                               "(FILES/<serial>/<start>-<run id>)")
        if not path.is_file():
            raise JournalError(f"{folder}: no {NAME}: the run never got past connecting to the unit (or this "
                               "is not a campaign's folder); start the campaign again")
        raw = path.read_bytes()
        good_end = raw.rfind(b"\n") + 1
        entries: list[dict[str, Any]] = []
        for number, line in enumerate(raw[:good_end].splitlines(), 1):
            try:
                entry = json.loads(line)
            except ValueError:
                entry = None
            if not isinstance(entry, dict) or entry.get("seq") != len(entries) or "type" not in entry:
                raise InputFileError(path, "is not a journal line this station wrote (or it was edited); the "
                                     "run cannot be resumed from it", line=number)
            entries.append(entry)
        if not entries or entries[0].get("journal") != SCHEMA:
            raise InputFileError(path, f"does not begin with a {SCHEMA} entry", line=1)
        if good_end < len(raw):
            # The write a crash cut: the step it described was not complete, and is done again.
            with open(folder / TORN, "ab") as torn:
                torn.write(raw[good_end:] + b"\n")
            os.truncate(path, good_end)
        if entries[-1]["type"] == "end":
            raise JournalError(f"{folder}: the run ended ({entries[-1].get('outcome')}) and its record is "
                               f"written ({entries[-1].get('record')}); a run is resumed only after a crash")
        return cls(folder, entries)

    @property
    def begin(self) -> dict[str, Any]:
        """The first entry (the run's identity and its first phases)."""
        return self.entries[0]

    def steps(self) -> dict[str, dict[str, Any]]:
        """The completed steps by id."""
        return {e["step"]: e for e in self.entries if e["type"] == "step"}

    def append(self, entry: dict[str, Any]) -> dict[str, Any]:
        """Write one entry (numbered, timed) as one line, and fsync it before returning.

        Raises
        ------
        JournalError
            A step that is journaled already (a step is never recorded twice).
        """
        if entry.get("type") == "step" and entry.get("step") in self.steps():
            raise JournalError(f"{self.path}: step {entry['step']} is journaled already")
        full = {"seq": len(self.entries), "time": utc_now(), **entry}
        line = (json.dumps(full, allow_nan=False, sort_keys=True) + "\n").encode()
        os.write(self._fd, line)  # O_APPEND: one write, at the end
        os.fsync(self._fd)
        self.entries.append(full)
        return full

    def verify(self) -> list[str]:
        """Check every journaled file against its SHA-256; returns the problems (empty: all intact)."""
        problems = []
        for entry in self.entries:
            for f in entry.get("files", []):
                path = self.folder / f["path"]
                if not path.is_file():
                    problems.append(f"{path}: missing (journaled by step {entry.get('step')})")
                elif sha256_file(path) != f["sha256"]:
                    problems.append(f"{path}: changed since step {entry.get('step')} wrote it "
                                    "(SHA-256 differs)")
        return problems

    def last_unit_c(self) -> float | None:
        """The unit's temperature at the last step that measured it."""
        for entry in reversed(self.entries):
            if entry.get("unit_c") is not None:
                return float(entry["unit_c"])
        return None

    def close(self) -> None:
        """Close the journal's file."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
