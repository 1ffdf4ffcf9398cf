"""A board's own binary frame as data (schema ``imu-station/frame/1``): the description and its rules.

:func:`describe` checks a description given as plain values (what a YAML or JSON file holds) against
``shared/specs/frame-description.md`` and returns a :class:`FrameDescription`, which
``protocols.frame`` compiles into a decoder. Reading the file is the station's job
(``station.frames.reader``: this layer reads no files); a broken description raises
:class:`FrameDescriptionError`, which names the key (``fields[3].at``) and the field, so the
reader can add the file and the line.

Several IMUs in one frame: a field of ``IMU_FIELDS`` may give ``imu: k`` (0 when it gives none), the
IMU instance whose value it is (``protocols.instances``); every instance a description names needs
its own ``ax``..``gz``, and ``seq``, ``t`` and the magnetic field are the board's, shared by all. A
description without ``imu`` is exactly what it was before the key existed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from protocols.errors import StationError
from protocols.frame_checksums import CHECKSUM_SIZES, CHECKSUM_TYPES

SCHEMA = "imu-station/frame/1"
MAX_SYNC = 8
MAX_LENGTH = 4096
"""The longest frame described (bytes); an IMU frame is a few tens."""
MIN_RATE_HZ = 0.1
"""The slowest ``rate_hz``: one frame in ten seconds (a smaller rate is a typo, and 1e-300 made
every sample's time overflow)."""
MAX_RATE_HZ = 100_000.0
"""The fastest ``rate_hz``: above the fastest IMU outputs (32 kHz), within the clock's microseconds."""
MAX_NAME = 64
SHOWN_CHARS = 60
"""The most of a value a message repeats (a name may be 60,000 characters)."""

# Field types: numpy's scalar kind and size in bytes. 24-bit integers have no numpy type; the
# decoder assembles them from their three bytes.
FIELD_TYPES: dict[str, tuple[str, int]] = {
    "u8": ("u", 1), "i8": ("i", 1), "u16": ("u", 2), "i16": ("i", 2), "u24": ("u", 3), "i24": ("i", 3),
    "u32": ("u", 4), "i32": ("i", 4), "u64": ("u", 8), "i64": ("i", 8), "f32": ("f", 4), "f64": ("f", 8),
}
REQUIRED_FIELDS = ("ax", "ay", "az", "gx", "gy", "gz")
FIELD_NAMES = ("seq", "t", *REQUIRED_FIELDS, "temp", "mx", "my", "mz")
BYTE_ORDERS = ("little", "big")
TOP_KEYS = ("schema", "name", "byte_order", "sync", "length", "checksum", "rate_hz", "fields")
CHECKSUM_KEYS = ("type", "from", "to", "at", "byte_order")
FIELD_KEYS = ("name", "at", "type", "scale", "offset", "byte_order", "imu")
IMU_FIELDS = (*REQUIRED_FIELDS, "temp")
"""The fields that may name their IMU instance (``imu: k``); the others are the board's."""
MAX_IMU = 15
"""The largest ``imu`` index of a frame description (a board carries a few IMUs, not hundreds)."""


class FrameDescriptionError(StationError, ValueError):
    """A description that breaks the rules: ``keys`` is where (``("fields", 3, "at")``), ``field`` whose.

    Parameters
    ----------
    keys : tuple
        The path of the offending value: mapping keys and list indices.
    problem : str
        What is wrong and what to write instead.
    field : str, optional
        The name of the field it concerns.
    """

    def __init__(self, keys: tuple[str | int, ...], problem: str, field: str | None = None):
        self.keys = keys
        self.problem = problem
        self.field = field
        super().__init__(f"{self.where}: {problem}")

    @property
    def where(self) -> str:
        """The key as the message names it: ``key 'fields[3].at' (field gx)``."""
        # a key may be the file's own (an unknown one): escaped and cut as a value is
        text = "".join(f"[{k}]" if isinstance(k, int) else f".{_cut(repr(str(k))[1:-1])}"
                       for k in self.keys).lstrip(".")
        where = f"key '{text}'" if text else "the description"
        return where + (f" (field {self.field})" if self.field else "")


@dataclass(frozen=True)
class FieldSpec:
    """One value in the frame: ``value = raw * scale + offset``, of the IMU instance ``imu``."""

    name: str
    at: int
    type: str
    scale: float = 1.0
    offset: float = 0.0
    byte_order: str = "little"
    imu: int = 0

    @property
    def key(self) -> str:
        """The field's name, and its instance when it is not 0 (``ax``, ``ax.imu1``): unique in a frame."""
        return self.name if self.imu == 0 else f"{self.name}.imu{self.imu}"

    @property
    def size(self) -> int:
        """Bytes the field spans."""
        return FIELD_TYPES[self.type][1]

    @property
    def kind(self) -> str:
        """``u``, ``i`` or ``f``."""
        return FIELD_TYPES[self.type][0]


@dataclass(frozen=True)
class ChecksumSpec:
    """The frame's checksum: over bytes ``start``..``end`` (exclusive), stored at ``at`` (none negative)."""

    type: str
    start: int
    end: int
    at: int
    byte_order: str

    @property
    def size(self) -> int:
        """Bytes of the checksum field."""
        return CHECKSUM_SIZES[self.type]


@dataclass(frozen=True)
class FrameDescription:
    """A checked frame description: what :class:`protocols.frame.FrameDecoder` compiles."""

    name: str
    sync: bytes
    length: int
    fields: tuple[FieldSpec, ...]
    checksum: ChecksumSpec | None = None
    rate_hz: float | None = None
    byte_order: str = "little"

    def field(self, name: str, imu: int = 0) -> FieldSpec | None:
        """The field called ``name`` (of the IMU instance ``imu``), or None."""
        return next((f for f in self.fields if f.name == name and f.imu == imu), None)

    @property
    def instances(self) -> tuple[int, ...]:
        """The IMU instances the frame carries, in order: ``(0,)`` for a description without ``imu``."""
        return tuple(sorted({f.imu for f in self.fields}))


def shown(value: Any) -> str:
    """``repr(value)`` for a message, cut to ``SHOWN_CHARS`` (this layer has no ``station.common.text``;
    repr() escapes what a terminal would act on, the cut keeps a huge value out of the message)."""
    return _cut(repr(value))


def _cut(text: str) -> str:
    return text if len(text) <= SHOWN_CHARS else text[: SHOWN_CHARS - 3] + "..."


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return (_is_int(value) or isinstance(value, float)) and math.isfinite(value)


class _Checker:
    """Reads one description, raising at the first value that breaks a rule."""

    def __init__(self, doc: Any):
        if not isinstance(doc, Mapping):
            raise FrameDescriptionError((), "must be a mapping of keys (schema, sync, length, fields, ...)")
        self.doc = doc

    def known_keys(self, mapping: Mapping, allowed: Sequence[str], keys: tuple,
                   field: str | None = None) -> None:
        for key in mapping:
            if key not in allowed:
                raise FrameDescriptionError((*keys, str(key)), f"unknown key; known: {', '.join(allowed)}",
                                            field)

    def integer(self, value: Any, keys: tuple, low: int, high: int, field: str | None = None) -> int:
        if not _is_int(value) or not low <= value <= high:
            raise FrameDescriptionError(keys, f"{shown(value)}: give an integer {low}..{high}", field)
        return int(value)

    def byte_order(self, value: Any, keys: tuple, field: str | None = None) -> str:
        if value not in BYTE_ORDERS:
            raise FrameDescriptionError(keys, f"{shown(value)}: give little or big", field)
        return str(value)

    def offset(self, value: Any, keys: tuple, length: int, what: str) -> int:
        """An offset in the frame; a negative one counts from the frame's end."""
        offset = self.integer(value, keys, -length, length)
        if offset < 0:
            offset += length
        if offset > length:
            raise FrameDescriptionError(keys, f"{value}: {what} lies past the frame's end (length {length})")
        return offset


def _sync(checker: _Checker, value: Any) -> bytes:
    values = [value] if _is_int(value) else value
    if not isinstance(values, list) or not 1 <= len(values) <= MAX_SYNC:
        raise FrameDescriptionError(("sync",), f"{shown(value)}: give a list of 1..{MAX_SYNC} bytes, e.g. "
                                    "[0xAA, 0x55]")
    return bytes(checker.integer(v, ("sync", i), 0, 255) for i, v in enumerate(values))


def _checksum(checker: _Checker, value: Any, length: int, sync_len: int, order: str) -> ChecksumSpec | None:
    keys: tuple[str | int, ...] = ("checksum",)
    if isinstance(value, str):
        value = {"type": value}
    if not isinstance(value, Mapping):
        raise FrameDescriptionError(keys, f"{shown(value)}: give a mapping with type (and from, to, at)")
    checker.known_keys(value, CHECKSUM_KEYS, keys)
    kind = value.get("type")
    if kind not in CHECKSUM_TYPES:
        raise FrameDescriptionError((*keys, "type"), f"{shown(kind)}: give one of "
                                    f"{', '.join(CHECKSUM_TYPES)}")
    if kind == "none":
        return None
    size = CHECKSUM_SIZES[kind]
    at = checker.offset(value.get("at", -size), (*keys, "at"), length, "the checksum")
    if at + size > length:
        raise FrameDescriptionError((*keys, "at"), f"the {size}-byte checksum at {at} runs past the frame's "
                                    f"end (length {length})")
    if at < sync_len:
        raise FrameDescriptionError((*keys, "at"), f"the checksum at {at} overlaps the sync "
                                    f"(bytes 0..{sync_len - 1})")
    start = checker.offset(value.get("from", sync_len), (*keys, "from"), length, "the first covered byte")
    end = checker.offset(value.get("to", at), (*keys, "to"), length, "the covered bytes' end")
    if end <= start:
        raise FrameDescriptionError((*keys, "to"), f"covers bytes {start}..{end - 1}: 'to' must come after "
                                    "'from'")
    if start < at + size and at < end:
        raise FrameDescriptionError((*keys, "at"), f"the checksum at {at}..{at + size - 1} lies inside the "
                                    f"bytes it covers ({start}..{end - 1})")
    byte_order = checker.byte_order(value.get("byte_order", order), (*keys, "byte_order"))
    return ChecksumSpec(str(kind), start, end, at, byte_order)


def _field(checker: _Checker, value: Any, index: int, length: int, order: str, sync_len: int,
           checksum: ChecksumSpec | None) -> FieldSpec:
    keys: tuple[str | int, ...] = ("fields", index)
    if not isinstance(value, Mapping):
        raise FrameDescriptionError(keys, f"{shown(value)}: give a mapping "
                                    "{name: ax, at: 8, type: i16, ...}")
    name = value.get("name")
    if name not in FIELD_NAMES:
        raise FrameDescriptionError((*keys, "name"), f"{shown(name)}: give one of "
                                    f"{', '.join(FIELD_NAMES)}")
    checker.known_keys(value, FIELD_KEYS, keys, name)
    kind = value.get("type")
    if kind not in FIELD_TYPES:
        raise FrameDescriptionError((*keys, "type"), f"{shown(kind)}: give one of "
                                    f"{' '.join(FIELD_TYPES)}", name)
    if name == "seq" and FIELD_TYPES[kind][0] == "f":
        raise FrameDescriptionError((*keys, "type"), f"{kind}: a sample counter is an integer type", name)
    if "at" not in value:
        raise FrameDescriptionError(keys, "missing key 'at' (the field's offset in the frame)", name)
    at = checker.integer(value["at"], (*keys, "at"), 0, length - 1, name)
    size = FIELD_TYPES[kind][1]
    if at + size > length:
        raise FrameDescriptionError((*keys, "at"), f"{at}: the {size}-byte {kind} runs past the frame's end "
                                    f"(length {length})", name)
    if at < sync_len:
        raise FrameDescriptionError((*keys, "at"), f"{at}: the field overlaps the sync "
                                    f"(bytes 0..{sync_len - 1})", name)
    if checksum is not None and at < checksum.at + checksum.size and checksum.at < at + size:
        raise FrameDescriptionError((*keys, "at"), f"{at}: the field overlaps the checksum (bytes "
                                    f"{checksum.at}..{checksum.at + checksum.size - 1})", name)
    numbers = {}
    for key, default in (("scale", 1.0), ("offset", 0.0)):
        number = value.get(key, default)
        if not _is_number(number) or (key == "scale" and number == 0):
            what = "a finite number other than 0" if key == "scale" else "a finite number"
            raise FrameDescriptionError((*keys, key), f"{shown(number)}: give {what}", name)
        numbers[key] = float(number)
    byte_order = checker.byte_order(value.get("byte_order", order), (*keys, "byte_order"), name)
    imu = 0
    if "imu" in value:
        if name not in IMU_FIELDS:
            raise FrameDescriptionError((*keys, "imu"), f"{name} is the board's, shared by its IMUs: only "
                                        f"{', '.join(IMU_FIELDS)} take imu; leave it out", name)
        imu = checker.integer(value["imu"], (*keys, "imu"), 0, MAX_IMU, name)
    return FieldSpec(str(name), at, str(kind), numbers["scale"], numbers["offset"], byte_order, imu)


def describe(doc: Any, default_name: str = "frame") -> FrameDescription:
    """Check a frame description given as plain values and return it.

    Parameters
    ----------
    doc : mapping
        The description as a YAML or JSON file holds it (schema ``imu-station/frame/1``).
    default_name : str
        The name when the description gives none (the file's stem).

    Returns
    -------
    FrameDescription
        The checked description, offsets made non-negative.

    Raises
    ------
    FrameDescriptionError
        The first rule the description breaks, naming the key and the field.
    """
    checker = _Checker(doc)
    checker.known_keys(doc, TOP_KEYS, ())
    if doc.get("schema") != SCHEMA:
        raise FrameDescriptionError(("schema",), f"{shown(doc.get('schema'))}: this station reads schema "
                                    f"{SCHEMA}")
    name = doc.get("name", default_name)
    if not isinstance(name, str) or not name.strip() or len(name) > MAX_NAME or not name.isprintable():
        raise FrameDescriptionError(("name",), f"{shown(name)}: give a printable name of up to {MAX_NAME} "
                                    "characters")
    order = checker.byte_order(doc.get("byte_order", "little"), ("byte_order",))
    if "sync" not in doc:
        raise FrameDescriptionError((), "missing key 'sync' (the bytes that start every frame)")
    sync = _sync(checker, doc["sync"])
    if "length" not in doc:
        raise FrameDescriptionError((), "missing key 'length' (the whole frame in bytes)")
    length = checker.integer(doc["length"], ("length",), len(sync) + 1, MAX_LENGTH)
    checksum = None
    if doc.get("checksum") is not None:
        checksum = _checksum(checker, doc["checksum"], length, len(sync), order)
    raw_fields = doc.get("fields")
    if not isinstance(raw_fields, list) or not raw_fields:
        raise FrameDescriptionError(("fields",), "give a list of fields ({name: ax, at: 8, type: i16, ...})")
    fields = tuple(_field(checker, f, i, length, order, len(sync), checksum)
                   for i, f in enumerate(raw_fields))
    seen: set[str] = set()
    for i, spec in enumerate(fields):
        if spec.key in seen:
            twice = "given twice" if spec.imu == 0 else f"given twice for imu {spec.imu}"
            raise FrameDescriptionError(("fields", i, "name"), twice, spec.name)
        seen.add(spec.key)
    for imu in sorted({f.imu for f in fields}):
        missing = [n for n in REQUIRED_FIELDS if FieldSpec(n, 0, "u8", imu=imu).key not in seen]
        if missing:
            whose = "" if imu == 0 else f" of imu {imu} (every IMU the frame carries needs ax..gz)"
            raise FrameDescriptionError(("fields",), f"missing required field(s) {', '.join(missing)}{whose}")
    rate_hz = doc.get("rate_hz")
    if rate_hz is not None and (not _is_number(rate_hz) or not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ):
        raise FrameDescriptionError(("rate_hz",), f"{shown(rate_hz)}: give the rate the board sends at, "
                                    f"{MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz")
    if rate_hz is None and "t" not in seen:
        raise FrameDescriptionError(("fields",), "no field gives the time (t): add one, or give rate_hz")
    return FrameDescription(name.strip(), sync, length, fields, checksum,
                            float(rate_hz) if rate_hz is not None else None, order)
