"""The capture CSV of ``shared/specs/capture-csv.md``: reader and streaming writer.

``# key: value`` metadata lines naming the unit (:mod:`station.acquisition.capture_metadata`; read
into ``Capture.device``), one header row, then one row per sample; columns in any order, unknown
columns ignored.
Required: t, ax, ay, az, gx, gy, gz; optional: temp, dtemp, step and the magnetometer's
mx, my, mz (microtesla, all three or none; ``nan`` cells for a sample without a field).
Malformed input is refused with a message naming the file, line and column, but for a last line
cut short (no line end, not a whole row: a power loss during a capture), which is left out with an
:class:`~station.errors.InputFileWarning`.

Memory stays bounded whatever the file holds: a line longer than ``MAX_LINE_CHARS`` is refused
(naming its line) without being read whole, and a chunk ends once its lines hold ``CHUNK_CHARS``
characters, so a chunk of long lines is not ``CHUNK_ROWS`` of them.

A long file's rows are parsed by a compiled loop (:mod:`station.acquisition._csv_kernel`, 0.3 s
against ``np.loadtxt``'s 1.6 s for a million rows); a chunk it does not read whole, and every chunk
after it, is read by ``np.loadtxt`` from its first line, so that what is refused or warned of is
said the same way, at the same line, whichever parse met it.

Why this module is long: the reader and the writers keep one spec's columns and rules; the reader's
two parses must end their chunks at the same rows and put the values through the same checks
(:class:`_Rows`), which apart would have to be stated twice and kept in step by hand.
"""

from __future__ import annotations

import contextlib
import functools
import gzip
import io
import itertools
import math
import os
import warnings
from collections.abc import Callable, Generator, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np

from protocols.base import has_mag
from station.acquisition import capture_metadata
from station.acquisition.capture_data import Capture
from station.errors import InputFileError, InputFileWarning, OutputFileError

REQUIRED = ("t", "ax", "ay", "az", "gx", "gy", "gz")
OPTIONAL_NUMERIC = ("temp", "dtemp")
MAG_COLUMNS = ("mx", "my", "mz")
HEADER = ("t", "ax", "ay", "az", "gx", "gy", "gz", "temp", "dtemp", "mx", "my", "mz", "step")
CHUNK_ROWS = 200_000
MAX_LINE_CHARS = 64 * 1024
"""The longest line read (its end included). A sample row is under 200 characters; this leaves room
for a few thousand columns the reader ignores, and refuses a file of one endless line (a 1 GB
line used to be read whole, then split, and end in a MemoryError)."""
CHUNK_CHARS = 64 * 1024 * 1024
"""A chunk ends once its lines hold this many characters (and, checked every ``_BATCH`` lines, by
at most ``_BATCH * MAX_LINE_CHARS`` more)."""
_BATCH = 64
"""Lines read between checks of their length: an endless line costs at most ``_BATCH`` pieces of
``MAX_LINE_CHARS`` (4 Mi characters) before it is refused."""
FAST_BYTES = 24 * 1024 * 1024
"""Files of this many bytes or more have their rows parsed by the compiled loop of
:mod:`station.acquisition._csv_kernel` (five times ``np.loadtxt``'s speed). Below, loading numba where
a command has not (about 0.3 s) and compiling the loop on a fresh install cost more than it saves."""
_BLOCK = 1 << 20
"""Bytes the compiled parse reads at a time (memory stays within a few of them, as the text reader's)."""
_PROBE_ROWS = 64
"""Rows :func:`reads_compiled` has the compiled loop read."""
_FIRST_ROOM = 1 << 14
"""Rows the compiled parse makes room for first, doubled as a chunk needs (a chunk of long lines holds
far fewer than ``CHUNK_ROWS``)."""


def _open_text(path: Path) -> IO[str]:
    if path.suffix == ".gz":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", newline="")
    return open(path, encoding="utf-8", newline="")


def _locate_bad_value(path: Path, lines: list[str], first_line: int,
                      columns: dict[str, int]) -> InputFileError:
    """Slow path, only after the fast parse failed: find the first bad cell and name it."""
    found = _bad_cell(path, lines, first_line, columns)
    return found or InputFileError(path, "could not be parsed as numbers", line=first_line)


def _bad_cell(path: Path, lines: list[str], first_line: int,
              columns: dict[str, int]) -> InputFileError | None:
    """The error of the first bad cell of ``lines``, or None when every row is whole and numeric."""
    for offset, line in enumerate(lines):
        cells = line.rstrip("\r\n").split(",")
        for name, idx in columns.items():
            if idx >= len(cells):
                return InputFileError(path, f"row has {len(cells)} cells, the header names {idx + 1} or more",
                                      line=first_line + offset, column=name)
            try:
                value = float(cells[idx])
            except ValueError:
                return InputFileError(path, f"value {cells[idx]!r} is not a number", line=first_line + offset,
                                      column=name)
            if name in REQUIRED and not math.isfinite(value):
                return InputFileError(path, f"value {cells[idx]!r} is not a finite number",
                                      line=first_line + offset, column=name)
    return None


def _drop_cut_line(path: Path, lines: list[str], first_line: int, columns: dict[str, int]) -> None:
    """Drop the file's last line from ``lines`` if a write cut it short, and warn.

    A capture written in place loses the end of its last row when the power or the station goes
    (``CsvCaptureWriter`` keeps whole rows, but the OS may not have written them all): that row has
    no line end and does not parse. It alone is dropped; a bad row anywhere else is refused.
    """
    if not lines or lines[-1].endswith("\n"):
        return
    at = first_line + len(lines) - 1
    problem = _bad_cell(path, lines[-1:], at, columns)
    if problem is None:
        return
    lines.pop()
    where = f", column '{problem.column}'" if problem.column else ""
    warnings.warn(InputFileWarning(
        f"{path}, line {at}: the last line is cut short ({problem.problem}{where}; no line end), as a power "
        "loss during a capture leaves it: it is left out"), stacklevel=2)


def _read_metadata(path: Path, readline: Callable[[], str]) -> tuple[str, int, dict[str, Any]]:
    """The header line, its line number and the device info of the ``# key: value`` lines before it."""
    metadata: dict[str, str] = {}
    line_no = 0
    while True:
        line_no += 1
        try:
            line = readline()
        except (UnicodeDecodeError, OSError, EOFError) as exc:
            raise InputFileError(path, f"is not a readable text file ({exc})", line=line_no) from None
        _check_length(path, [line], line_no)
        if not line.startswith("#"):
            return line, line_no, capture_metadata.device_of(metadata)
        if line_no > capture_metadata.MAX_LINES:
            raise InputFileError(path, f"has more than {capture_metadata.MAX_LINES} '#' lines before the "
                                 "header row: is this a capture CSV?", line=line_no)
        parsed = capture_metadata.parse_line(line)
        if parsed is not None:
            metadata.setdefault(*parsed)


def iter_csv_chunks(path: str | Path, chunk_rows: int = CHUNK_ROWS,
                    from_byte: int | None = None) -> Iterator[Capture]:
    """Read a capture CSV in chunks of at most ``chunk_rows`` rows, in bounded memory.

    Checks every rule of the spec across chunk borders (t strictly increasing included). With
    ``from_byte`` (the offset of a line's start in an uncompressed file), the rows from there on, read
    with the file's header: a part of the file for another process (line numbers in its messages then
    count from that offset, as if the header stood just before it). A file of ``FAST_BYTES`` or more
    without step labels has its rows parsed by a compiled loop (the same chunks and values; any chunk
    it does not read whole is read by ``np.loadtxt`` from its first line, with every message).
    """
    path = Path(path)
    with _open_reader(path) as fh:
        # every line is read with readline(limit): a line without an end in reach is refused, never read whole
        readline = functools.partial(fh.readline, MAX_LINE_CHARS + 1)
        rows, data_at, fields, step_idx = _header(path, readline)
        if from_byte is not None:
            fh.seek(from_byte)  # a line's start: the UTF-8 decoder holds no state there
            data_at = from_byte
        if step_idx is None and _compiled(path):
            resume = yield from _compiled_chunks(rows, data_at, fields, chunk_rows)
            if resume is None:
                return
            fh.seek(resume)  # the start of the chunk it did not read whole: a line's start
        numeric = rows.columns
        usecols = list(numeric.values())
        while True:
            try:
                lines, at_end = _read_chunk(path, readline, chunk_rows, rows.line_no + 1)
            except UnicodeDecodeError as exc:
                raise InputFileError(path, f"is not UTF-8 text ({exc.reason})",
                                     line=rows.line_no + 1) from None
            if at_end:
                # The end of the file: blank lines there are harmless; inside the file they are refused.
                while lines and not lines[-1].strip():
                    lines.pop()
                _drop_cut_line(path, lines, rows.line_no + 1, numeric)
            if not lines:
                return
            try:
                values = np.loadtxt(lines, delimiter=",", usecols=usecols, ndmin=2, dtype=float)
                if values.shape[0] != len(lines):
                    raise ValueError
            except (ValueError, IndexError):
                raise _locate_bad_value(path, lines, rows.line_no + 1, numeric) from None
            step = None
            if step_idx is not None:
                step = np.array([_cell(ln, step_idx) for ln in lines], dtype=object)
            yield rows.capture(values, step)


def _open_reader(path: Path) -> IO[str]:
    try:
        return _open_text(path)
    except FileNotFoundError:
        raise InputFileError(path, "does not exist; give a capture CSV or capture file") from None
    except OSError as exc:
        raise InputFileError(path, f"cannot be opened: {exc.strerror}") from None


def _header(path: Path, readline: Callable[[], str]) -> tuple[_Rows, int, int, int | None]:
    """The metadata and header lines read and checked: the checks of the rows to come, the byte where
    they start, the header's field count and the step labels' field (None without)."""
    head_bytes = 0

    def counted() -> str:
        nonlocal head_bytes
        line = readline()
        head_bytes += len(line.encode("utf-8"))  # the decoder is strict and newline="": the file's bytes
        return line

    header_line, line_no, device = _read_metadata(path, counted)
    header = [h.strip() for h in header_line.rstrip("\r\n").split(",")]
    if not header_line.strip():
        raise InputFileError(path, "is empty; expected a header row: " + ",".join(HEADER), line=line_no)
    for name in REQUIRED:
        if name not in header:
            raise InputFileError(path, f"header lacks the required column; it has {header}", line=line_no,
                                 column=name)
    mag_present = [n for n in MAG_COLUMNS if n in header]
    if mag_present and len(mag_present) < len(MAG_COLUMNS):
        missing = [n for n in MAG_COLUMNS if n not in header]
        raise InputFileError(path, f"header has {', '.join(mag_present)} but not {', '.join(missing)}: "
                             f"the magnetometer needs all three columns (microtesla) or none",
                             line=line_no, column=missing[0])
    numeric = {n: header.index(n) for n in REQUIRED + OPTIONAL_NUMERIC + MAG_COLUMNS if n in header}
    step_idx = header.index("step") if "step" in header else None
    return _Rows(path, numeric, bool(mag_present), device, line_no), head_bytes, len(header), step_idx


def reads_compiled(path: str | Path) -> bool:
    """Whether :func:`iter_csv_chunks` parses the rows of ``path`` by the compiled loop: a file of
    ``FAST_BYTES`` or more, without step labels, whose first rows the loop reads (a later row it does
    not read sends the rest of its chunk and of the file to ``np.loadtxt``). False for a file the
    reader refuses: it says why when asked for the rows.

    Parameters
    ----------
    path : str or Path
        A capture CSV.

    Returns
    -------
    bool
    """
    path = Path(path)
    if not _compiled(path):
        return False
    try:
        with _open_reader(path) as fh:
            readline = functools.partial(fh.readline, MAX_LINE_CHARS + 1)
            rows, data_at, fields, step_idx = _header(path, readline)
        if step_idx is not None:
            return False
        with contextlib.closing(_compiled_chunks(rows, data_at, fields, _PROBE_ROWS)) as first:
            next(first)
    except StopIteration as end:
        return end.value is None  # the whole file in less than a chunk
    except (InputFileError, UnicodeDecodeError):
        return False
    return True


def _compiled(path: Path) -> bool:
    try:
        return path.stat().st_size >= FAST_BYTES
    except OSError:
        return False  # the text reader says what is wrong with the file


class _Rows:
    """The checks every chunk's values go through, whoever parsed them, and where the file has got to."""

    def __init__(self, path: Path, numeric: dict[str, int], mag: bool, device: dict[str, Any], line_no: int):
        self.path = path
        self.columns = numeric  # name: its field in a line
        self.names = list(numeric)
        self.mag = mag
        self.device = device
        self.line_no = line_no  # the last line read
        self.last_t = -math.inf

    def capture(self, values: np.ndarray, step: np.ndarray | None) -> Capture:
        """The chunk of the lines after ``line_no`` (``values``: a row a line, columns as ``names``),
        checked: required values finite, t increasing from the chunk before."""
        path, first = self.path, self.line_no + 1
        cols = {n: values[:, i] for i, n in enumerate(self.names)}
        for n in REQUIRED:
            bad = np.flatnonzero(~np.isfinite(cols[n]))
            if len(bad):
                raise InputFileError(path, "value is not a finite number", line=first + int(bad[0]), column=n)
        t = cols["t"]
        steps = np.diff(np.concatenate([[self.last_t], t]))
        bad = np.flatnonzero(steps <= 0)
        if len(bad):
            i = int(bad[0])
            raise InputFileError(path, f"t = {float(t[i])!r} does not increase (previous row has "
                                 f"{float(t[i - 1]) if i else self.last_t!r}); rows must be in time order",
                                 line=first + i, column="t")
        self.last_t = float(t[-1])
        self.line_no += len(values)
        return Capture(
            t=t,
            acc=np.column_stack([cols["ax"], cols["ay"], cols["az"]]),
            gyro=np.column_stack([cols["gx"], cols["gy"], cols["gz"]]),
            temp=cols.get("temp"),
            dtemp=cols.get("dtemp"),
            step=step,
            source=str(path),
            mag=np.column_stack([cols[n] for n in MAG_COLUMNS]) if self.mag else None,
            device=dict(self.device),
        )


def _compiled_chunks(rows: _Rows, at: int, fields: int,
                     chunk_rows: int) -> Generator[Capture, None, int | None]:
    """The chunks from byte ``at`` (a line's start) parsed by :func:`_csv_kernel.parse_rows`, ending where
    the text reader's chunks end; returns None at the file's end, or the byte where the chunk the loop
    did not read whole starts (a line it leaves to ``np.loadtxt``, or a last line without its end)."""
    from station.acquisition import _csv_kernel as kernel

    slots = np.full(fields, -1, dtype=np.int64)  # each field's column of the chunk's values; -1 ignored
    for i, name in enumerate(rows.names):
        slots[rows.columns[name]] = i
    opener = gzip.open if rows.path.suffix == ".gz" else open
    with opener(rows.path, "rb") as raw:
        raw.seek(at)
        buf = np.empty(0, dtype=np.uint8)
        pos = 0
        base = at  # the file's byte at buf[0]
        ended = False
        while True:
            start = base + pos
            out = np.empty((min(chunk_rows, _FIRST_ROOM), len(rows.names)))
            row = chars = 0
            while True:
                row, pos, chars, why = kernel.parse_rows(buf, pos, slots, out, row, chars, chunk_rows,
                                                         CHUNK_CHARS, _BATCH, MAX_LINE_CHARS)
                if why == kernel.ROOM:
                    more = np.empty((min(len(out), chunk_rows - len(out)), out.shape[1]))
                    out = np.concatenate([out, more])
                    continue
                if why == kernel.STOP:
                    return start
                if why == kernel.FULL:
                    break
                block = b"" if ended else raw.read(_BLOCK)
                if block:
                    buf = np.concatenate([buf[pos:], np.frombuffer(block, dtype=np.uint8)])
                    base += pos
                    pos = 0
                    continue
                ended = True
                if why == kernel.MORE:
                    return start
                break
            if row == 0:
                return None
            yield rows.capture(out[:row], None)


def _check_length(path: Path, lines: list[str], first_line: int) -> None:
    """Refuse the first of ``lines`` (read with a limit of ``MAX_LINE_CHARS + 1``) that reached the limit."""
    if max(map(len, lines), default=0) > MAX_LINE_CHARS:
        at = next(i for i, line in enumerate(lines) if len(line) > MAX_LINE_CHARS)
        raise InputFileError(path, f"line is longer than {MAX_LINE_CHARS} characters, the most a capture CSV "
                             "row may hold (a sample row is under 200): is this a capture CSV? Cut the file "
                             "at that line, or write it again with one sample per line",
                             line=first_line + at)


def _read_chunk(path: Path, readline: Callable[[], str], rows: int,
                first_line: int) -> tuple[list[str], bool]:
    """Up to ``rows`` lines, fewer once they hold ``CHUNK_CHARS`` characters, each checked for length;
    and whether the file ended."""
    lines: list[str] = []
    chars = 0
    while len(lines) < rows and chars < CHUNK_CHARS:
        want = min(_BATCH, rows - len(lines))
        batch = list(itertools.islice(iter(readline, ""), want))
        _check_length(path, batch, first_line + len(lines))
        lines += batch
        chars += sum(map(len, batch))
        if len(batch) < want:
            return lines, True
    return lines, False


def _cell(line: str, idx: int) -> str:
    cells = line.rstrip("\r\n").split(",")
    return cells[idx].strip() if idx < len(cells) else ""


def read_csv_device(path: str | Path) -> dict[str, Any]:
    """The device info of a capture CSV's metadata lines alone (the rows are not read)."""
    path = Path(path)
    with _open_reader(path) as fh:
        return _read_metadata(path, functools.partial(fh.readline, MAX_LINE_CHARS + 1))[2]


def read_csv(path: str | Path) -> Capture:
    """The whole capture CSV in memory (see :func:`iter_csv_chunks` for bounded memory)."""
    chunks = list(iter_csv_chunks(path))
    if not chunks:
        raise InputFileError(path, "has a header but no sample rows", line=2)

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(c, name) for c in chunks])

    def cat_optional(name: str) -> np.ndarray | None:
        return None if getattr(chunks[0], name) is None else cat(name)

    return Capture(t=cat("t"), acc=cat("acc"), gyro=cat("gyro"), temp=cat_optional("temp"),
                   dtemp=cat_optional("dtemp"), step=cat_optional("step"), source=str(path),
                   mag=cat_optional("mag"), device=chunks[0].device)


class CsvWriter:
    """Appends sample batches to a capture CSV; the caller owns the file handle.

    With ``header``, the ``metadata`` lines (``# key: value``, see :mod:`capture_metadata`) come first.
    """

    def __init__(self, fh: IO[str], with_temp: bool = True, with_dtemp: bool = False,
                 with_step: bool = False, with_mag: bool = False, header: bool = True,
                 metadata: Mapping[str, str] | None = None):
        self.fh = fh
        self.columns = ["t", "ax", "ay", "az", "gx", "gy", "gz"]
        if with_temp:
            self.columns.append("temp")
        if with_dtemp:
            self.columns.append("dtemp")
        if with_mag:
            self.columns.extend(MAG_COLUMNS)
        if with_step:
            self.columns.append("step")
        if header:
            fh.write(capture_metadata.metadata_text(metadata or {}) + ",".join(self.columns) + "\n")

    def write(self, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray, temp: np.ndarray | None = None,
              dtemp: np.ndarray | None = None, step: np.ndarray | list[str] | None = None,
              mag: np.ndarray | None = None) -> None:
        """Append rows: times (s), acc and gyro (N, 3), and the temperature, dT, field (uT, N x 3; NaN
        when None) and step columns it has."""
        numeric = [np.asarray(t, float)[:, None], np.asarray(acc), np.asarray(gyro)]
        if "temp" in self.columns:
            numeric.append(np.full((len(t), 1), np.nan) if temp is None else np.asarray(temp, float)[:, None])
        if "dtemp" in self.columns:
            numeric.append(np.zeros((len(t), 1)) if dtemp is None else np.asarray(dtemp, float)[:, None])
        if "mx" in self.columns:
            numeric.append(np.full((len(t), 3), np.nan) if mag is None else np.asarray(mag, float))
        block = np.hstack([np.asarray(a, dtype=float) for a in numeric])
        buf = io.StringIO()
        # 9 significant digits round-trip float32 sensor values exactly; t keeps microseconds.
        np.savetxt(buf, block, delimiter=",", fmt=["%.6f"] + ["%.9g"] * (block.shape[1] - 1))
        text = buf.getvalue()
        if "step" in self.columns:
            labels = [""] * len(t) if step is None else list(step)
            text = "".join(f"{row},{lab}\n" for row, lab in zip(text.splitlines(), labels, strict=True))
        self.fh.write(text)


def write_csv(path: str | Path, capture: Capture) -> None:
    """Write a whole capture atomically, with the metadata of the unit ``capture.device`` describes."""
    from station.common.files import atomic_open

    with atomic_open(path, "w") as fh:
        w = CsvWriter(fh, with_temp=capture.temp is not None, with_dtemp=capture.dtemp is not None,
                      with_step=capture.step is not None, with_mag=capture.mag is not None,
                      metadata=capture_metadata.csv_metadata(capture.device))
        w.write(capture.t, capture.acc, capture.gyro, capture.temp, capture.dtemp, capture.step, capture.mag)


class CsvCaptureWriter:
    """Streams sample batches (``protocols.base.SAMPLE_DTYPE``) into a capture CSV at ``path``.

    Written in place, not atomically, so a capture cut short keeps everything written so far.
    The metadata lines name the unit ``device`` describes (its DEVICE_INFO) and the ``protocol``.
    The header waits for the first batch: a batch of ``MAG_SAMPLE_DTYPE`` (a unit with a
    magnetometer) adds mx, my, mz; later batches without a field write NaN there. A field that first
    comes after the header (a unit whose first packets carry none) widens the file once: the rows so
    far are rewritten beside it with NaN in mx, my, mz and the copy replaces the file atomically, so a
    failure there (disk full) leaves the old file whole; the capture then goes on without the field
    and :attr:`field_dropped` counts the samples whose field was left out.
    Every batch goes to the OS in whole rows; if a write fails (disk full), the file is cut back
    to the last whole batch so it stays a valid capture CSV, and :class:`OutputFileError` says how
    much was kept. ``t`` is the device clock in seconds (``t_us`` / 1e6, microsecond resolution).
    """

    def __init__(self, path: str | Path, with_step: bool = False, device: Mapping[str, Any] | None = None,
                 protocol: str = ""):
        self.path = Path(path)
        self.rows = 0
        self._text = io.StringIO()
        self._with_step = with_step
        self._metadata = capture_metadata.csv_metadata(device, protocol)
        self._csv: CsvWriter | None = None
        try:
            self._fh = open(self.path, "wb", buffering=0)
        except OSError as exc:
            raise OutputFileError(self.path, f"cannot be created: {exc.strerror}; choose another path"
                                  ) from None
        self._good_size = 0
        self.field_dropped = 0
        self._widen_failed = False

    def _writer(self, with_mag: bool) -> CsvWriter:
        """The row writer, its header written when first asked for; widened for a field that comes late."""
        if self._csv is None:
            self._csv = CsvWriter(self._text, with_temp=True, with_step=self._with_step, with_mag=with_mag,
                                  metadata=self._metadata)
        elif with_mag and "mx" not in self._csv.columns and not self._widen_failed:
            self._widen()
        return self._csv

    def _widen(self) -> None:
        """Rewrite the rows written so far with mx, my, mz (NaN) beside the file, then replace it."""
        assert self._csv is not None
        wider = CsvWriter(self._text, with_temp=True, with_step=self._with_step, with_mag=True, header=False)
        tmp = self.path.with_name(f".{self.path.name}.widen")
        self._fh.close()
        try:
            with open(self.path, encoding="utf-8", newline="") as src, open(tmp, "w", encoding="utf-8",
                                                                             newline="") as dst:
                line = src.readline()
                while line.startswith("#"):  # the metadata lines stay as they are
                    dst.write(line)
                    line = src.readline()
                dst.write(",".join(wider.columns) + "\n")
                for line in src:
                    if self._with_step:
                        numbers, _, label = line.rstrip("\n").rpartition(",")
                        dst.write(f"{numbers},nan,nan,nan,{label}\n")
                    else:
                        dst.write(line.rstrip("\n") + ",nan,nan,nan\n")
                dst.flush()
                os.fsync(dst.fileno())
            os.replace(tmp, self.path)
            self._csv = wider
        except OSError:
            tmp.unlink(missing_ok=True)
            self._widen_failed = True  # the file keeps its columns; write() counts the fields left out
        self._fh = open(self.path, "ab", buffering=0)
        self._good_size = self._fh.tell()

    def write(self, samples: np.ndarray, step: np.ndarray | list[str] | None = None) -> None:
        """Append a batch of ``SAMPLE_DTYPE`` or ``MAG_SAMPLE_DTYPE`` samples (and their step labels)
        and commit them to disk."""
        if len(samples) == 0:
            return
        t = samples["t_us"] * 1e-6
        mag = samples["mag"] if has_mag(samples) else None
        writer = self._writer(mag is not None)
        if mag is not None and "mx" not in writer.columns:
            self.field_dropped += len(samples)
        writer.write(t, samples["acc"], samples["gyro"], samples["temp"], step=step, mag=mag)
        self._commit()
        self.rows += len(samples)

    def _commit(self) -> None:
        data = self._text.getvalue().encode("utf-8")
        self._text.seek(0)
        self._text.truncate()
        view = memoryview(data)
        try:
            while view:
                view = view[self._fh.write(view):]
        except OSError as exc:
            self._fh.truncate(self._good_size)
            self._fh.close()
            raise OutputFileError(self.path, f"writing failed: {exc.strerror}; the file keeps the first "
                                  f"{self.rows} samples and stays a valid capture; free space and capture "
                                  f"again") from None
        self._good_size += len(data)

    def flush(self) -> None:
        """Make what was written durable (the rows already reached the OS with each batch)."""
        if not self._fh.closed:
            self._commit_header()
            os.fsync(self._fh.fileno())

    def close(self, link: dict | None = None) -> None:
        """Close the file; ``link`` (link statistics) has no place in a CSV and is ignored."""
        if not self._fh.closed:
            self._commit_header()
            self._fh.close()

    def _commit_header(self) -> None:
        """A file without rows still gets its header, so it is a valid (empty) capture CSV."""
        if self._csv is None:
            self._writer(False)
            self._commit()
