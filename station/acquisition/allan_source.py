"""A still recording streamed into per-axis cumulative sums on disk, for the Allan deviation.

Any input (capture CSV, station capture file, ROS bag) is read in chunks; the six axes are appended to
float64 files; then each file is turned in place into the demeaned cumulative sum of
``station.engines.allan.deviation`` eq. (1), which the engine reads through ``np.memmap``. Memory stays
bounded by one
input chunk (at most 200,000 rows) plus the engine's cache blocks, whatever the length of the record;
the disk holds 6 x 8 bytes per sample (4.1 GB for 24 h at 1 kHz) in a temporary folder removed afterwards.

The sums are read back through read-only maps whose pages the engine releases as it goes, so the
process's resident memory does not grow with the record either.

Timestamps are checked on the way: duplicates and samples older than the newest one are dropped and
counted, gaps (steps over 1.5 nominal periods) are counted with the samples they miss. Nothing is assumed
silently: the report goes to the user and into the outputs.

Why this module is long: the two passes, the timestamp checks between them, the read-ahead thread and
each input's chunking (CSV halves, capture files read twice, bags, autopilot logs) share one invariant,
the drop masks of pass 1 applied by chunk index in pass 2; apart, each piece would have to re-state it.
"""

from __future__ import annotations

import math
import os
import queue
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from station.errors import EngineInputError, InputFileError

AXES = ("gx", "gy", "gz", "ax", "ay", "az")
GAP_FACTOR = 1.5
MAX_EXAMPLES = 5
PASS2_ROWS = 1 << 20
FIRST_ROWS = 1000
READ_AHEAD = 2  # chunks read ahead of the one being summed or written (16 MB each from a capture file)

Chunk = tuple[np.ndarray, np.ndarray, np.ndarray]  # t (n,), acc (n, 3), gyro (n, 3)


@dataclass
class TimingReport:
    """What the timestamps of a record showed."""

    samples: int = 0  # kept
    rate_hz: float = float("nan")  # nominal, from the median step of the first chunk (or given)
    first_t: float = float("nan")
    last_t: float = float("nan")
    gaps: int = 0
    missing_samples: int = 0
    largest_gap_s: float = 0.0
    duplicates: int = 0
    disordered: int = 0
    gap_examples: list[tuple[float, float]] = field(default_factory=list)  # (t before the gap, length s)

    @property
    def span_s(self) -> float:
        """Time from the first to the last sample, s."""
        return self.last_t - self.first_t

    @property
    def mean_rate_hz(self) -> float:
        """(samples - 1) / span: the rate the timestamps show, Hz (NaN with fewer than two)."""
        return (self.samples - 1) / self.span_s if self.samples > 1 and self.span_s > 0 else float("nan")

    @property
    def missing_fraction(self) -> float:
        """Missing samples over the samples there should have been."""
        total = self.samples + self.missing_samples
        return self.missing_samples / total if total else 0.0

    def problems(self) -> list[str]:
        """One sentence per kind of irregularity found."""
        out = []
        if self.gaps:
            where = ", ".join(f"{dt:.3g} s after t = {t:.6g}" for t, dt in self.gap_examples)
            out.append(f"{self.gaps} gap(s) missing {self.missing_samples} samples "
                       f"({self.missing_fraction:.3%}), largest {self.largest_gap_s:.3g} s: {where}")
        if self.duplicates:
            out.append(f"{self.duplicates} sample(s) with a repeated timestamp dropped")
        if self.disordered:
            out.append(f"{self.disordered} sample(s) older than the sample before them dropped")
        if self.samples > 1 and abs(self.mean_rate_hz / self.rate_hz - 1.0) > 0.01 and not self.gaps:
            out.append(f"mean rate {self.mean_rate_hz:.6g} Hz differs from the nominal {self.rate_hz:.6g} Hz "
                       f"by more than 1 %")
        return out

    def as_dict(self) -> dict[str, Any]:
        """Plain-data form of the report, for ``--json`` and the results file."""
        return {"samples": self.samples, "rate_hz": self.rate_hz, "mean_rate_hz": self.mean_rate_hz,
                "first_t": self.first_t, "last_t": self.last_t, "gaps": self.gaps,
                "missing_samples": self.missing_samples, "missing_fraction": self.missing_fraction,
                "largest_gap_s": self.largest_gap_s, "duplicates": self.duplicates,
                "disordered": self.disordered,
                "gap_examples": [{"t": t, "length_s": dt} for t, dt in self.gap_examples]}


class TimingChecker:
    """Checks timestamps chunk by chunk; returns the mask of samples to keep."""

    def __init__(self, rate_hz: float | None = None):
        self.report = TimingReport(rate_hz=float(rate_hz) if rate_hz else float("nan"))
        self._last = -math.inf

    def check(self, t: np.ndarray) -> np.ndarray:
        """Account one chunk of timestamps ``t`` (s) in the report: rate, duplicates, gaps.

        Returns
        -------
        ndarray of bool
            Which samples to keep (those later than every earlier timestamp).

        Raises
        ------
        EngineInputError
            The rate is neither given nor readable from the first timestamps.
        """
        r = self.report
        if not math.isfinite(r.rate_hz):
            steps = np.diff(t)
            steps = steps[steps > 0]
            if len(steps) == 0:
                raise EngineInputError("cannot tell the sample rate from the first timestamps; give --rate")
            # 6 significant digits: timestamps printed to microseconds would otherwise give 200.0000000002 Hz
            r.rate_hz = float(f"{1.0 / np.median(steps):.6g}")
        if len(t) and t[0] > self._last and (len(t) < 2 or np.min(np.diff(t)) > 0):
            # the usual chunk: every stamp later than the one before, nothing dropped
            keep = np.ones(len(t), dtype=bool)
            kept = t
        else:
            newest = np.maximum.accumulate(np.concatenate([[self._last], t]))[:-1]
            keep = t > newest
            r.duplicates += int(np.count_nonzero(t == newest))
            r.disordered += int(np.count_nonzero(t < newest))
            kept = t[keep]
        if len(kept) == 0:
            return keep
        dt = np.diff(np.concatenate([[self._last], kept]))
        if not math.isfinite(self._last):
            dt = dt[1:]
            base = kept[:-1]
            r.first_t = float(kept[0])
        else:
            base = np.concatenate([[self._last], kept[:-1]])
        period = 1.0 / r.rate_hz
        big = np.flatnonzero(dt > GAP_FACTOR * period)
        if len(big):
            r.gaps += len(big)
            r.missing_samples += int(np.sum(np.rint(dt[big] / period) - 1))
            r.largest_gap_s = max(r.largest_gap_s, float(dt[big].max()))
            for i in big[:MAX_EXAMPLES - len(r.gap_examples)]:
                r.gap_examples.append((float(base[i]), float(dt[i])))
        r.samples += len(kept)
        r.last_t = float(kept[-1])
        self._last = float(kept[-1])
        return keep


@dataclass
class IntegratedRecord:
    """Per-axis demeaned cumulative sums on disk (``phase`` rows are memmaps), with what was learnt."""

    phase: list[np.ndarray]
    rate_hz: float
    timing: TimingReport
    means: np.ndarray
    source: str
    device: dict[str, Any]
    _tmp: tempfile.TemporaryDirectory | None = None

    @property
    def n_samples(self) -> int:
        """Number of rate samples integrated (one less than the phase points)."""
        return len(self.phase[0]) - 1

    def close(self) -> None:
        """Drop the phase arrays and remove the temporary files behind them."""
        self.phase = []
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> IntegratedRecord:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def integrate_stream(chunks: Iterable[Chunk], source: str, rate_hz: float | None = None,
                     workdir: str | Path | None = None, device: dict[str, Any] | None = None,
                     on_rows: Callable[[int], None] | None = None) -> IntegratedRecord:
    """Stream (t, acc, gyro) chunks into cumulative sums on disk (two passes, bounded memory).

    Pass 1 checks the timestamps and sums each axis; pass 2 writes ``cumsum(y - mean) / rate`` chunk by
    chunk, carrying the running sum across chunks, which is exactly the sequential float64 sum of the whole
    record. An input that can be read twice (``chunks`` an iterable that is not its own iterator, such as a
    capture file's :class:`H5Chunks`) is read twice and the sums written once; a one-shot stream is
    appended to the files as float64 in pass 1 and replaced in place in pass 2 (the record is written
    twice and read once more: on a day-long record that I/O costs more than reading the input again).

    Parameters
    ----------
    chunks : iterable of (t, acc, gyro)
        Batches in time order.
    source : str
        Name of the input, for messages.
    rate_hz : float, optional
        Sample rate; default from the first timestamps.
    workdir : str or Path, optional
        Folder for the phase files; default a temporary one.
    device : dict, optional
        The unit's info.
    on_rows : callable, optional
        Called with the rows read so far.

    Returns
    -------
    IntegratedRecord

    Raises
    ------
    EngineInputError
        Non-finite samples, or too few to compute an Allan deviation.
    """
    tmp = tempfile.TemporaryDirectory(prefix="imu-allan-", dir=workdir)
    try:
        paths = [Path(tmp.name) / f"{axis}.f64" for axis in AXES]
        checker = TimingChecker(rate_hz)
        sums = np.zeros(len(AXES))
        twice = iter(chunks) is not chunks
        dropped: dict[int, np.ndarray] = {}  # keep masks of the chunks that lose samples (read twice)
        with ExitStack() as stack:
            files = [stack.enter_context(open(p, "wb")) for p in paths]
            for f in files:
                f.write(np.zeros(1).tobytes())
            for index, (t, acc, gyro) in enumerate(_merge_first(_read_ahead(chunks))):
                keep, columns, chunk_sums = _checked(t, acc, gyro, checker, source)
                if keep is not None:
                    dropped[index] = keep
                sums += chunk_sums
                if not twice:
                    for f, y in zip(files, columns, strict=True):
                        f.write(np.ascontiguousarray(y, dtype=np.float64).data)
                if on_rows is not None:
                    on_rows(len(t))
            report = checker.report
            if report.samples < 2:
                raise EngineInputError(f"{source}: {report.samples} usable samples; an Allan deviation needs "
                                       "a long still recording")
            means = sums / report.samples
            if twice:
                for f in files:
                    f.flush()
                    # the whole length at once: ext4 allocates it in one go rather than page by page
                    os.posix_fallocate(f.fileno(), 0, (report.samples + 1) * 8)
                _write_sums(chunks, dropped, means, 1.0 / report.rate_hz, files)
        if not twice:
            for j, p in enumerate(paths):
                _sums_in_place(p, report.samples, means[j], 1.0 / report.rate_hz)
        return IntegratedRecord([_map(p) for p in paths], report.rate_hz, report, means, source, device or {},
                                tmp)
    except BaseException:
        tmp.cleanup()
        raise


def _checked(t: np.ndarray, acc: np.ndarray, gyro: np.ndarray, checker: TimingChecker,
             source: str) -> tuple[np.ndarray | None, list[np.ndarray], np.ndarray]:
    """One chunk's timestamps checked: the keep mask (None when every sample is kept), the kept
    columns gx..az (views where no sample is dropped) and their float64 sums."""
    keep = checker.check(np.asarray(t, dtype=np.float64))
    whole = bool(keep.all())
    columns = _columns(acc, gyro)
    if not whole:
        columns = [c[keep] for c in columns]
    sums = np.array([np.sum(c, dtype=np.float64) for c in columns])
    # a NaN or an infinity makes its column's sum non-finite: only then look for it, sample by sample
    if not np.isfinite(sums).all() and not all(np.isfinite(c).all() for c in columns):
        block = np.column_stack(columns)
        i, j = (int(v) for v in np.argwhere(~np.isfinite(block))[0])
        t_kept = np.asarray(t, dtype=np.float64)[keep]
        raise EngineInputError(f"{source}: the sample at t = {t_kept[i]:.6f} s has a non-finite {AXES[j]} "
                               f"({block[i, j]}); cut the record before it or repair")
    return (None if whole else keep), columns, sums


def _columns(acc: np.ndarray, gyro: np.ndarray) -> list[np.ndarray]:
    """gx..az as views of the chunk, in its own float type (a capture file's float32 is widened where the
    sums are formed, not copied first)."""
    arrays = [np.asarray(a) for a in (gyro, acc)]
    return [a[:, j] for a in arrays for j in range(3)]


def _write_sums(chunks: Iterable[Chunk], dropped: dict[int, np.ndarray], means: np.ndarray, tau0: float,
                files: list) -> None:
    """Pass 2 of a record read twice: each axis's ``cumsum(y - mean) tau0`` appended to its file (the
    timestamps were checked in pass 1: a capture file's are not read again)."""
    carry = np.zeros(len(means))
    buf = np.empty(0)
    # the same chunks as pass 1 (the drop masks go by index); a capture file's without its timestamps
    source = H5Chunks(chunks.path, chunks.rows, times=False) if isinstance(chunks, H5Chunks) else chunks
    for index, (_, acc, gyro) in enumerate(_merge_first(_read_ahead(source))):
        keep = dropped.get(index)
        for j, y in enumerate(_columns(acc, gyro)):
            if keep is not None:
                y = y[keep]
            if len(buf) < len(y) + 1:
                buf = np.empty(len(y) + 1)
            part = buf[:len(y) + 1]
            part[0] = carry[j]
            np.subtract(y, means[j], out=part[1:], dtype=np.float64)
            np.cumsum(part, out=part)
            carry[j] = part[-1]
            part *= tau0
            files[j].write(part[1:].data)


def _sums_in_place(path: Path, samples: int, mean: float, tau0: float) -> None:
    """Pass 2 of a one-shot stream: the file's values replaced by ``cumsum(y - mean) tau0``, a piece at a
    time (plain reads and writes, not a writable map: dirty mapped pages would count against the process
    for the whole file)."""
    buf = np.empty(PASS2_ROWS + 1)
    with open(path, "r+b") as f:
        carry = 0.0
        for a in range(samples // PASS2_ROWS + 1):
            f.seek((1 + a * PASS2_ROWS) * 8)
            raw = np.fromfile(f, dtype=np.float64, count=PASS2_ROWS)
            if len(raw) == 0:
                break
            part = buf[:len(raw) + 1]
            part[0] = carry
            np.subtract(raw, mean, out=part[1:])
            np.cumsum(part, out=part)
            carry = float(part[-1])
            f.seek((1 + a * PASS2_ROWS) * 8)
            f.write((part[1:] * tau0).tobytes())


def _map(path: Path) -> np.ndarray:
    """A read-only view of a file of float64 whose map the engine can release page by page."""
    return np.memmap(path, dtype=np.float64, mode="r")


def _read_ahead(chunks: Iterable[Chunk], depth: int = READ_AHEAD) -> Iterator[Chunk]:
    """The chunks, read by a thread of their own at most ``depth`` ahead: reading the input (HDF5, a CSV
    parser) overlaps the checks, sums, cumulative sums and file writes of the chunk before, which release
    the GIL (numpy's loops, ``write``), so the two passes use both cores. An error reading is raised here,
    in the caller's thread; leaving early stops the reader at its next chunk."""
    items: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def put(item: object) -> bool:
        while not stop.is_set():
            try:
                items.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def read() -> None:
        try:
            for chunk in chunks:
                if not put(chunk):
                    return
        except BaseException as exc:  # handed to the caller's thread, which raises it
            put(exc)
            return
        put(end)

    reader = threading.Thread(target=read, name="allan-read-ahead", daemon=True)
    reader.start()
    try:
        while True:
            item = items.get()
            if item is end:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        reader.join()


def _merge_first(chunks: Iterable[Chunk], rows: int = FIRST_ROWS) -> Iterator[Chunk]:
    """The chunks, the first merged until they hold ``rows`` samples (the nominal rate comes from them)."""
    head: list[Chunk] = []
    it = iter(chunks)
    for chunk in it:
        head.append(chunk)
        if sum(len(c[1]) for c in head) >= rows:  # rows of acc: pass 2 of a capture file has no times
            break
    if head:
        yield (np.concatenate([c[0] for c in head]), np.concatenate([c[1] for c in head]),
               np.concatenate([c[2] for c in head]))
    yield from it


class LogChunks(list):
    """An autopilot log's IMU as one chunk (a log is read whole), with the notes of its conversion."""

    notes: list[str]


def capture_chunks(path: str | Path, topic: str | None = None,
                   instance: int | None = None) -> tuple[Iterable[Chunk], dict[str, Any], int]:
    """Chunks of a capture CSV, station capture file, ROS bag or autopilot log; the unit's info; the size
    in bytes.

    Parameters
    ----------
    path : str or Path
    topic : str, optional
        The IMU topic of a bag.
    instance : int, optional
        The IMU of a PX4 or ArduPilot log (:class:`LogChunks`, whose ``notes`` say what was converted).

    Returns
    -------
    tuple
        The chunks (a capture file's can be read twice, see :class:`H5Chunks`), the unit's info, the size
        in bytes.

    Raises
    ------
    InputFileError
        A file that does not exist or cannot be read.
    """
    from station.acquisition import rosbag_reader

    path = Path(path)
    if not path.exists():
        raise InputFileError(path, "does not exist; give a capture CSV, a capture file (.h5), a ROS bag or a "
                             "PX4/ArduPilot log")
    if path.is_dir():
        size = sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    else:
        size = path.stat().st_size
    if rosbag_reader.is_rosbag(path):
        return rosbag_reader.iter_imu_chunks(path, topic), {}, size
    from station.acquisition import autopilot_log

    if autopilot_log.is_autopilot_log(path):
        capture = autopilot_log.read_log_capture(path, instance)
        chunks = LogChunks([(capture.t, capture.acc, capture.gyro)])
        chunks.notes = autopilot_log.log_notes(capture)
        return chunks, capture.device, size
    name = path.name.lower()
    if name.endswith((".h5", ".hdf5")):
        return H5Chunks(path), _h5_device(path), size
    from station.acquisition import csv_halves
    from station.acquisition.capture_csv import read_csv_device

    return csv_halves.iter_chunks(path), read_csv_device(path), size


def _h5_file(path: Path):
    import h5py

    from station.acquisition.capture_h5 import SCHEMA

    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(path, f"is not a readable HDF5 file ({exc})") from None
    schema = f.attrs.get("schema")
    schema = schema.decode("utf-8", "replace") if isinstance(schema, bytes) else schema
    missing = [n for n in ("t_us", "acc", "gyro") if n not in f]
    if schema != SCHEMA or missing:
        f.close()
        raise InputFileError(path, f"is not a station capture file of schema {SCHEMA!r} (schema {schema!r}, "
                             f"missing {missing})", column="schema")
    return f


def _h5_device(path: Path) -> dict[str, Any]:
    import json

    with _h5_file(path) as f:
        return json.loads(f.attrs.get("device", "{}"))


class H5Chunks:
    """Slices of a station capture file, ``rows`` at a time: memory bounded whatever the file's length.
    Each ``iter()`` reads the file afresh, so :func:`integrate_stream` reads it twice rather than writing
    the record to disk twice. Samples stay in the file's float32; times are seconds (``times=False``:
    empty, the timestamps not read, for a pass that has checked them already)."""

    def __init__(self, path: Path, rows: int = 1 << 19, times: bool = True):
        self.path = path
        self.rows = rows
        self.times = times

    def __iter__(self) -> Iterator[Chunk]:
        with _h5_file(self.path) as f:
            t_us, acc, gyro = f["t_us"], f["acc"], f["gyro"]
            no_times = np.empty(0)
            for a in range(0, len(acc), self.rows):
                b = a + self.rows
                t = t_us[a:b].astype(np.float64) * 1e-6 if self.times else no_times
                yield t, acc[a:b], gyro[a:b]
