"""Atomic file writes: a reader sees the old file or the new one, never half of either; and sets of
files written by one command, which appear together or not at all.

Every output goes through :func:`atomic_open` (a temporary file beside the target, fsynced, then
renamed over it). Inside :func:`output_set`, the rename waits: the set's files are all written
first, and renamed one after the other only once the last is whole, with Ctrl-C and SIGTERM held
back for those few microseconds; an error or an interrupt before then removes every temporary
file and leaves every old file as it was. So ``allan`` never leaves a new Kalibr file beside the
old parameter file, nor ``export -f c`` a new header beside an older unit's blob.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import tempfile
import threading
from collections.abc import Iterator
from contextvars import ContextVar
from pathlib import Path
from types import FrameType
from typing import IO


def _read_umask() -> int:
    # Read once at import: os.umask can only be read by setting it, which is not thread-safe.
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: str = "w",
                encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success fsync it and rename it over ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    binary = "b" in mode
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    # mkstemp makes 0600; an output file gets the mode any new file would get (0666 less umask).
    os.chmod(tmp, 0o666 & ~_UMASK)
    try:
        with os.fdopen(fd, mode, encoding=None if binary else encoding) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        outputs = _CURRENT_SET.get()
        if outputs is None:
            os.replace(tmp, path)
        else:
            outputs.stage(Path(tmp), path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


class OutputSet:
    """The files one command writes, staged under temporary names until all are written
    (:func:`output_set`)."""

    def __init__(self) -> None:
        self._staged: dict[Path, Path] = {}  # target (absolute) -> its temporary file, in order

    def stage(self, tmp: Path, path: Path) -> None:
        """Hold ``tmp`` (whole and fsynced) until the set is committed, then rename it to ``path``; a
        second write of ``path`` in the set replaces the first."""
        target = path.absolute()
        earlier = self._staged.pop(target, None)
        if earlier is not None:
            with contextlib.suppress(FileNotFoundError):
                earlier.unlink()
        self._staged[target] = tmp

    def staged(self, path: str | os.PathLike[str]) -> Path:
        """Where ``path``'s new content is until the set is committed (``path`` itself if the set
        did not write it): for a step that reads what an earlier step wrote (a PDF printed from the
        page just written)."""
        return self._staged.get(Path(path).absolute(), Path(path))

    def commit(self) -> None:
        """Rename every staged file to its target, with Ctrl-C and SIGTERM held back meanwhile (they
        take effect once the set is whole)."""
        with _signals_held():
            for target, tmp in self._staged.items():
                os.replace(tmp, target)
        self._staged.clear()

    def discard(self) -> None:
        """Remove every staged file: the targets stay as they were."""
        for tmp in self._staged.values():
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
        self._staged.clear()


_CURRENT_SET: ContextVar[OutputSet | None] = ContextVar("imu_station_output_set", default=None)


@contextlib.contextmanager
def output_set() -> Iterator[OutputSet]:
    """Write a command's files as one set: every :func:`atomic_open` inside the block stages its
    file, and the files are renamed into place together when the block ends, or all discarded when
    it raises (an error, Ctrl-C, SIGTERM). Sets do not nest: an inner block joins the outer set."""
    outer = _CURRENT_SET.get()
    if outer is not None:
        yield outer
        return
    outputs = OutputSet()
    token = _CURRENT_SET.set(outputs)
    try:
        yield outputs
    except BaseException:
        outputs.discard()
        raise
    finally:
        _CURRENT_SET.reset(token)
    outputs.commit()


def staged_path(path: str | os.PathLike[str]) -> Path:
    """``path``'s new content within the current :func:`output_set` (``path`` outside one)."""
    outputs = _CURRENT_SET.get()
    return Path(path) if outputs is None else outputs.staged(path)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """Defer SIGINT and SIGTERM (main thread only: Python runs handlers there) until the block ends,
    then act on the first that came, as its handler would have."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[tuple[int, FrameType | None]] = []
    held = (signal.SIGINT, signal.SIGTERM)
    before = {int(sig): signal.getsignal(sig) for sig in held}
    for sig in held:
        signal.signal(sig, lambda signum, frame: came.append((signum, frame)))
    try:
        yield
    finally:
        for number, handler in before.items():
            signal.signal(number, handler)
    if came:
        signum, frame = came[0]
        handler = before[signum]
        if callable(handler):
            handler(signum, frame)
        elif handler == signal.SIG_DFL:
            signal.raise_signal(signum)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` atomically (:func:`atomic_open`): the file is whole or untouched."""
    with atomic_open(path, "w") as fh:
        fh.write(text)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (:func:`atomic_open`): the file is whole or untouched."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def sha256_file(path: str | os.PathLike[str]) -> str:
    """The SHA-256 of a file's bytes, in hex, read in 1 MiB pieces (a capture may be gigabytes).

    Parameters
    ----------
    path : str or path-like
        The file.

    Returns
    -------
    str
        64 lowercase hex digits.
    """
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()
