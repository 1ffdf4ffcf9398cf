"""A stored record read back as data, never trusted: its JSON checked field by field, its files read
only where they belong.

A row of the record database, or a record spooled beside a run's files, may be partial (a crash,
a hand edit), from another program, or hostile. :func:`build` turns its JSON into the record's
dataclasses only when every field has the type the dataclass declares, and raises
:class:`BadRecord` (one line naming the field) otherwise, so a reader refuses that row and goes on
with the others. :func:`attachment_problem` and :func:`hash_problem` decide whether an attachment
may be read (a plain relative path to a regular file inside the record's files folder) and read it
with a bound: no absolute path, no ``..``, no link out of the folder, no device or FIFO (opened
without blocking), never more bytes than the record says the file has.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import stat
import types
import typing
from pathlib import Path, PurePath
from typing import Any

from station.common.text import printable
from station.errors import StationError

MAX_RECORD_CHARS = 64 << 20
"""A record's JSON longer than this is refused unread (a real record is a few hundred kB at most)."""


class BadRecord(StationError):
    """A stored record that is not one this station wrote: a field missing or of another type, or
    text that is not JSON. Readers refuse its row in one line and read the others."""


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


def parse_json(text: object, where: str) -> dict[str, Any]:
    """The record's JSON text as a dict, or :class:`BadRecord`.

    Parameters
    ----------
    text : object
        What the database or the spool file holds (text, or anything else a foreign row holds).
    where : str
        What to name in the message (the database's row, or the spool file).

    Returns
    -------
    dict
        The parsed object; ``NaN`` and ``Infinity`` are refused, as the station never writes them.
    """
    if not isinstance(text, str):
        raise BadRecord(f"{where}: the record is {type(text).__name__}, not JSON text")
    if len(text) > MAX_RECORD_CHARS:
        raise BadRecord(f"{where}: the record is {len(text)} characters long, beyond {MAX_RECORD_CHARS}")
    try:
        data = json.loads(text, parse_constant=_refuse_constant)
    except (ValueError, RecursionError) as exc:
        raise BadRecord(f"{where}: the record is not valid JSON ({printable(exc, 80)})") from None
    if not isinstance(data, dict):
        raise BadRecord(f"{where}: the record is a JSON {type(data).__name__}, not an object")
    return data


def build(cls: type, data: object, where: str) -> Any:
    """An instance of the dataclass ``cls`` from plain data, every field checked against its type.

    Parameters
    ----------
    cls : type
        A dataclass whose fields are typed with ``str``, ``int``, ``float``, ``None``, unions of
        them, ``dict[str, Any]``, ``Any`` and lists of these or of other such dataclasses.
    data : object
        The parsed JSON.
    where : str
        The path to ``data`` in the record, for the message (``record.phases[2]``).

    Returns
    -------
    object
        ``cls(**data)``, nested dataclasses built too.

    Raises
    ------
    BadRecord
        A key the dataclass does not have, a field without a default that is missing, or a value of
        another type.
    """
    if not isinstance(data, dict):
        raise BadRecord(f"{where} is {_kind(data)}, not an object")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        raise BadRecord(f"{where} has a key this station does not write: {printable(unknown[0], 40)!r}")
    values = {}
    for name, f in fields.items():
        if name in data:
            values[name] = _value(data[name], hints[name], f"{where}.{name}")
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise BadRecord(f"{where} lacks {name!r}")
    return cls(**values)


def _kind(value: object) -> str:
    return "null" if value is None else f"a {type(value).__name__}"


def _value(value: object, hint: Any, where: str) -> Any:
    """``value`` if it has the type ``hint`` (lists and nested dataclasses built), else BadRecord."""
    origin = typing.get_origin(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        for option in typing.get_args(hint):
            try:
                return _value(value, option, where)
            except BadRecord:
                continue
        raise BadRecord(f"{where} is {_kind(value)}, not {printable(hint, 60)}")
    if origin is list:
        if not isinstance(value, list):
            raise BadRecord(f"{where} is {_kind(value)}, not a list")
        (item,) = typing.get_args(hint)
        return [_value(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise BadRecord(f"{where} is {_kind(value)}, not an object")
        return value  # JSON object keys are text; the values are the plan's or the device's own
    if dataclasses.is_dataclass(hint):
        return build(hint, value, where)  # type: ignore[arg-type]
    if hint is type(None):
        ok = value is None
    elif hint is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    elif hint is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    else:
        ok = isinstance(value, hint)
    if not ok:
        raise BadRecord(f"{where} is {_kind(value)}, not {getattr(hint, '__name__', hint)}")
    return value


def attachment_problem(files_dir: str, rel: str, root: Path | None = None) -> str:
    """Why the attachment at ``rel`` of a record whose files are in ``files_dir`` may not be read;
    empty when it may.

    Parameters
    ----------
    files_dir : str
        The record's files folder.
    rel : str
        The attachment's path, relative to it.
    root : Path, optional
        The files folder of the whole database (``--files``): the record's folder must be inside.

    Returns
    -------
    str
        Empty, or the reason, beginning with ``missing`` (the file is not where a record's file is).
    """
    if not files_dir:
        return "missing: the record names no files folder"
    path = PurePath(rel)
    if not rel or "\0" in rel or "\0" in files_dir or path.is_absolute() or ".." in path.parts:
        return "missing: its path leads outside the record's files folder, so it is not read"
    folder = Path(files_dir).resolve()
    if root is not None and not folder.is_relative_to(Path(root).resolve()):
        return f"missing: the record's files folder is outside {printable(root)}, so it is not read"
    if not (folder / rel).resolve().is_relative_to(folder):
        return "missing: a link leads outside the record's files folder, so it is not read"
    return ""


def hash_problem(path: Path, size: int, sha256: str) -> str:
    """Why the file at ``path`` is not the one recorded (``size`` bytes with SHA-256 ``sha256``);
    empty when it is. Only a regular file is read, opened without blocking and without following a
    last link, and never beyond ``size`` + 1 bytes.

    Parameters
    ----------
    path : Path
        The attachment, already allowed by :func:`attachment_problem`.
    size : int
        Its size in bytes, as recorded.
    sha256 : str
        Its SHA-256, as recorded.

    Returns
    -------
    str
        Empty, ``missing...`` or ``SHA-256 differs from the record's...``.
    """
    try:
        # O_NONBLOCK: opening a FIFO for reading would otherwise wait for a writer forever.
        fd = os.open(path.resolve(), os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"missing: cannot be opened ({exc.strerror})"
    with os.fdopen(fd, "rb") as fh:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            return "missing: not a regular file, so it is not read"
        if info.st_size != size:
            return f"SHA-256 differs from the record's (its size does: {info.st_size} bytes, recorded {size})"
        digest = hashlib.sha256()
        left = size + 1  # one byte more than recorded tells a file that grew since the fstat
        while left > 0:
            chunk = fh.read(min(left, 1 << 20))
            if not chunk:
                break
            digest.update(chunk)
            left -= len(chunk)
    return "" if digest.hexdigest() == sha256 else "SHA-256 differs from the record's"
