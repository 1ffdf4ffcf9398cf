"""Frames a board describes in data (``shared/specs/frame-description.md``), decoded in numpy.

A :class:`~protocols.frame_description.FrameDescription` compiles into :class:`FrameDecoder`: the
frame becomes one numpy record type (each field at its offset, in its byte order), so a run of
back-to-back frames in the buffer is viewed as records without copying; the sync and the checksum
of every frame in the run are checked at once, and the values come out of the record columns with
their scale and offset. Python only steps in where the run breaks (garbage, a damaged frame), as in
the native decoder, and follows the native protocol's resync rules: a frame whose checksum fails is
counted (``truncated`` when a sync starts inside it, ``crc_errors`` otherwise), the search resumes
at the next sync candidate after the one it tried, and garbage is counted and skipped, so no good
frame after it is lost.

When most frames fail their checksum (``CHECKSUM_FAILING_MIN`` failures and more than good frames),
the description is wrong rather than the link: :attr:`FrameDecoder.problem` then holds a one-line
diagnosis naming the checksum that fits the frames refused last (``protocols.frame_checksum_fit``),
for a capture to stop on and ``frame check`` to show; decoding goes on as before.

Sequence counters and integer clocks narrower than 64 bits are unwrapped (a step back of up to half
their range is a step back, not a wrap). A board without a clock is timed by ``rate_hz``: by its
counter when it has one, else by the count of samples. Without a counter, the counter is made from
the clock: a step of more than 1.5 sample periods counts the samples missing in it.

A description with all three of ``mx``, ``my``, ``mz`` is a unit with a magnetometer: its samples are
``MAG_SAMPLE_DTYPE``, the field in microtesla as the fields' scales make it. With only some of them
the samples carry no field (they stay in :attr:`FrameDecoder.last_values`).

A frame of several IMUs (fields with ``imu: k``) decodes instance 0 alone, as a frame of one IMU,
until :meth:`FrameDecoder.decode_instances`; then each feed returns an
:class:`~protocols.instances.InstancesDecoded` whose ``instances`` hold the other instances' samples,
with instance 0's ``seq`` and ``t_us`` (one frame, one time) and no field (the board's field goes
with instance 0).

The station reads description files (``station.frames.reader``) and registers its reader here with
:func:`set_description_reader`, so ``make_decoder("frame:board.yaml")`` works wherever a protocol is
named; this layer reads no files itself.

Why this module is long: ``FrameDecoder``'s vectorised run and its resync rules are one
state machine over one buffer, kept beside the record type it views the buffer as; the description
itself and the checksums already have their own modules (``frame_description``, ``frame_checksums``).
"""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import Callable

import numpy as np

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, Decoded, StreamDecoderBase
from protocols.errors import StationError
from protocols.frame_checksum_fit import diagnosis
from protocols.frame_checksums import RowChecksum, checksum_rows
from protocols.frame_description import FieldSpec, FrameDescription
from protocols.instances import InstancesDecoded

# Frames checked per vectorised run. After a damaged frame the next run re-checks at most this many,
# so a stream with errors costs little more than a clean one.
_WINDOW = 1024
# Samples whose clock steps give the period of a board with neither counter nor stated rate.
_PERIOD_SAMPLES = 8
CHECKSUM_FAILING_MIN = 50
"""Checksum failures before most frames failing (more failures than good frames) is a wrong description."""
REFUSED_KEPT = 64
"""Frames refused for their checksum kept (the latest), for the diagnosis to try other checksums on."""

DescriptionReader = Callable[[str], FrameDescription]
_reader: DescriptionReader | None = None


def set_description_reader(reader: DescriptionReader) -> None:
    """Install the function that reads a description file for ``frame:FILE`` (the station's YAML reader).

    Parameters
    ----------
    reader : callable
        ``path -> FrameDescription``; it raises a ``StationError`` naming the file and line.
    """
    global _reader
    _reader = reader


def decoder_from_option(path: str) -> FrameDecoder:
    """The decoder for ``--protocol frame:PATH``: the description file read by the installed reader.

    Parameters
    ----------
    path : str
        The description file.

    Returns
    -------
    FrameDecoder

    Raises
    ------
    StationError
        No path, no reader installed (import ``station.frames.reader``), or the reader's refusal.
    """
    if not path:
        raise StationError("frame needs its description file: --protocol frame:FILE.yaml")
    if _reader is None:
        raise StationError("frame descriptions are read by the station: import station.frames.reader first, "
                           "or build FrameDecoder(describe({...}))")
    return FrameDecoder(_reader(path))


def _field_dtype(spec: FieldSpec) -> np.dtype:
    if spec.size == 3:
        return np.dtype((np.uint8, 3))  # assembled by _raw_values
    return np.dtype(f"{'<' if spec.byte_order == 'little' else '>'}{spec.kind}{spec.size}")


def frame_dtype(desc: FrameDescription) -> np.dtype:
    """The numpy record of one whole frame: ``sync``, ``check`` (when there is a checksum) and each field.

    Parameters
    ----------
    desc : FrameDescription
        The frame.

    Returns
    -------
    numpy.dtype
        A structured type of ``desc.length`` bytes whose fields lie at their offsets.
    """
    names, formats, offsets = [], [], []
    ls = len(desc.sync)
    names.append("sync")
    formats.append(np.dtype(f"<u{ls}") if ls in (1, 2, 4, 8) else np.dtype((np.uint8, ls)))
    offsets.append(0)
    if desc.checksum is not None:
        cs = desc.checksum
        names.append("check")
        formats.append(np.dtype(f"{'<' if cs.byte_order == 'little' else '>'}u{cs.size}"))
        offsets.append(cs.at)
    for spec in desc.fields:
        names.append(f"f_{spec.key}")
        formats.append(_field_dtype(spec))
        offsets.append(spec.at)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": desc.length})


def _raw_values(records: np.ndarray, spec: FieldSpec) -> np.ndarray:
    """A field's raw numbers; 24-bit integers assembled from their bytes and sign-extended."""
    column = records[f"f_{spec.key}"]
    if spec.size != 3:
        return column
    b = column.astype(np.int32)
    lo, hi = (0, 2) if spec.byte_order == "little" else (2, 0)
    value = b[:, lo] | (b[:, 1] << 8) | (b[:, hi] << 16)
    return (value ^ 0x800000) - 0x800000 if spec.kind == "i" else value


class _Extractor:
    """Some fields of a batch of records as one ``(frames, fields)`` float64 matrix, ``raw * scale + offset``.

    Fields of one type and byte order are gathered together: one fancy index over the frame bytes,
    one view as that type and one conversion per type, whatever the number of fields.
    """

    def __init__(self, desc: FrameDescription, specs: list[FieldSpec]):
        self.length = desc.length
        groups: dict[np.dtype, list[int]] = {}
        self.wide: list[tuple[int, FieldSpec]] = []  # 24-bit fields, assembled from their bytes
        for col, spec in enumerate(specs):
            if spec.size == 3:
                self.wide.append((col, spec))
            else:
                groups.setdefault(_field_dtype(spec), []).append(col)
        self.groups = []
        for dtype, cols in groups.items():
            index = np.concatenate([np.arange(specs[c].at, specs[c].at + dtype.itemsize) for c in cols])
            self.groups.append((dtype, index, np.array(cols)))
        self.single = len(self.groups) == 1 and not self.wide
        # The values side by side in the frame, in order: a strided view of the records, no gathering.
        self.strided_at: int | None = None
        if self.single:
            dtype, index, _ = self.groups[0]
            if np.array_equal(index, np.arange(index[0], index[0] + len(index))):
                self.strided_at = int(index[0])
        self.width = len(specs)
        self.scales = np.array([f.scale for f in specs])
        self.offsets = np.array([f.offset for f in specs])
        self.no_offset = bool((self.offsets == 0).all())
        self.identity = self.no_offset and bool((self.scales == 1).all())
        self._scaled = np.empty((0, self.width))
        # Whether a value can overflow float32 (or is a float, which may be inf or NaN): only then are
        # numpy's overflow warnings silenced, which costs a little on every batch.
        self.wild = any(f.kind == "f" or 2.0 ** (8 * f.size) * abs(f.scale) + abs(f.offset) > 1e38
                        for f in specs)

    def __call__(self, records: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        if self.strided_at is not None:
            dtype = self.groups[0][0]
            raw = np.ndarray((len(records), self.width), dtype=dtype, buffer=records, offset=self.strided_at,
                             strides=(self.length, dtype.itemsize))
            if out is None:
                out = np.empty((len(records), self.width))
            with _quiet(self.wild):
                # Scaled and offset in a contiguous float64 work array (a ufunc that casts into a strided
                # float32 ``out`` is buffered, slower than the arithmetic), rounded once into ``out``.
                scaled = np.multiply(raw, self.scales, out=self._scratch(len(records)))
                if self.no_offset:
                    out[...] = scaled
                else:
                    np.add(scaled, self.offsets, out=out)
            return out
        if out is not None:
            with _quiet(self.wild):
                out[...] = self(records)
            return out
        rows = records.view(np.uint8).reshape(len(records), self.length)
        with np.errstate(over="ignore", invalid="ignore"):
            if self.single:
                dtype, index, _ = self.groups[0]
                raw = np.ascontiguousarray(rows[:, index]).view(dtype)
                return raw.astype(np.float64) if self.identity else raw * self.scales + self.offsets
            out = np.empty((len(records), self.width))
            for dtype, index, cols in self.groups:
                out[:, cols] = np.ascontiguousarray(rows[:, index]).view(dtype)
            for col, spec in self.wide:
                out[:, col] = _raw_values(records, spec)
            if not self.identity:
                out *= self.scales
                out += self.offsets
        return out


    def _scratch(self, n: int) -> np.ndarray:
        """A float64 ``(n, width)`` work array, kept between calls (one extractor serves one decoder)."""
        if len(self._scaled) < n:
            self._scaled = np.empty((n, self.width))
        return self._scaled[:n]


def field_values(desc: FrameDescription, records: np.ndarray) -> dict[str, np.ndarray]:
    """Every described field of a batch of frame records, scaled: ``raw * scale + offset`` (float64).

    Parameters
    ----------
    desc : FrameDescription
        The frame.
    records : numpy.ndarray
        Records of :func:`frame_dtype`.

    Returns
    -------
    dict
        Field key (``ax``, ``ax.imu1``: :attr:`~protocols.frame_description.FieldSpec.key`) to values.
    """
    matrix = _Extractor(desc, list(desc.fields))(np.ascontiguousarray(records))
    return {spec.key: matrix[:, i] for i, spec in enumerate(desc.fields)}


def _quiet(needed: bool) -> contextlib.AbstractContextManager:
    """numpy's overflow and invalid-value warnings silenced where values may be wild (not on every batch)."""
    return np.errstate(over="ignore", invalid="ignore") if needed else contextlib.nullcontext()


class _Unwrapper:
    """An integer that wraps at ``2**bits``, made continuous across calls: steps are taken modulo the
    range, and a step of more than half of it counts as a step back."""

    def __init__(self, bits: int):
        self.modulus = 1 << bits
        self.last: int | None = None
        self.total = 0

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        r = raw.astype(np.int64)
        if self.last is None:
            self.last, self.total = int(r[0]), int(r[0])
        half = self.modulus // 2
        first, end = int(r[0]), int(r[-1])
        if 0 <= first - self.last < half and int(np.maximum.reduce(r)) - int(np.minimum.reduce(r)) < half:
            # No wrap in the batch (the usual case): every step is a raw difference, so one shift.
            r += self.total - self.last
            self.last, self.total = end, int(r[-1])
            return r
        steps = np.empty_like(r)
        steps[0] = r[0] - self.last
        np.subtract(r[1:], r[:-1], out=steps[1:])
        steps += half
        steps &= self.modulus - 1
        steps -= half
        np.cumsum(steps, out=steps)
        steps += self.total
        self.last, self.total = int(r[-1]), int(steps[-1])
        return steps


class FrameDecoder(StreamDecoderBase):
    """Incremental decoder of the frames a :class:`FrameDescription` describes (``StreamDecoderBase``).

    Parameters
    ----------
    desc : FrameDescription
        The checked description (``protocols.frame_description.describe``).
    """

    name = "frame"

    def __init__(self, desc: FrameDescription):
        super().__init__()
        self.description = desc
        self.label = f"frame:{desc.name}"  # the spec: the name goes into capture files, not the file's path
        self._dtype = frame_dtype(desc)
        self._sync = desc.sync
        self._len = desc.length
        ls = len(desc.sync)
        self._sync_value = int.from_bytes(desc.sync, "little") if ls in (1, 2, 4, 8) else None
        self._last_records = np.zeros(0, dtype=self._dtype)
        self._checked_at: int | None = None  # where the validity of frames in this feed was computed
        self._checked = np.zeros(0, dtype=bool)
        cs = desc.checksum
        self._check_rows = RowChecksum(cs.type, cs.end - cs.start) if cs is not None else None
        # acc, gyro and temp lie side by side in a sample record: 7 float32 from byte 12.
        imu = [desc.field(n) for n in ("ax", "ay", "az", "gx", "gy", "gz", "temp")]
        self._imu = _Extractor(desc, [f for f in imu if f is not None])
        mag = [f for f in (desc.field(n) for n in ("mx", "my", "mz")) if f is not None]
        self._mag = _Extractor(desc, mag) if len(mag) == 3 else None
        self._out_dtype = SAMPLE_DTYPE if self._mag is None else MAG_SAMPLE_DTYPE
        seq = self._seq_spec = desc.field("seq")
        # A counter of 32 bits or more is read as it is: the sample's seq wraps at 2^32 anyway.
        self._seq = _Unwrapper(8 * seq.size) if seq is not None and seq.size < 4 else None
        t = self._t_spec = desc.field("t")
        self._clock_ticks_us: int | None = None
        if t is not None and t.kind != "f" and t.size < 8 and t.offset == 0:
            ticks = t.scale * 1e6
            if ticks == round(ticks) and 1 <= ticks <= 1e6:
                self._clock_ticks_us = int(round(ticks))
        self._clock = _Unwrapper(8 * t.size) if t is not None and t.kind != "f" and t.size < 8 else None
        self._count = 0  # samples so far
        self._seq0: float | None = None
        self._period_s = 1.0 / desc.rate_hz if desc.rate_hz else None
        self._last_t: float | None = None
        self._synth_seq = -1
        self._refused: deque[bytes] = deque(maxlen=REFUSED_KEPT)
        self.problem: str | None = None  # set once most frames failed their checksum (see the module)
        self._others: dict[int, _Extractor] | None = None  # decode_instances(): instances 1.. by instance
        self.instance = 0  # the IMU instance ``samples`` are of

    # -- several IMUs ----------------------------------------------------------------------------

    def decode_instances(self) -> None:
        """Decode every IMU instance the frame carries (fields with ``imu: k``): from now on ``feed`` and
        ``flush`` return :class:`~protocols.instances.InstancesDecoded` (a frame of one IMU: no others)."""
        desc = self.description
        if self._others is None:
            self._others = {}
            for k in desc.instances[1:]:
                specs = [desc.field(n, k) for n in ("ax", "ay", "az", "gx", "gy", "gz", "temp")]
                self._others[k] = _Extractor(desc, [f for f in specs if f is not None])

    @property
    def instances_seen(self) -> dict[int, int]:
        """The IMU instances the frame carries, with the frames decoded (every frame carries each)."""
        frames = self.stats.frames
        return {k: frames for k in self.description.instances} if frames else {}

    def _instance_batches(self, records: np.ndarray, samples: np.ndarray) -> dict[int, np.ndarray]:
        """Each other instance's samples of ``records``, with instance 0's ``seq`` and ``t_us``."""
        assert self._others is not None
        out = {}
        n = len(records)
        for k, extract in self._others.items():
            batch = np.empty(n, dtype=SAMPLE_DTYPE)
            floats = batch.view(np.uint8).reshape(n, SAMPLE_DTYPE.itemsize)[:, 12:].view(np.float32)
            extract(records, out=floats[:, : extract.width])
            if extract.width == 6:
                floats[:, 6] = np.nan
            batch["seq"] = samples["seq"]
            batch["t_us"] = samples["t_us"]
            out[k] = batch
        return out

    # -- framing -------------------------------------------------------------------------------

    def _validity(self, pos: int) -> np.ndarray:
        """Whether each frame of the lattice from ``pos`` is valid: sync and checksum, up to ``_WINDOW``
        frames; kept for the feed, so after a damaged frame the frames beyond it are not checked again."""
        at = self._checked_at
        if at is not None and pos >= at and (pos - at) % self._len == 0 and (pos - at) // self._len < len(
                self._checked):
            return self._checked[(pos - at) // self._len :]
        buf = self._buf
        count = min((len(buf) - pos) // self._len, _WINDOW)
        records = np.frombuffer(buf, dtype=self._dtype, count=count, offset=pos)
        if self._sync_value is not None:
            ok = records["sync"] == self._sync_value
        else:
            ok = (records["sync"] == np.frombuffer(self._sync, dtype=np.uint8)).all(axis=1)
        cs = self.description.checksum
        if cs is not None:
            rows = np.frombuffer(buf, dtype=np.uint8, count=count * self._len, offset=pos)
            rows = rows.reshape(count, self._len)[:, cs.start : cs.end]
            assert self._check_rows is not None  # made with the checksum
            ok &= self._check_rows(rows) == records["check"]
        self._checked_at, self._checked = pos, ok
        return ok

    def _valid_run(self, pos: int) -> tuple[np.ndarray, int]:
        """Records of the longest run of valid frames at ``pos`` (a copy: the buffer may then shrink)."""
        ok = self._validity(pos)
        n_ok = len(ok) if np.logical_and.reduce(ok) else int(ok.argmin())
        # A copy of the bytes (copying records field by field is slower), so the buffer may then shrink.
        return np.frombuffer(self._buf[pos : pos + n_ok * self._len], dtype=self._dtype), n_ok

    def _partial_sync_start(self, pos: int) -> int:
        """Where a sync cut by the end of the buffer starts (its first bytes are kept), else the end."""
        buf, sync = self._buf, self._sync
        for keep in range(min(len(sync) - 1, len(buf) - pos), 0, -1):
            if buf.endswith(sync[:keep]):
                return len(buf) - keep
        return len(buf)

    def _seek(self, pos: int) -> tuple[int, bool]:
        """The next sync at or after ``pos``, counting the bytes skipped as garbage."""
        start = self._buf.find(self._sync, pos)
        found = start >= 0
        if not found:
            start = self._partial_sync_start(pos)
        if start > pos:
            self.stats.garbage_bytes += start - pos
            self.stats.resyncs += 1
        return start, found

    def _reject(self, pos: int) -> int:
        """Count the damaged frame at ``pos`` and resume at the next sync candidate after it."""
        buf = self._buf
        nxt = buf.find(self._sync, pos + 1)
        if 0 <= nxt < pos + self._len:
            self.stats.truncated += 1  # the next frame started inside this one
        else:
            self.stats.crc_errors += 1
            self._refused.append(bytes(buf[pos : pos + self._len]))
        if nxt < 0:
            nxt = self._partial_sync_start(pos + 1)
        self.stats.resyncs += 1
        self.stats.garbage_bytes += nxt - pos
        return nxt

    def feed(self, data: bytes) -> Decoded:
        """Decode ``data`` after what is buffered (``StreamDecoderBase.feed``)."""
        buf = self._buf
        buf += data
        self._checked_at = None
        runs: list[np.ndarray] = []
        pos = 0
        while True:
            pos, found = self._seek(pos)
            if not found or len(buf) - pos < self._len:
                break
            records, n_ok = self._valid_run(pos)
            if n_ok:
                runs.append(records)
                pos += n_ok * self._len
            else:
                pos = self._reject(pos)
        if pos:
            del buf[:pos]
        if self.problem is None and self.stats.crc_errors >= CHECKSUM_FAILING_MIN:
            self._check_failing(sum(len(r) for r in runs))
        if not runs:
            self._last_records = self._last_records[:0]
            empty = np.zeros(0, self._out_dtype)
            return Decoded(empty) if self._others is None else InstancesDecoded(empty)
        # Joined as bytes: numpy would pack the records' type (dropping the bytes between fields).
        records = runs[0] if len(runs) == 1 else \
            np.concatenate([r.view(np.uint8) for r in runs]).view(self._dtype)
        samples = self._samples(records)
        self.stats.frames += len(samples)
        self.stats.samples += len(samples)
        if self._others is None:
            return Decoded(samples)
        return InstancesDecoded(samples, [], self._instance_batches(records, samples))

    def _check_failing(self, new_frames: int) -> None:
        """Set :attr:`problem` when most frames so far failed their checksum (``new_frames`` are not counted
        yet)."""
        failed = self.stats.crc_errors
        total = failed + self.stats.frames + new_frames
        if failed > total - failed:
            found = diagnosis(self.description, self.refused_frames(), failed, total)
            self.problem = f"{self.label}: {found}"

    def refused_frames(self) -> np.ndarray:
        """The latest frames refused for their checksum (up to ``REFUSED_KEPT``), ``(n, length)`` of uint8."""
        kept = list(self._refused)
        return np.frombuffer(b"".join(kept), dtype=np.uint8).reshape(len(kept), self._len)

    def flush(self) -> Decoded:
        """End of stream: every sync candidate left is a truncated frame, the rest garbage."""
        buf = self._buf
        if buf:
            candidates, at = 0, buf.find(self._sync)
            while at >= 0:
                candidates += 1
                at = buf.find(self._sync, at + 1)
            self.stats.truncated += candidates
            self.stats.garbage_bytes += len(buf)
            buf.clear()
        empty = np.zeros(0, self._out_dtype)
        return Decoded(empty) if self._others is None else InstancesDecoded(empty)

    # -- values --------------------------------------------------------------------------------

    @property
    def last_values(self) -> dict[str, np.ndarray]:
        """Every described field of the frames the last ``feed`` completed, scaled (``mx``.. included)."""
        return field_values(self.description, self._last_records)

    def _samples(self, records: np.ndarray) -> np.ndarray:
        self._last_records = records
        n = len(records)
        out = np.empty(n, dtype=self._out_dtype)
        # acc, gyro, temp (and the field) lie side by side from byte 12: 7 (10) float32.
        floats = out.view(np.uint8).reshape(n, self._out_dtype.itemsize)[:, 12:].view(np.float32)
        self._imu(records, out=floats[:, : self._imu.width])
        if self._imu.width == 6:
            floats[:, 6] = np.nan
        if self._mag is not None:
            self._mag(records, out=floats[:, 7:10])
        seq = self._counter(records)
        out["t_us"] = self._time_us(records, seq)
        if seq is None:
            seq = self._counter_from_clock(out["t_us"])
        out["seq"] = seq & 0xFFFFFFFF
        self._count += n
        return out

    def _counter(self, records: np.ndarray) -> np.ndarray | None:
        """The board's counter, unwrapped, or None when it has none."""
        spec = self._seq_spec
        if spec is None:
            return None
        raw = _raw_values(records, spec)
        if self._seq is not None:
            return self._seq(raw)
        return raw.astype(np.uint64).astype(np.int64)

    def _time_us(self, records: np.ndarray, seq: np.ndarray | None) -> np.ndarray:
        """Microseconds of each sample: the clock (unwrapped), else the counter or the count at the rate."""
        spec = self._t_spec
        with _quiet(spec is not None and (spec.kind == "f" or spec.size == 8)):
            if spec is None:
                rate = self.description.rate_hz or 1.0
                if seq is not None:
                    if self._seq0 is None:
                        self._seq0 = int(seq[0])
                    ticks = (seq - self._seq0).astype(np.float64)
                else:
                    ticks = self._count + np.arange(len(records), dtype=np.float64)
                t_us = np.rint(ticks * (1e6 / rate))
            else:
                raw = _raw_values(records, spec)
                if self._clock is not None:
                    raw = self._clock(raw)
                if self._clock_ticks_us is not None:
                    # Whole microseconds a tick (a clock in us or ms): integers, no rounding.
                    t_us = raw * self._clock_ticks_us if self._clock_ticks_us != 1 else raw
                    return np.maximum(t_us, 0)
                t_us = np.rint(raw * (spec.scale * 1e6) + spec.offset * 1e6)
                if spec.kind == "f" or spec.size == 8:
                    t_us[~np.isfinite(t_us)] = 0.0
                    np.minimum(t_us, 2.0**63, out=t_us)
            return np.maximum(t_us, 0.0, out=t_us)

    def _counter_from_clock(self, t_us: np.ndarray) -> np.ndarray:
        """A counter for a board without one: a clock step of k sample periods (rounded) counts k."""
        t = t_us.astype(np.float64)
        if self._period_s is None:
            steps = np.diff(t)
            steps = steps[steps > 0]
            if len(steps) >= _PERIOD_SAMPLES:
                self._period_s = float(np.median(steps)) / 1e6
        if self._period_s is None:
            inc = np.ones(len(t), dtype=np.int64)
        else:
            dt = np.diff(t, prepend=t[0] if self._last_t is None else self._last_t)
            inc = np.rint(dt / (self._period_s * 1e6)).clip(1, 2**31).astype(np.int64)
        if self._last_t is None:
            inc[0] = 1
        self._last_t = float(t[-1])
        seq = self._synth_seq + np.cumsum(inc)
        self._synth_seq = int(seq[-1])
        return seq


def encode_frames(desc: FrameDescription, values: dict[str, np.ndarray]) -> bytes:
    """Frames of ``desc`` carrying ``values`` (field name to physical values), back to back.

    The inverse of the decoder, for the tests, the examples' recordings and the benchmark:
    ``raw = round((value - offset) / scale)``, wrapped into the field's type; the checksum is computed.

    Parameters
    ----------
    desc : FrameDescription
        The frame.
    values : dict
        One array per described field (by :attr:`~protocols.frame_description.FieldSpec.key`: ``ax``,
        ``ax.imu1``), all of one length (missing fields are 0).

    Returns
    -------
    bytes
        The encoded frames.
    """
    n = len(next(iter(values.values())))
    records = np.zeros(n, dtype=frame_dtype(desc))
    ls = len(desc.sync)
    records["sync"] = int.from_bytes(desc.sync, "little") if ls in (1, 2, 4, 8) else np.frombuffer(desc.sync,
                                                                                                     np.uint8)
    for spec in desc.fields:
        if spec.key not in values:
            continue
        raw = (np.asarray(values[spec.key], dtype=np.float64) - spec.offset) / spec.scale
        column = f"f_{spec.key}"
        if spec.kind == "f":
            records[column] = raw
            continue
        as_int = np.rint(raw).astype(np.int64)
        if spec.size == 3:
            b = np.stack([(as_int >> s) & 0xFF for s in (0, 8, 16)], axis=1).astype(np.uint8)
            records[column] = b if spec.byte_order == "little" else b[:, ::-1]
        else:
            records[column] = as_int.astype(records.dtype[column])  # wraps into the field's range
    rows = records.view(np.uint8).reshape(n, desc.length)
    if desc.checksum is not None:
        cs = desc.checksum
        records["check"] = checksum_rows(cs.type, rows[:, cs.start : cs.end])
    return records.tobytes()
