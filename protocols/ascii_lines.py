"""Text protocols, one sample a line: configurable CSV, PJRC MotionCal ``Raw:``/``Uni:`` and
VectorNav ``$VNYMR``/``$VNIMU`` sentences.

Lines end in ``\\n``, ``\\r`` or both. Each line is recognised by its start:

- ``Raw:ax,ay,az,gx,gy,gz,mx,my,mz`` (integers; the scales MotionCal assumes): accelerometer
  8192 counts per g (g = 9.80665 m/s^2), gyroscope 16 counts per deg/s, magnetometer 10 counts
  per uT;
- ``Uni:`` with the same nine fields as decimals in m/s^2, rad/s and uT (Adafruit's sketches);
- ``$VNYMR,yaw,pitch,roll,mx,my,mz,ax,ay,az,gx,gy,gz*CS`` (gauss, m/s^2, rad/s) and
  ``$VNIMU,mx,my,mz,ax,ay,az,gx,gy,gz,temp,pressure*CS`` (temp degC), where CS is the XOR of
  the bytes between ``$`` and ``*`` as two hex digits, or their CRC-16 (XMODEM) as four;
  a counter or status the device appends (``,T...``, ``,S...``) is ignored;
- any other line is CSV in the configured columns (``parse_columns``); columns ``mx,my,mz`` (all
  three or none, in uT, mG or G) carry a magnetometer (a ``nan`` field is a sample without one).

The batches are ``MAG_SAMPLE_DTYPE`` once the stream has carried a field (mx, my, mz columns, or a
MotionCal or VectorNav line, whose nine fields always hold one), the field in uT; a CSV line of the
same stream without one has a NaN field.

These formats carry no sample counter and, except CSV with a time column, no device clock:
``seq`` counts the samples and ``t_us`` is ``seq / rate_hz`` at the nominal rate given.
A VectorNav sentence with bytes glued before it (a cut line, noise) is read from its ``$``, a
MotionCal line from its tag when a whole sample follows it.
A line longer than ``max_line`` bytes is dropped (``length_errors``); a line whose numbers are
malformed or implausible (beyond ``max_acc``, ``max_gyro``, ``temp_range``, or not finite) is a
``bad_payloads`` error; a sentence with a wrong checksum is a ``crc_errors`` error. Lines of
text that hold no numbers (banners, headers) and tagged lines of other kinds (``Cal1:...``) are
returned as messages.

Why this module is long: every text dialect (CSV columns, MotionCal, VectorNav) goes
through one line splitter and one rejection count in ``AsciiDecoder``, read two ways that must agree
line for line: one line at a time (``_line``) and in batches (``_batched``: each dialect's well-formed
lines as one table checked in arrays, for speed, issue 30); and their encoders sit beside the parser they
must round-trip with; the fuzz table tests them as pairs.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from protocols._fixed_lines import FixedForm, fixed_form, read_fixed
from protocols._text_table import form_mask, number_table, simple_table
from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, Decoded, Message, StreamDecoderBase, has_mag
from protocols.crc import crc16_ccitt_false
from protocols.mag_batches import join_batches, rows_to_batch, with_mag
from protocols.units import STANDARD_GRAVITY

MAX_LINE_RATE_HZ = 65535.0  # as SET_RATE's 16 bits; no text link carries more lines a second
MOTIONCAL_ACC_PER_G = 8192.0
MOTIONCAL_GYRO_PER_DPS = 16.0
MOTIONCAL_MAG_PER_UT = 10.0
UT_PER_GAUSS = 100.0  # VectorNav's magnetometer unit

# Message ids of the lines returned as messages (Message.msg_id), by kind of line.
MSG_TEXT = 0
MSG_VECTORNAV = 1
MSG_MOTIONCAL = 2

UNITS = {
    "t": {"s": 1.0, "ms": 1e-3, "us": 1e-6},
    "acc": {"m/s^2": 1.0, "mps2": 1.0, "g": STANDARD_GRAVITY, "mg": STANDARD_GRAVITY * 1e-3},
    "gyro": {"rad/s": 1.0, "rads": 1.0, "dps": math.pi / 180.0, "deg/s": math.pi / 180.0, "mrad/s": 1e-3},
    "temp": {"degc": 1.0, "c": 1.0, "cdegc": 0.01},
    "mag": {"ut": 1.0, "nt": 1e-3, "mg": 0.1, "mgauss": 0.1, "g": 100.0, "gauss": 100.0},
    "seq": {"": 1.0},
}
FIELDS = {"t": "t", "seq": "seq", "ax": "acc", "ay": "acc", "az": "acc", "gx": "gyro", "gy": "gyro",
          "gz": "gyro", "temp": "temp", "mx": "mag", "my": "mag", "mz": "mag"}
MAG_NAMES = ("mx", "my", "mz")
_NAN3 = (math.nan, math.nan, math.nan)
SKIP = "_"
DEFAULT_COLUMNS = "t,ax,ay,az,gx,gy,gz,temp"


@dataclass(frozen=True)
class CsvColumns:
    """Names of the CSV fields (``_`` for an ignored one) and the factor to SI of each."""

    names: tuple[str, ...]
    scales: tuple[float, ...]
    delimiter: str = ","

    @property
    def has_mag(self) -> bool:
        """True when the columns carry a magnetometer (mx, my, mz)."""
        return "mx" in self.names

    def describe(self) -> str:
        """The columns as one line, each field's factor to SI after ``*`` where it is not 1."""
        return self.delimiter.join(n if s == 1.0 else f"{n}*{s:g}" for n, s in zip(self.names, self.scales,
                                                                                      strict=True))


def parse_columns(spec: str, delimiter: str = ",") -> CsvColumns:
    """Read a column spec: comma-separated ``name[:unit]``, ``_`` for a field to ignore.

    Names: t, seq, ax, ay, az, gx, gy, gz, temp, and mx, my, mz (all three or none). Units: t in s,
    ms, us; accelerations in m/s^2 (or mps2), g, mg; rates in rad/s (or rads), dps (or deg/s),
    mrad/s; temp in degC, cdegC; the magnetic field in uT (the default), nT, mG (or mgauss), G (or
    gauss); or a number, the factor to SI (to uT for the field). Example:
    ``t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps,mx:mG,my:mG,mz:mG``.
    Raises ``ValueError`` naming the item it cannot read.
    """
    names, scales = [], []
    for item in spec.split(","):
        name, _, unit = item.strip().partition(":")
        name, unit = name.strip().lower(), unit.strip()
        if name == SKIP:
            names.append(SKIP)
            scales.append(1.0)
            continue
        if name not in FIELDS:
            raise ValueError(f"unknown column {name!r} in {spec!r}; known: {', '.join(FIELDS)} and _ to skip")
        if name in names:
            raise ValueError(f"column {name!r} appears twice in {spec!r}")
        table = UNITS[FIELDS[name]]
        if not unit:
            scale = 1.0
        elif unit.lower() in table:
            scale = table[unit.lower()]
        else:
            try:
                scale = float(unit)
            except ValueError:
                raise ValueError(f"unknown unit {unit!r} for column {name!r}; use one of "
                                 f"{', '.join(u for u in table if u)} or a number") from None
        names.append(name)
        scales.append(scale)
    missing = [n for n in ("ax", "ay", "az", "gx", "gy", "gz") if n not in names]
    if missing:
        raise ValueError(f"column spec {spec!r} lacks {', '.join(missing)}")
    mag = [n for n in MAG_NAMES if n in names]
    if mag and len(mag) < len(MAG_NAMES):
        raise ValueError(f"column spec {spec!r} has {', '.join(mag)} but not "
                         f"{', '.join(n for n in MAG_NAMES if n not in names)}: the field needs all three")
    return CsvColumns(tuple(names), tuple(scales), delimiter)


def nmea_xor(body: bytes) -> int:
    """XOR of the bytes between ``$`` and ``*`` (the VectorNav 8-bit checksum)."""
    value = 0
    for b in body:
        value ^= b
    return value


def vectornav_sentence(body: str, crc16: bool = False) -> bytes:
    """``$`` + body + ``*`` + checksum + CRLF."""
    raw = body.encode("ascii")
    cs = f"{crc16_ccitt_false(raw, 0):04X}" if crc16 else f"{nmea_xor(raw):02X}"
    return b"$" + raw + b"*" + cs.encode("ascii") + b"\r\n"


class _Reject(ValueError):
    """A line that cannot be a sample; ``kind`` names the counter it lands in."""

    def __init__(self, kind: str):
        super().__init__(kind)
        self.kind = kind


class _Options(TypedDict, total=False):
    """The :class:`AsciiDecoder` arguments :meth:`AsciiDecoder.from_option` may set."""

    columns: str
    rate_hz: float


# Limits of what a line's numbers may hold (NaN fails the comparisons too): times and counters
# must fit the sample record's 64-bit fields (t_us = t * 1e6), and MotionCal's raw counts a
# 32-bit integer, so that an over-long number is a bad payload rather than an overflow.
_MAX_T_S = 2.0**63 / 1e6
_MAX_SEQ = 2.0**63
_MAX_COUNTS = 2**31
_BELOW_MAX_T_S = float(np.nextafter(_MAX_T_S, 0.0))  # x < _MAX_T_S as x <= this
_BELOW_MAX_SEQ = float(np.nextafter(_MAX_SEQ, 0.0))
_LINE_END = re.compile(rb"[\r\n]")
# "Cal1:...", "Info: ...": a tagged line of another kind, text for us (Raw: and Uni: are read before).
_TAGGED = re.compile(r"[A-Za-z][A-Za-z0-9 _-]*:")


class AsciiDecoder(StreamDecoderBase):
    """Incremental decoder of text lines (see the module docstring for the formats).

    ``kinds_seen`` counts the lines by kind (``csv``, ``motioncal``, ``vectornav``, ``text``).
    """

    name = "ascii"

    def __init__(
        self,
        columns: str | CsvColumns = DEFAULT_COLUMNS,
        rate_hz: float = 100.0,
        max_line: int = 512,
        max_acc: float = 40 * STANDARD_GRAVITY,
        max_gyro: float = 40.0,
        temp_range: tuple[float, float] = (-60.0, 150.0),
        max_mag: float = 5000.0,
    ) -> None:
        super().__init__()
        self.max_mag = max_mag  # uT: beyond any magnetometer's range
        self.columns = parse_columns(columns) if isinstance(columns, str) else columns
        self.rate_hz = rate_hz
        self.max_line = max_line
        self.max_acc = max_acc
        self.max_gyro = max_gyro
        self.temp_range = temp_range
        self.kinds_seen: dict[str, int] = {}
        self.clock_lines = 0  # sample lines that carried their own time
        self._count = 0
        self._first_line = True  # the stream may start in the middle of a line
        self._discarding = False  # inside an over-long line, until its end
        self._field = self.columns.has_mag  # the stream has carried a magnetic field
        self._fixed_form: tuple[int, FixedForm] | None = None  # the layout of lines of one width, by kind
        self._scanned: tuple[bytes, bytes, bytes] | None = None  # _uniform's text, body, other bytes

    @classmethod
    def from_option(cls, option: str) -> AsciiDecoder:
        """A decoder from ``COLUMNS[@RATE_HZ]`` (either part may be empty): ``t:ms,ax:g,...``,
        ``@50`` (default columns, lines without a clock at 50 Hz), ``ax,ay,az,gx,gy,gz@200``."""
        columns, has_rate, rate = option.rpartition("@") if "@" in option else (option, "", "")
        kwargs: _Options = {}
        if columns:
            kwargs["columns"] = columns
        if has_rate:
            try:
                rate_hz = float(rate)
            except ValueError:
                raise ValueError(f"rate {rate!r} after '@' in {option!r} is not a number of Hz") from None
            if not 0 < rate_hz <= MAX_LINE_RATE_HZ:
                raise ValueError(f"rate {rate!r} after '@' in {option!r} must be positive, at most "
                                 f"{MAX_LINE_RATE_HZ:g} Hz")
            kwargs["rate_hz"] = rate_hz
        return cls(**kwargs)

    def feed(self, data: bytes) -> Decoded:
        """Decode ``data`` after what is buffered: one sample per complete line
        (``StreamDecoderBase.feed``)."""
        buf = self._buf
        buf += data
        rows: list[tuple] = []
        messages: list[Message] = []
        pos = 0
        pos, pieces, clean = self._batched(rows, messages)
        if clean and len(buf) == pos:
            del buf[:pos]
            self.stats.samples += len(pieces[0])
            return Decoded(pieces[0], messages)
        while True:
            m = _LINE_END.search(buf, pos)
            if m is None:
                if len(buf) - pos > self.max_line:
                    self._too_long(len(buf) - pos)
                    self._discarding = True
                    pos = len(buf)
                break
            line = bytes(buf[pos : m.start()])
            pos = m.end()
            if self._discarding:
                self.stats.garbage_bytes += len(line)
                self._discarding = False
                self._first_line = False
                continue
            if len(line) > self.max_line:
                self._too_long(len(line))
                self._first_line = False
                continue
            if line:
                self._line(line, rows, messages)
        if pos:
            del buf[:pos]
        samples = rows_to_batch(rows, self._field)
        if pieces:
            samples = join_batches([*pieces, samples])
            if self._field and not clean:  # as if every line had gone one by one
                samples = with_mag(samples)
        self.stats.samples += len(samples)
        return Decoded(samples, messages)

    def _batched(self, rows: list[tuple], messages: list[Message]) -> tuple[int, list[np.ndarray], bool]:
        """The complete lines in the buffer, the well-formed sample lines of every dialect in batches.

        A line that is a sample as it stands (CSV in the columns, ``Raw:``, ``Uni:``, ``$VNYMR`` or
        ``$VNIMU`` with its field count, only the characters of numbers, a two-digit checksum that
        matches) is parsed with the others of its dialect in one ``np.loadtxt`` and checked in arrays;
        every other line (and one the batch refuses) goes :meth:`_line` one by one, in order, so the
        counters, messages and sample numbers are those of reading every line alone. Returns the bytes
        used, the batches (the rows of the lines read one by one appended to ``rows``: their batch is
        the last, made by the caller), and whether every line was a CSV sample (then the one batch has
        the columns' dtype, as it always had).
        """
        buf = self._buf
        end = max(buf.rfind(b"\n"), buf.rfind(b"\r")) + 1
        if end == 0 or self._first_line or self._discarding:
            return 0, [], False
        raw = bytes(buf[:end])
        fixed = self._read_fixed(raw)
        if fixed is not None:  # lines of one width, read as a byte matrix: the lines only for damaged ones
            first, got = fixed
            n = len(got.good)
            kind = np.full(n, first, dtype=np.int8)
            lines = [] if _ALL(got.good) else [ln for ln in raw.replace(b"\r", b"\n").split(b"\n") if ln]
            return (end, *self._assemble(first, True, kind, got, lines, rows, messages))
        text = raw.replace(b"\r", b"\n")
        lines = [line for line in text.split(b"\n") if line]
        if not lines:
            return end, [], False
        n = len(lines)
        match = _line_forms(self.columns.delimiter, len(self.columns.names)).fullmatch
        long = max(map(len, lines)) > self.max_line
        first = 0 if long or (m := match(lines[0])) is None else m.lastindex or 0
        if not first and not long and (m := match(lines[-1])) is not None:
            first = m.lastindex or 0  # the first line damaged: the last one names the dialect
        if first and self._uniform(first, text, lines):
            kinds = [first] * n
        elif first and not long and (few := self._few_bad(first, text, lines, match)) is not None:
            kinds = few
            first = kinds[0]
        elif first and not long and self._fast_forms:
            # The lines of the dialect found in arrays; the others (damage, other dialects) by the regex.
            head, chars, delim, fields, checksum = self._form(first)
            of_form = form_mask(lines, head, chars, delim, fields, checksum).tolist()
            kinds = [first if ok else (m.lastindex or 0 if (m := match(line)) else 0)
                     for line, ok in zip(lines, of_form, strict=True)]
            first = kinds[0]
        else:
            kinds = [m.lastindex or 0 if (m := match(line)) else 0 for line in lines]
            if long:
                kinds = [0 if len(line) > self.max_line else k for line, k in zip(lines, kinds, strict=True)]
            first = kinds[0]
        uniform = bool(first) and kinds.count(first) == n
        if uniform:  # one dialect throughout: its arrays as they are
            got = self._parse_kind(first, lines)
            kind = np.full(n, first, dtype=np.int8)
        rows_of = None
        if not uniform:
            kind = np.array(kinds, dtype=np.int8)
            dialects = set(kinds) - {0}
            if len(dialects) == 1:  # one dialect and lines of none (damage): its lines alone, no scatter
                one = dialects.pop()
                rows_of = (kind == one).nonzero()[0]  # np.flatnonzero without its wrappers
                got = self._parse_kind(one, [lines[i] for i in rows_of.tolist()])
            else:
                got = _Parsed.empty(n)
                for k in dialects:
                    at = np.flatnonzero(kind == k)
                    got.put(at, self._parse_kind(k, [lines[i] for i in at.tolist()]))
        if n >= 4 and len(set(map(len, lines))) == 1 and got.good[i := int(np.argmax(got.good))]:
            line = i if rows_of is None else int(rows_of[i])
            self._learn_form(int(kind[line]), lines[line], raw)
        return (end, *self._assemble(first, uniform, kind, got, lines, rows, messages, rows_of))

    def _assemble(self, first: int, uniform: bool, kind: np.ndarray, got: _Parsed, lines: list[bytes],
                  rows: list[tuple], messages: list[Message],
                  rows_of: np.ndarray | None = None) -> tuple[list[np.ndarray], bool]:
        """The batches of parsed lines (``kind`` of each, ``got`` their numbers, of the lines ``rows_of``
        when not of every line, all of one kind): runs of sample lines as arrays, the other lines through
        :meth:`_line` in order (their rows appended to ``rows``)."""
        n = len(kind)
        if rows_of is None:
            ok = got.good
        else:
            ok = np.zeros(n, dtype=bool)
            ok[rows_of] = got.good
        clean = first == _CSV and uniform and bool(_ALL(ok))
        if clean:
            return [self._batch(0, n, first, got, self._csv_dtype)], True
        one = first if uniform else kind if rows_of is None else int(kind[rows_of[0]])
        if _ALL(ok):
            dtype = MAG_SAMPLE_DTYPE if self._field or first != _CSV or not uniform and _ANY(kind != _CSV) \
                else SAMPLE_DTYPE
            return [self._batch(0, n, one, got, dtype)], False
        # Runs of samples between lines read one by one: each sample's place in one batch, the numbers
        # (counts) given in line order as reading every line alone gives them.
        edges = (ok[1:] != ok[:-1]).nonzero()[0] + 1
        bounds = [0, *edges.tolist(), n]
        row_places: list[int] = []  # places of the rows of lines read one by one
        runs: list[tuple[int, int]] = []  # the first count and length of each run of batch lines
        filled = 0
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            if not ok[a]:
                for line in lines[a:b]:
                    if len(line) > self.max_line:
                        self._too_long(len(line))
                    else:
                        before = len(rows)
                        self._line(line, rows, messages)
                        if len(rows) > before:
                            row_places.append(filled)
                            filled += 1
                continue
            runs.append((self._count, b - a))
            self._count += b - a
            filled += b - a
        if not runs:  # no batch: the rows are the caller's, as they were
            return [], False
        parsed: slice | np.ndarray
        if rows_of is None:
            parsed = ok.nonzero()[0]
            self._field = self._field or bool(_ANY(kind[parsed] != _CSV))
        else:  # got holds the lines of one dialect: all of them samples, or those it found good
            parsed = slice(None) if _ALL(got.good) else got.good.nonzero()[0]
            self._field = self._field or one != _CSV
        dtype = MAG_SAMPLE_DTYPE if self._field else SAMPLE_DTYPE
        # The batch's samples together (slices on the output side: cheaper than fancy field writes), then
        # the rows between them where any. Without such rows, the runs' numbers follow each other.
        size = sum(m for _, m in runs)
        batch = np.empty(size, dtype=dtype)
        counts = np.concatenate([np.arange(c, c + m) for c, m in runs]) if rows and len(runs) > 1 \
            else np.arange(runs[0][0], runs[0][0] + size)
        self._fill(batch, slice(None), parsed, one, got, counts)
        if not rows:
            return [batch], False
        out = np.empty(filled, dtype=dtype)
        mine = np.ones(filled, dtype=bool)
        mine[row_places] = False
        out[mine] = batch
        out[row_places] = rows_to_batch(rows, dtype == MAG_SAMPLE_DTYPE)
        rows.clear()
        return [out], False

    def _learn_form(self, kind: int, line: bytes, raw: bytes) -> None:
        """Keep the fixed layout of ``line`` (a sample of ``kind``, the first of a batch of lines of one
        width in ``raw``) for :meth:`_read_fixed`, when its numbers have one."""
        ending = b"\r\n" if b"\r" in raw else b"\n"  # read_fixed refuses text this does not fit
        if kind == _CSV and not self._fast_forms:
            return
        head, _, delim, _, checksum = self._form(kind)
        form = fixed_form(line, ending, len(head), checksum, delim)
        self._fixed_form = None if form is None else (kind, form)

    def _read_fixed(self, raw: bytes) -> tuple[int, _Parsed] | None:
        """The lines of ``raw`` read by the layout :meth:`_learn_form` kept, when they are lines of its
        width and most of them have it (else None: the general way, which may learn another)."""
        if self._fixed_form is None or self._first_line or self._discarding:
            return None
        kind, form = self._fixed_form
        found = read_fixed(form, raw)
        if found is None:
            return None
        table, good = found
        if 4 * int(np.count_nonzero(good)) < 3 * len(good):  # not this layout any more: lines one by one
            self._fixed_form = None
            return None
        return kind, self._parse_kind(kind, [], (table, good))

    def _uniform(self, kind: int, text: bytes, lines: list[bytes]) -> bool:
        """Whether every line of ``text`` (its ends all ``\\n``) has the form of ``kind`` (as
        :func:`_line_forms`), checked on the whole text at once; a line with a field too many and another
        with one too few pass, and their batch refuses them (:func:`_table`)."""
        n = len(lines)
        self._scanned = None
        if kind == _CSV:
            delim = self.columns.delimiter.encode("ascii")
            others = text.translate(None, _NUMBER_BYTES + delim + b"\n")
            self._scanned = (text, text, others)  # for _few_bad when this says no
            return not others and text.count(delim) == n * (len(self.columns.names) - 1)
        head = _HEADS[kind]
        if text.count(head) != n or (b"\n" + text).count(b"\n" + head) != n:
            return False
        if kind in (_RAW, _UNI):
            body = text.replace(head, b"")
            others = body.translate(None, (_INT_BYTES if kind == _RAW else _NUMBER_BYTES) + b",\n")
            self._scanned = (text, body, others)
            return not others and body.count(b",") == 8 * n
        if text.count(b"*") != n or any(line[-3] != 42 for line in lines):  # '*'
            return False
        body = b"\n".join(line[len(head):-3] for line in lines)
        sums = b"".join(line[-2:] for line in lines)
        fields = 12 if kind == _VNYMR else 11
        return (not body.translate(None, _NUMBER_BYTES + b",\n") and not sums.translate(None, _HEX_BYTES)
                and body.count(b",") == (fields - 1) * n)

    def _few_bad(self, kind: int, text: bytes, lines: list[bytes],
                 match: Callable[[bytes], re.Match[bytes] | None]) -> list[int] | None:
        """The kinds of ``lines`` (as :meth:`_uniform`'s, line for line) when all but a few hold only the
        bytes of numbers of ``kind`` (CSV, ``Raw:``, ``Uni:``): the other bytes :meth:`_uniform` found (by
        deleting those of numbers from the text) are looked up to find their lines (damage), which the
        regex classes one by one; the others pass as in :meth:`_uniform` (their field counts add up).
        None when the lines are not so (then :func:`form_mask` classes them all)."""
        n = len(lines)
        scanned = self._scanned
        if kind not in (_CSV, _RAW, _UNI) or (kind == _CSV and not self._fast_forms) or scanned is None \
                or scanned[0] is not text:
            return None  # _uniform found no line of the form (a head count off): form_mask
        # The other bytes, found by _uniform by deleting the allowed ones (C speed); where each is by find.
        _, body, others = scanned
        head, delim, fields = (b"", self.columns.delimiter.encode("ascii"), len(self.columns.names)) \
            if kind == _CSV else (_HEADS[kind], b",", 9)
        if len(others) > 4 * _FEW_BAD:
            return None
        where = set()
        for byte in set(others):
            at = -1
            for _ in range(others.count(byte)):
                at = body.find(byte, at + 1)
                where.add(at)
        bad: list[int] = []
        after = lo = 0
        for at in sorted(where):
            if at < after:
                continue  # another byte of a line already found
            start = body.rfind(b"\n", 0, at) + 1
            after = body.find(b"\n", at) % (len(body) + 1)  # -1 (never: text ends a line) as the end
            try:
                i = lines.index(head + body[start:after], lo)  # in order: the first copy from lo is this one
            except ValueError:  # pragma: no cover - every line of body is a line without its head
                return None
            bad.append(i)
            lo = i + 1
            if len(bad) > _FEW_BAD:
                return None
        rest = body.count(delim) - sum(lines[i].count(delim) for i in bad)
        if not bad or rest != (n - len(bad)) * (fields - 1):
            return None
        kinds = [kind] * n
        for i in bad:
            found = match(lines[i])
            kinds[i] = 0 if found is None else found.lastindex or 0
        return kinds

    @functools.cached_property
    def _fast_forms(self) -> bool:
        """Whether the CSV delimiter leaves the number characters as they are (a sane one: ``,``, ``;``,
        a tab ...), so that :func:`form_mask` and :func:`number_table` read lines as the regex does."""
        delim = self.columns.delimiter
        return len(delim) == 1 and delim not in "-+.0123456789eE\r\n"

    def _form(self, kind: int) -> tuple[bytes, bytes, bytes, int, bool]:
        """A dialect's form for :func:`form_mask`: head, number characters, delimiter, fields, checksum."""
        if kind == _CSV:
            return b"", _NUMBER_BYTES, self.columns.delimiter.encode("ascii"), len(self.columns.names), False
        fields = {_RAW: 9, _UNI: 9, _VNYMR: 12, _VNIMU: 11}[kind]
        return _HEADS[kind], _INT_BYTES if kind == _RAW else _NUMBER_BYTES, b",", fields, kind >= _VNYMR

    @functools.cached_property
    def _csv_dtype(self) -> np.dtype:
        return MAG_SAMPLE_DTYPE if self.columns.has_mag else SAMPLE_DTYPE

    def _batch(self, a: int, b: int, kind: np.ndarray | int, got: _Parsed, dtype: np.dtype) -> np.ndarray:
        """The samples of lines ``a:b`` (all of them samples), numbered from the decoder's count."""
        out = np.empty(b - a, dtype=dtype)  # every field written below
        self._fill(out, slice(None), slice(a, b), kind, got)
        return out

    def _fill(self, out: np.ndarray, at: slice | np.ndarray, sel: slice | np.ndarray, kind: np.ndarray | int,
              got: _Parsed, counts: np.ndarray | None = None) -> None:
        """Write the samples of lines ``sel`` (all of them samples; ``kind`` the kind of every line, or the
        one kind of them all) to ``out[at]``, numbered ``counts`` (default: on from the decoder's count,
        which moves past them), and count them."""
        if counts is None:
            counts = np.arange(self._count, self._count + len(got.good[sel]))
            self._count += len(counts)
        m = len(counts)
        csv: np.ndarray | bool
        if isinstance(kind, int):
            kinds = {kind: m}
            csv = kind == _CSV
        else:
            of = kind[sel]
            found = np.bincount(of, minlength=len(_KIND_NAMES) + 1).tolist()
            kinds = {k: found[k] for k in _KIND_NAMES if found[k]}
            csv = of == _CSV
            csv = True if len(kinds) == 1 and _CSV in kinds else csv if _CSV in kinds else False
        if got.seq is not None and csv is not False:
            seq = got.seq[sel] if csv is True else np.where(csv, got.seq[sel], counts)
            out["seq"][at] = seq & 0xFFFFFFFF
        else:
            out["seq"][at] = counts  # stored modulo 2**32, as & 0xFFFFFFFF
        if got.t is not None and csv is not False:
            self.clock_lines += kinds.get(_CSV, 0)
            t: np.ndarray = got.t[sel] * 1e6
            if csv is not True:
                t = np.where(csv, t, counts * 1e6 / self.rate_hz)
        else:
            t = counts * 1e6 / self.rate_hz
        out["t_us"][at] = np.rint(t)
        out["acc"][at] = got.acc[sel]
        out["gyro"][at] = got.gyro[sel]
        out["temp"][at] = got.temp[sel]
        if out.dtype == MAG_SAMPLE_DTYPE:
            out["mag"][at] = np.nan if got.mag is None else got.mag[sel]
        self.stats.frames += m
        for k, count in kinds.items():
            name = _KIND_NAMES[k]
            self.kinds_seen[name] = self.kinds_seen.get(name, 0) + count
            if name != "csv":
                self._field = True

    def _parse_kind(self, k: int, lines: list[bytes],
                    fixed: tuple[np.ndarray, np.ndarray] | None = None) -> _Parsed:
        """The numbers of the lines of one dialect, and which of them are samples; ``fixed``: their table
        and the lines of its form (checksums checked), read by :func:`read_fixed`."""
        key = (k, self.columns, self.max_acc, self.max_gyro, self.max_mag, tuple(self.temp_range))
        lay = self._layouts.get(key) or self._layouts.setdefault(key, self._layout(k))
        if fixed is not None:
            table, good = fixed
            if k == _RAW:
                table += 0.0  # int("-0") is 0: no negative zero (-0.0 + 0.0 is 0.0)
                good &= _ALL(np.abs(table) <= _MAX_COUNTS, axis=1)
        elif k == _CSV:
            delim = self.columns.delimiter
            found = _arrays_table(b"\n".join(lines), lines, delim.encode("ascii"), len(lay.lo), False) \
                if self._fast_forms else None
            table, good = found or _table(lines, delim, len(lay.lo))
        else:
            head = _HEADS[k]
            if k >= _VNYMR:
                bodies = [line[len(head):-3] for line in lines]
                text = b"\n".join(bodies)
            else:  # every line starts with its head, and holds no other (a colon is no number's)
                text = b"\n".join(lines).replace(head, b"")
                bodies = text.split(b"\n")
            found = _arrays_table(text, bodies, b",", len(lay.lo), k == _RAW)
            table, good = found or _table(bodies, ",", len(lay.lo))
            if k >= _VNYMR:
                good &= _checksums_match(lines)
            elif k == _RAW:
                counted = np.abs(table) <= _MAX_COUNTS
                if not _ALL(counted, axis=None):
                    good &= _ALL(counted, axis=1)
        v = table
        for factor, divide in ((lay.m1, False), (lay.div, True), (lay.m2, False)):
            if factor is not None:
                v = v / factor if divide else v * factor
        inside = (v >= lay.lo) & (v <= lay.hi)
        if not _ALL(inside, axis=None):  # lines out of bounds, or a NaN (outside both bounds) where it may be
            if lay.nan_ok is not None:
                inside |= np.isnan(v) & lay.nan_ok
            good &= _ALL(inside, axis=1)
        n = len(good)
        seq = None
        if lay.seq is not None:
            seq = np.zeros(n, dtype=np.int64)
            seq[good] = v[good, lay.seq].astype(np.int64)
        temp = np.full(n, np.nan) if lay.temp is None else v[:, lay.temp]
        return _Parsed(good, v[:, lay.acc], v[:, lay.gyro], temp, None if lay.mag is None else v[:, lay.mag],
                       None if lay.t is None else v[:, lay.t], seq)

    @functools.cached_property
    def _layouts(self) -> dict[tuple, _Layout]:
        return {}

    def _layout(self, k: int) -> _Layout:
        """Where each quantity sits in the table of a dialect, its factors to SI (applied as
        ``x * m1 / div * m2``, the order of the line-by-line arithmetic) and the bounds of a sample."""
        width = {_CSV: len(self.columns.names), _RAW: 9, _UNI: 9, _VNYMR: 12, _VNIMU: 11}[k]
        m1, div, m2 = np.ones(width), np.ones(width), np.ones(width)
        lo, hi, nan_ok = np.full(width, -np.inf), np.full(width, np.inf), np.ones(width, dtype=bool)
        at: dict[str, int]
        if k == _CSV:
            at = {name: i for i, name in enumerate(self.columns.names) if name != SKIP}
            m1 = np.array(self.columns.scales)
        else:
            base = {_RAW: 0, _UNI: 0, _VNYMR: 6, _VNIMU: 3}[k]
            at = {name: base + i for i, name in enumerate(("ax", "ay", "az", "gx", "gy", "gz"))}
            at.update({n: ({_RAW: 6, _UNI: 6, _VNYMR: 3, _VNIMU: 0}[k] + i) for i, n in enumerate(MAG_NAMES)})
            if k == _VNIMU:
                at["temp"] = 9
        acc = [at[n] for n in ("ax", "ay", "az")]
        gyro = [at[n] for n in ("gx", "gy", "gz")]
        mag = [at[n] for n in MAG_NAMES] if "mx" in at else None
        if k == _RAW:
            m1[acc], div[acc] = STANDARD_GRAVITY, MOTIONCAL_ACC_PER_G
            div[gyro], m2[gyro] = MOTIONCAL_GYRO_PER_DPS, _DEG_TO_RAD
            div[mag] = MOTIONCAL_MAG_PER_UT
        elif k in (_VNYMR, _VNIMU):
            m1[mag] = UT_PER_GAUSS
        for cols, low, high, nan in ((acc, -self.max_acc, self.max_acc, False),
                                     (gyro, -self.max_gyro, self.max_gyro, False),
                                     (mag, -self.max_mag, self.max_mag, True),
                                     ([at["temp"]] if "temp" in at else None, *self.temp_range, True),
                                     ([at["t"]] if "t" in at else None, 0.0, _BELOW_MAX_T_S, False),
                                     ([at["seq"]] if "seq" in at else None, 0.0, _BELOW_MAX_SEQ, False)):
            if cols is not None:
                lo[cols], hi[cols], nan_ok[cols] = low, high, nan

        def unit(factors: np.ndarray) -> np.ndarray | None:
            return None if (factors == 1.0).all() else factors

        return _Layout(unit(m1), unit(div), unit(m2), lo, hi, nan_ok if nan_ok.any() else None,
                       _columns(acc), _columns(gyro), None if mag is None else _columns(mag), at.get("temp"),
                       at.get("t"), at.get("seq"))

    def flush(self) -> Decoded:
        """End of stream: a last line without its end of line is still read."""
        rows: list[tuple] = []
        messages: list[Message] = []
        if self._buf and not self._discarding:
            self._line(bytes(self._buf), rows, messages)
        elif self._buf:
            self.stats.garbage_bytes += len(self._buf)
        self._buf.clear()
        self._discarding = False
        samples = rows_to_batch(rows, self._field)
        self.stats.samples += len(samples)
        return Decoded(samples, messages)

    def _too_long(self, n: int) -> None:
        if not self._discarding:
            self.stats.length_errors += 1
            self.stats.resyncs += 1
        self.stats.garbage_bytes += n

    def _line(self, line: bytes, rows: list[tuple], messages: list[Message]) -> None:
        first, self._first_line = self._first_line, False
        stats = self.stats
        start = self._glued_start(line)
        if start:
            stats.garbage_bytes += start
            stats.resyncs += 1
            line = line[start:]
        try:
            text = line.decode("ascii").strip()
        except UnicodeDecodeError:
            stats.garbage_bytes += len(line)
            stats.resyncs += 1
            return
        if not text:
            return
        values: tuple | None
        try:
            if text.startswith(("Raw:", "Uni:")):
                kind, values = "motioncal", self._motioncal(text)
            elif text.startswith("$VN"):
                kind, values = "vectornav", self._vectornav(text)
                if values is None:
                    self._seen("vectornav")
                    stats.frames += 1
                    messages.append(Message(MSG_VECTORNAV, line))
                    return
            else:
                kind, values = "csv", None if _TAGGED.match(text) else self._csv(text)
                if values is None:
                    self._seen("text")
                    stats.frames += 1
                    stats.unknown_ids += 1
                    messages.append(Message(MSG_TEXT, line))
                    return
            row = self._row(*values)
        except _Reject as reject:
            if first:  # most likely the tail of a line sent before we listened
                stats.garbage_bytes += len(line)
                stats.resyncs += 1
            else:
                setattr(stats, reject.kind, getattr(stats, reject.kind) + 1)
            return
        self._seen(kind)
        stats.frames += 1
        rows.append(row)

    def _glued_start(self, line: bytes) -> int:
        """Where a sample line starts after bytes glued before it (a line cut short, noise on the
        wire), or 0. A VectorNav sentence carries its own checksum, so it is read from its '$'; a
        MotionCal line from its tag, when what follows it is a whole sample (so a banner that
        mentions ``Raw:`` stays text)."""
        sentence = max(line.rfind(b"$VN"), 0)
        tag = max(line.rfind(b"Raw:"), line.rfind(b"Uni:"))
        # The later of the two starts the line: '$VN' in the noise before a MotionCal tag is noise.
        if tag > sentence:
            try:
                self._motioncal(line[tag:].decode("ascii").strip())
            except (_Reject, UnicodeDecodeError):
                return sentence
            return tag
        return sentence

    def _seen(self, kind: str) -> None:
        self.kinds_seen[kind] = self.kinds_seen.get(kind, 0) + 1

    @staticmethod
    def _numbers(fields: list[str], cast=float) -> list:
        try:
            return [cast(f) for f in fields]
        except ValueError:
            raise _Reject("bad_payloads") from None

    def _motioncal(self, text: str) -> tuple:
        fields = text[4:].split(",")
        if len(fields) != 9:
            raise _Reject("bad_payloads")
        if text.startswith("Raw:"):
            v = self._numbers(fields, int)
            if any(abs(x) > _MAX_COUNTS for x in v):
                raise _Reject("bad_payloads")
            acc = [x * STANDARD_GRAVITY / MOTIONCAL_ACC_PER_G for x in v[0:3]]
            gyro = [math.radians(x / MOTIONCAL_GYRO_PER_DPS) for x in v[3:6]]
            mag = tuple(x / MOTIONCAL_MAG_PER_UT for x in v[6:9])
        else:
            v = self._numbers(fields)
            acc, gyro, mag = v[0:3], v[3:6], tuple(v[6:9])
        return None, None, acc, gyro, math.nan, mag

    def _vectornav(self, text: str) -> tuple | None:
        body, star, cs = text[1:].partition("*")
        if not star or len(cs) not in (2, 4):
            raise _Reject("bad_payloads")
        raw = body.encode("ascii")
        try:
            expected = int(cs, 16)
        except ValueError:
            raise _Reject("bad_payloads") from None
        actual = nmea_xor(raw) if len(cs) == 2 else crc16_ccitt_false(raw, 0)
        if actual != expected:
            raise _Reject("crc_errors")
        fields = body.split(",")
        head, fields = fields[0], fields[1:]
        # SerialCount / SerialStatus append ",T<count>" / ",S<status>" before the checksum.
        while fields and fields[-1][:1] in ("T", "S"):
            fields.pop()
        if head == "VNYMR":
            if len(fields) != 12:
                raise _Reject("bad_payloads")
            v = self._numbers(fields)
            return None, None, v[6:9], v[9:12], math.nan, tuple(x * UT_PER_GAUSS for x in v[3:6])
        if head == "VNIMU":
            if len(fields) != 11:
                raise _Reject("bad_payloads")
            v = self._numbers(fields)
            return None, None, v[3:6], v[6:9], v[9], tuple(x * UT_PER_GAUSS for x in v[0:3])
        return None

    def _csv(self, text: str) -> tuple | None:
        cols = self.columns
        fields = [f.strip() for f in text.split(cols.delimiter)]
        if not any(_is_number(f) for f in fields):
            return None
        if len(fields) != len(cols.names):
            raise _Reject("bad_payloads")
        got: dict[str, float] = {}
        for name, scale, field in zip(cols.names, cols.scales, fields, strict=True):
            if name == SKIP:
                continue
            try:
                got[name] = float(field) * scale
            except ValueError:
                raise _Reject("bad_payloads") from None
        seq = got.get("seq")
        if seq is not None and not 0 <= seq < _MAX_SEQ:
            raise _Reject("bad_payloads")
        t = got.get("t")
        if t is not None and not 0 <= t < _MAX_T_S:
            raise _Reject("bad_payloads")
        mag = (got["mx"], got["my"], got["mz"]) if cols.has_mag else None
        return (None if seq is None else int(seq), t, [got["ax"], got["ay"], got["az"]],
                [got["gx"], got["gy"], got["gz"]], got.get("temp", math.nan), mag)

    def _row(self, seq: int | None, t: float | None, acc, gyro, temp: float,
             mag: tuple[float, ...] | None = None) -> tuple:
        """A sample row, its field (or NaN) the sixth element (``rows_to_batch`` drops it from a stream
        that has carried none)."""
        if mag is not None and any(math.isinf(m) or abs(m) > self.max_mag for m in mag):
            raise _Reject("bad_payloads")
        if not all(math.isfinite(a) and abs(a) <= self.max_acc for a in acc):
            raise _Reject("bad_payloads")
        if not all(math.isfinite(g) and abs(g) <= self.max_gyro for g in gyro):
            raise _Reject("bad_payloads")
        if not math.isnan(temp) and not self.temp_range[0] <= temp <= self.temp_range[1]:
            raise _Reject("bad_payloads")
        n = self._count
        self._count += 1
        seq = n if seq is None else seq
        if t is None:
            t_us = round(n * 1e6 / self.rate_hz)
        else:
            t_us = round(t * 1e6)
            self.clock_lines += 1
        if mag is not None:
            self._field = True
        return (seq & 0xFFFFFFFF, t_us, acc, gyro, temp, _NAN3 if mag is None else mag)


@dataclass
class _Parsed:
    """Numbers of parsed lines (SI; the field in uT), and which lines are samples. ``mag`` None: no field;
    ``t`` / ``seq`` None: the lines carry no clock / counter (then the decoder's count makes them)."""

    good: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    temp: np.ndarray
    mag: np.ndarray | None
    t: np.ndarray | None
    seq: np.ndarray | None

    @classmethod
    def empty(cls, n: int) -> _Parsed:
        return cls(np.zeros(n, dtype=bool), np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, np.nan),
                   np.full((n, 3), np.nan), None, None)

    def put(self, at: np.ndarray, part: _Parsed) -> None:
        """Place ``part`` (the lines ``at``) in these arrays."""
        self.good[at], self.acc[at], self.gyro[at], self.temp[at] = part.good, part.acc, part.gyro, part.temp
        if part.mag is not None and self.mag is not None:
            self.mag[at] = part.mag
        if part.t is not None:
            if self.t is None:
                self.t = np.zeros(len(self.good))
            self.t[at] = part.t
        if part.seq is not None:
            if self.seq is None:
                self.seq = np.zeros(len(self.good), dtype=np.int64)
            self.seq[at] = part.seq


@dataclass(frozen=True)
class _Layout:
    """A dialect's table: its factors to SI, the bounds of a sample's values (NaN allowed where
    ``nan_ok``), and the columns of each quantity."""

    m1: np.ndarray | None
    div: np.ndarray | None
    m2: np.ndarray | None
    lo: np.ndarray
    hi: np.ndarray
    nan_ok: np.ndarray | None
    acc: slice | list[int]
    gyro: slice | list[int]
    mag: slice | list[int] | None
    temp: int | None
    t: int | None
    seq: int | None


def _columns(at: list[int]) -> slice | list[int]:
    """Consecutive columns as a slice (a view), others as a list."""
    return slice(at[0], at[-1] + 1) if at == list(range(at[0], at[0] + len(at))) else at


# Kinds of line the batches read (the group of _line_forms that matched), and their kinds_seen name.
_CSV, _RAW, _UNI, _VNYMR, _VNIMU = 1, 2, 3, 4, 5
_KIND_NAMES = {_CSV: "csv", _RAW: "motioncal", _UNI: "motioncal", _VNYMR: "vectornav", _VNIMU: "vectornav"}
_DEG_TO_RAD = math.pi / 180.0  # math.radians' factor
_NUMBER = "-+.0-9eE \t"
_NUMBER_BYTES = b"-+.0123456789eE \t"
_INT_BYTES = b"-+0123456789 \t"
_HEX_BYTES = b"0123456789ABCDEFabcdef"
# Lines from which number_table parses a batch: it costs a fixed few tens of numpy calls and then less a
# number than np.loadtxt (about 1.2-1.9x on 700 lines of a 64 KiB read), which costs less on few lines.
_ARRAY_PARSE = 256
_HEADS = {_RAW: b"Raw:", _UNI: b"Uni:", _VNYMR: b"$VNYMR,", _VNIMU: b"$VNIMU,"}
# ndarray.all / any without their Python wrappers (a few microseconds each, many times a read).
_ALL = np.logical_and.reduce
_ANY = np.logical_or.reduce
_FEW_BAD = 8
_FLOATS_AT = SAMPLE_DTYPE.fields["acc"][1]  # type: ignore[index]  # the first float32 of a sample  # damaged lines a batch finds by a regex scan; more: form_mask classes every line




@functools.cache
def _line_forms(delimiter: str, fields: int) -> re.Pattern[bytes]:
    """A sample line as it stands, group n the kind n (``_CSV`` ... ``_VNIMU``): the field count of its
    dialect, only the characters of numbers in its fields, and for VectorNav a two-digit checksum.
    CSV lines only with a one-character delimiter (other lines of a longer one go one by one)."""
    def fields_of(chars: str, count: int, sep: str = ",") -> str:
        one = f"[{chars.replace(sep, '')}]*"
        return one + f"(?:{re.escape(sep)}{one}){{{count - 1}}}"

    forms = [
        fields_of(_NUMBER, fields, delimiter) if len(delimiter) == 1 else "(?!)",
        "Raw:" + fields_of("-+0-9 \t", 9),
        "Uni:" + fields_of(_NUMBER, 9),
        r"\$VNYMR," + fields_of(_NUMBER, 12) + r"\*[0-9A-Fa-f]{2}",
        r"\$VNIMU," + fields_of(_NUMBER, 11) + r"\*[0-9A-Fa-f]{2}",
    ]
    return re.compile("|".join(f"({form})" for form in forms).encode("ascii"))


def _arrays_table(text: bytes, lines: list[bytes], delimiter: bytes, width: int,
                  integers: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """The table of numbers of ``lines`` (``text``: joined by newlines) in arrays: :func:`simple_table`
    when every field is a simple number, else :func:`number_table` for a batch large enough to pay its
    fixed cost; None: :func:`_table` reads them."""
    found = simple_table(text, len(lines), delimiter, width, integers)
    if found is None and len(lines) >= _ARRAY_PARSE:
        found = number_table(lines, delimiter, width, integers)
    return found


def _table(lines: list[bytes], delimiter: str, width: int) -> tuple[np.ndarray, np.ndarray]:
    """The numbers of lines of ``width`` fields as a table, and which lines parsed (a line that does not, or
    has another field count, holds NaN; found by halving the lines where ``np.loadtxt`` refuses)."""
    try:
        table = np.loadtxt(lines, delimiter=delimiter, dtype=np.float64, ndmin=2, comments=None,
                           encoding="ascii")
        if table.shape[1] == width:  # a line of another field count alone parses, at its own width
            return table, np.ones(len(lines), dtype=bool)
    except ValueError:
        pass
    if len(lines) == 1:
        return np.full((1, width), np.nan), np.zeros(1, dtype=bool)
    half = len(lines) // 2
    (t1, g1), (t2, g2) = _table(lines[:half], delimiter, width), _table(lines[half:], delimiter, width)
    return np.concatenate([t1, t2]), np.concatenate([g1, g2])


def _checksums_match(lines: list[bytes]) -> np.ndarray:
    """Which ``$...*XX`` sentences carry the XOR of their body as XX."""
    bodies = [line[1:-3] for line in lines]
    data = np.frombuffer(b"".join(bodies), dtype=np.uint8)
    starts = np.cumsum([0, *map(len, bodies[:-1])])
    actual = np.bitwise_xor.reduceat(data, starts)
    expected = np.array([int(line[-2:], 16) for line in lines])
    return actual == expected


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------------------------- encoders


def encode_csv(samples: np.ndarray, columns: str | CsvColumns = DEFAULT_COLUMNS) -> bytes:
    """CSV lines of a ``SAMPLE_DTYPE`` batch in the given columns (values divided by their scale);
    mx, my, mz from a ``MAG_SAMPLE_DTYPE`` batch (NaN without)."""
    cols = parse_columns(columns) if isinstance(columns, str) else columns
    field = samples["mag"] if has_mag(samples) else np.full((len(samples), 3), np.nan)
    values = {
        "mx": field[:, 0], "my": field[:, 1], "mz": field[:, 2],
        "seq": samples["seq"].astype(np.float64), "t": samples["t_us"].astype(np.float64) / 1e6,
        "ax": samples["acc"][:, 0], "ay": samples["acc"][:, 1], "az": samples["acc"][:, 2],
        "gx": samples["gyro"][:, 0], "gy": samples["gyro"][:, 1], "gz": samples["gyro"][:, 2],
        "temp": samples["temp"],
    }
    lines = []
    for i in range(len(samples)):
        fields = []
        for name, scale in zip(cols.names, cols.scales, strict=True):
            if name == SKIP:
                fields.append("0")
            elif name == "seq":
                fields.append(str(int(samples["seq"][i])))
            else:
                fields.append(f"{float(values[name][i]) / scale:.9g}")
        lines.append(cols.delimiter.join(fields))
    return ("\r\n".join(lines) + "\r\n").encode("ascii") if lines else b""


def _fields(samples: np.ndarray, default_ut: tuple[float, float, float]) -> np.ndarray:
    """(N, 3) field in uT the lines write: a nine-axis batch's own, ``default_ut`` where it has none."""
    field = np.tile(np.asarray(default_ut, dtype=np.float64), (len(samples), 1))
    if has_mag(samples):
        own = samples["mag"].astype(np.float64)
        known = np.isfinite(own).all(axis=1)
        field[known] = own[known]
    return field


def encode_motioncal(samples: np.ndarray, mag_ut: tuple[float, float, float] = (20.0, 0.0, -40.0)) -> bytes:
    """``Raw:`` lines at MotionCal's scales (rounded to whole counts); the field of a nine-axis batch, else
    the constant ``mag_ut``."""
    acc = np.rint(samples["acc"].astype(np.float64) / STANDARD_GRAVITY * MOTIONCAL_ACC_PER_G).astype(np.int64)
    gyro = np.rint(np.degrees(samples["gyro"].astype(np.float64)) * MOTIONCAL_GYRO_PER_DPS).astype(np.int64)
    mag = np.rint(_fields(samples, mag_ut) * MOTIONCAL_MAG_PER_UT).astype(np.int64)
    return "".join(
        f"Raw:{a[0]},{a[1]},{a[2]},{g[0]},{g[1]},{g[2]},{m[0]},{m[1]},{m[2]}\r\n"
        for a, g, m in zip(acc, gyro, mag, strict=True)
    ).encode("ascii")


def encode_vectornav(samples: np.ndarray, sentence: str = "VNYMR", crc16: bool = False) -> bytes:
    """``$VNYMR`` (zero attitude) or ``$VNIMU`` sentences, in VectorNav's number formats; the field of a
    nine-axis batch, else zero."""
    out = bytearray()
    fields = _fields(samples, (0.0, 0.0, 0.0)) / UT_PER_GAUSS
    for s, field in zip(samples, fields, strict=True):
        acc = ",".join(f"{float(v):+07.3f}" for v in s["acc"])
        gyro = ",".join(f"{float(v):+09.6f}" for v in s["gyro"])
        mag = ",".join(f"{float(v):+07.4f}" for v in field)
        if sentence == "VNYMR":
            body = f"VNYMR,+000.000,+000.000,+000.000,{mag},{acc},{gyro}"
        elif sentence == "VNIMU":
            temp = float(s["temp"]) if math.isfinite(float(s["temp"])) else 0.0
            body = f"VNIMU,{mag},{acc},{gyro},{temp:+05.1f},+101.325"
        else:
            raise ValueError(f"unknown VectorNav sentence {sentence!r}; use VNYMR or VNIMU")
        out += vectornav_sentence(body, crc16)
    return bytes(out)


def encode_samples(samples: np.ndarray, kind: str = "csv") -> bytes:
    """Lines of one kind: ``csv`` (the default columns), ``motioncal``, ``vnymr`` or ``vnimu``."""
    if not has_mag(samples):  # a nine-axis batch keeps its dtype: its field is written
        samples = np.asarray(samples, dtype=SAMPLE_DTYPE)
    if kind == "csv":
        return encode_csv(samples)
    if kind == "motioncal":
        return encode_motioncal(samples)
    if kind in ("vnymr", "vnimu"):
        return encode_vectornav(samples, kind.upper())
    raise ValueError(f"unknown line kind {kind!r}; use csv, motioncal, vnymr or vnimu")
