"""A long capture CSV parsed by two processes: this one reads the first half while a forked child reads
the second.

Parsing the numbers of a capture CSV by ``np.loadtxt`` holds the GIL, so a thread does not help: the
86 MB, one-million-row ADIS16405 record took 1.7 s of parsing in one process, most of the whole
``imu-station allan`` run. Split at a line's start near the middle, the two halves parse at once on two
cores. The child only ever hands back arrays: on any problem in its half (a bad value, a cut last line,
time that does not follow on from the first half) this process reads that half itself, line by line,
so every message and warning names the file's own line numbers as a single reader would.

A file whose rows the reader parses by its compiled loop (``capture_csv.reads_compiled``: the station's
own captures without step labels: 0.3 s for that record) is read by one process: forking and handing
half the arrays back would cost more than the parse. Two processes remain for the long files the loop
does not read (step labels, numbers of more than 18 digits such as ``np.savetxt``'s ``%.18e``).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
from collections.abc import Iterator
from multiprocessing.connection import Connection
from pathlib import Path

import numpy as np

from station.acquisition.capture_csv import CHUNK_ROWS, iter_csv_chunks, reads_compiled

Chunk = tuple[np.ndarray, np.ndarray, np.ndarray]  # t, acc, gyro
MIN_BYTES = 32 * 1024 * 1024
"""Files smaller than this are read by one process: forking and handing the arrays back costs more
than half of their parse saves."""


def iter_chunks(path: str | Path, chunk_rows: int = CHUNK_ROWS) -> Iterator[Chunk]:
    """The ``(t, acc, gyro)`` chunks of a capture CSV, in order, parsed by two processes when the file
    is long, uncompressed, not one the compiled loop reads, and the platform forks; else by
    :func:`iter_csv_chunks` alone.

    Parameters
    ----------
    path : str or Path
        The capture CSV.
    chunk_rows : int
        Rows a chunk holds at most.

    Yields
    ------
    tuple of ndarray
        ``t`` (N,), ``acc`` (N, 3), ``gyro`` (N, 3).
    """
    path = Path(path)
    split = _split(path, chunk_rows) if _parallel(path) else None
    own = (c for c in iter_csv_chunks(path, chunk_rows))
    if split is None:
        yield from ((c.t, c.acc, c.gyro) for c in own)
        return
    offset, first_rows = split
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    child = context.Process(target=_parse_half, args=(path, offset, chunk_rows, sender), daemon=True,
                            name="imu-station-csv-half")
    child.start()
    sender.close()
    try:
        rest: Chunk | None = None
        taken = 0
        last_t = -np.inf
        for c in own:
            need = first_rows - taken
            if len(c.t) >= need:
                if need:
                    yield c.t[:need], c.acc[:need], c.gyro[:need]
                    last_t = float(c.t[need - 1])
                rest = (c.t[need:], c.acc[need:], c.gyro[need:])
                break
            taken += len(c.t)
            last_t = float(c.t[-1]) if len(c.t) else last_t
            yield c.t, c.acc, c.gyro
        half = _receive(receiver)
        if half is not None and len(half[0]) and float(half[0][0]) > last_t:
            yield half
            return
        # the child's half failed (or did not follow on): read it here, with the file's line numbers
        if rest is not None and len(rest[0]):
            yield rest
        yield from ((c.t, c.acc, c.gyro) for c in own)
    finally:
        receiver.close()
        if child.is_alive():
            child.terminate()
        child.join()


def _parallel(path: Path) -> bool:
    try:
        size = path.stat().st_size
    except OSError:
        return False  # the single reader says what is wrong with the file
    return (path.suffix.lower() == ".csv" and size >= MIN_BYTES and hasattr(os, "fork")
            and "fork" in multiprocessing.get_all_start_methods() and not reads_compiled(path))


def _split(path: Path, chunk_rows: int) -> tuple[int, int] | None:
    """Where the second half starts: the offset of the start of data row ``k * chunk_rows`` nearest the
    middle (so that this process's chunks end there and it parses no row of the child's), and ``k *
    chunk_rows``; None where the file is too short for that."""
    with open(path, "rb") as fh:
        while True:  # the '#' metadata lines and the header
            line = fh.readline(1 << 16)
            if not line:
                return None
            if not line.startswith(b"#"):
                break
        data_start = fh.tell()
        size = os.fstat(fh.fileno()).st_size
        sample = fh.read(1 << 20)
        rows_per_byte = sample.count(b"\n") / max(len(sample), 1)
        rows = round((size - data_start) * rows_per_byte / 2 / chunk_rows) * chunk_rows
        if rows <= 0:
            return None
        fh.seek(data_start)
        offset = _line_start(fh, rows)
    return None if offset is None or offset >= size else (offset, rows)


def _line_start(fh, rows: int) -> int | None:
    """The offset of the start of the line ``rows`` lines past the file's position."""
    at = fh.tell()
    while rows > 0:
        block = fh.read(1 << 22)
        if not block:
            return None
        found = block.count(b"\n")
        if found < rows:
            rows -= found
            at += len(block)
            continue
        pos = -1
        for _ in range(rows):
            pos = block.index(b"\n", pos + 1)
        return at + pos + 1
    return at


def _parse_half(path: Path, offset: int, chunk_rows: int, sender: Connection) -> None:
    """In the child: parse from ``offset`` to the end and send the arrays, or None on any problem."""
    import signal
    import warnings

    # Ctrl-C is the parent's to handle, and it ends this child with SIGTERM: die quietly then
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a warning (a cut last line) is the parent's to give
            parts = [(c.t, c.acc, c.gyro) for c in iter_csv_chunks(path, chunk_rows, from_byte=offset)]
        half: Chunk | None = None
        if parts:
            half = (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                    np.concatenate([p[2] for p in parts]))
        sender.send(half)
    except Exception:  # noqa: BLE001  (any problem: the parent reads this half itself)
        with contextlib.suppress(OSError):
            sender.send(None)
    finally:
        sender.close()


def _receive(receiver: Connection) -> Chunk | None:
    try:
        half = receiver.recv()
    except (EOFError, OSError):  # the child died: read its half here
        return None
    return half if isinstance(half, tuple) else None
