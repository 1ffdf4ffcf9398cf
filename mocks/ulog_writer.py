"""A writer of PX4 ULog files, for simulated flight-controller logs (a board's IMUs in a chamber sweep).

It follows PX4's "ULog File Format" document (``docs/en/dev_log/ulog_file_format.md``, file format
version 1), little endian throughout:

- the header, 16 bytes: the magic ``55 4c 6f 67 01 12 35`` ("ULog", 0x01, 0x12, 0x35), the version
  byte (1) and a uint64 timestamp (us);
- the definitions: messages of a 3-byte header ``uint16 msg_size`` (the payload, header excluded),
  ``uint8 msg_type``, then the payload: ``B`` flag bits (``uint8 compat_flags[8]``, ``uint8
  incompat_flags[8]``, ``uint64 appended_offsets[3]``; the first message), ``I`` information and
  ``P`` parameter (``uint8 key_len``, ``char key[key_len]`` as ``"<type> <name>"``, the value's
  bytes), ``F`` format (``char format[]``: ``"name:type field;type field;..."``);
- the data: ``A`` add-logged (``uint8 multi_id``, ``uint16 msg_id``, ``char message_name[]``),
  ``D`` data (``uint16 msg_id`` then the fields packed as the format lists them, without the
  trailing padding field, which is never logged), ``L`` logged string (``uint8 log_level``,
  ``uint64 timestamp``, ``char message[]``).

The topics are PX4's uORB messages as the logger writes them (``msg/SensorAccel.msg``,
``msg/SensorGyro.msg``, ``msg/SensorBaro.msg``): fields ordered largest type first and padded with
``uint8_t[n] _paddingK`` to a multiple of 8 bytes, as PX4's message generator does. Units are
PX4's: m/s^2, rad/s, degC, Pa, microseconds since boot.

Data messages of all topics are interleaved by timestamp and laid out with numpy (offsets
computed, rows scattered), so an hour of three IMUs writes in well under a second.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
VERSION = 1
ALIGN = 8  # PX4 pads each message struct to 8 bytes (its generator's trailing _padding field)

# C type -> numpy little-endian type (the spec's table of binary types)
CTYPES: dict[str, str] = {
    "int8_t": "i1", "uint8_t": "u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4",
    "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8",
    "bool": "u1", "char": "S1",
}
LOG_LEVEL_INFO = ord("6")  # the spec's log levels are ASCII '0'..'7'; '6' is INFO


@dataclass(frozen=True)
class Field:
    """One field of a ULog format: C type, name and array length (1: a scalar)."""

    ctype: str
    name: str
    count: int = 1

    def text(self) -> str:
        """The field as an ``F`` message writes it, e.g. ``float x`` or ``uint8_t[3] clip_counter``."""
        return f"{self.ctype}{f'[{self.count}]' if self.count > 1 else ''} {self.name}"


def padded(fields: Sequence[Field]) -> list[Field]:
    """``fields`` with the trailing ``uint8_t[n] _padding0`` that makes the struct a multiple of 8 bytes."""
    size = sum(np.dtype(CTYPES[f.ctype]).itemsize * f.count for f in fields)
    pad = -size % ALIGN
    return list(fields) + ([Field("uint8_t", "_padding0", pad)] if pad else [])


def dtype_of(fields: Sequence[Field]) -> np.dtype:
    """The packed numpy record type of a format's fields (no alignment: ULog data are packed)."""
    return np.dtype([(f.name, CTYPES[f.ctype], (f.count,)) if f.count > 1 else (f.name, CTYPES[f.ctype])
                     for f in fields])


_STAMPS = [Field("uint64_t", "timestamp"), Field("uint64_t", "timestamp_sample"),
           Field("uint32_t", "device_id")]
# PX4's msg/SensorAccel.msg and msg/SensorGyro.msg (x, y, z in m/s^2 and rad/s, temperature degC),
# msg/SensorBaro.msg (pressure Pa), in the generator's largest-first order.
SENSOR_ACCEL = padded([*_STAMPS, Field("float", "x"), Field("float", "y"), Field("float", "z"),
                       Field("float", "temperature"), Field("uint32_t", "error_count"),
                       Field("uint8_t", "clip_counter", 3), Field("uint8_t", "samples")])
SENSOR_GYRO = padded([*_STAMPS, Field("float", "x"), Field("float", "y"), Field("float", "z"),
                      Field("float", "temperature"), Field("uint32_t", "error_count"),
                      Field("uint8_t", "clip_counter", 3), Field("uint8_t", "samples")])
SENSOR_BARO = padded([*_STAMPS, Field("float", "pressure"), Field("float", "temperature"),
                      Field("uint32_t", "error_count")])


@dataclass
class Topic:
    """One logged instance of a uORB topic: its name, ``multi_id``, fields and records (a structured
    array of :func:`dtype_of` the fields; ``timestamp`` orders the data messages)."""

    name: str
    multi_id: int
    fields: list[Field]
    records: np.ndarray

    def __post_init__(self) -> None:
        want = dtype_of(self.fields)
        if self.records.dtype != want:
            raise ValueError(f"{self.name}: records of {self.records.dtype} do not match the format's {want}")
        if not 0 <= self.multi_id <= 255:
            raise ValueError(f"{self.name}: multi_id {self.multi_id} is outside 0..255")


def records(fields: Sequence[Field], n: int, **values: object) -> np.ndarray:
    """``n`` zeroed records of ``fields`` with the named columns set from ``values`` (broadcast)."""
    out = np.zeros(n, dtype_of(fields))
    for name, value in values.items():
        out[name] = value
    return out


def _message(kind: str, payload: bytes) -> bytes:
    if len(payload) > 0xFFFF:
        raise ValueError(f"a ULog '{kind}' message holds at most 65535 bytes, not {len(payload)}")
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _keyed(kind: str, key: str, value: bytes) -> bytes:
    raw = key.encode("ascii")
    return _message(kind, struct.pack("<B", len(raw)) + raw + value)


def _parameter(name: str, value: float | int) -> bytes:
    # A Python int is an int32_t parameter (PX4's INT32), anything else a float (REAL32).
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return _keyed("P", f"int32_t {name}", struct.pack("<i", int(value)))
    return _keyed("P", f"float {name}", struct.pack("<f", float(value)))


def logged_size(fields: Sequence[Field]) -> int:
    """Bytes of one ``D`` message's fields: the struct without its trailing padding (the spec: padding
    at the end of a message is not logged)."""
    size = dtype_of(fields).itemsize
    if fields and fields[-1].name.startswith("_padding"):
        size -= np.dtype(CTYPES[fields[-1].ctype]).itemsize * fields[-1].count
    return size


def _data(topics: Sequence[Topic]) -> bytes:
    """Every topic's ``D`` messages interleaved by timestamp (stable: equal times keep topic order)."""
    if not topics:
        return b""
    sizes = np.array([3 + 2 + logged_size(t.fields) for t in topics])
    which = np.concatenate([np.full(len(t.records), i) for i, t in enumerate(topics)])
    stamps = np.concatenate([t.records["timestamp"] for t in topics])
    order = np.argsort(stamps, kind="stable")
    lengths = sizes[which[order]]
    starts = np.empty(len(order), np.int64)
    starts[order] = np.concatenate([[0], np.cumsum(lengths)[:-1]])  # start of each message, input order
    out = np.zeros(int(lengths.sum()), np.uint8)
    first = 0
    for msg_id, topic in enumerate(topics):
        n, full, size = len(topic.records), topic.records.dtype.itemsize, logged_size(topic.fields)
        head = np.zeros(n, np.dtype([("size", "<u2"), ("type", "u1"), ("msg_id", "<u2")]))
        head["size"], head["type"], head["msg_id"] = size + 2, ord("D"), msg_id
        rows = np.concatenate([head.view(np.uint8).reshape(n, 5),
                               np.ascontiguousarray(topic.records).view(np.uint8).reshape(n, full)[:, :size]],
                              axis=1)
        at = starts[first:first + n]
        out[at[:, None] + np.arange(size + 5)] = rows
        first += n
    return out.tobytes()


def write_ulog(path: str | Path, topics: Sequence[Topic], params: Mapping[str, float | int] | None = None,
               info: Mapping[str, str] | None = None, start_us: int = 0,
               messages: Sequence[tuple[int, str]] = ()) -> Path:
    """Write a ULog file: header, flag bits, information, formats, parameters, subscriptions, data.

    Parameters
    ----------
    path : str or Path
    topics : sequence of Topic
        Each gets its ``F`` format (once per topic name) and an ``A`` subscription with ``msg_id``
        its index here; its records become ``D`` messages.
    params : mapping, optional
        Parameters: a Python ``int`` is written ``int32_t``, any other number ``float``.
    info : mapping, optional
        ``I`` messages, strings written as ``char[len]`` (e.g. ``sys_name``, ``ver_hw``).
    start_us : int
        The header's timestamp.
    messages : sequence of (timestamp_us, text)
        ``L`` logged strings (INFO level), written before the data.

    Returns
    -------
    Path
    """
    head = bytearray(MAGIC + struct.pack("<BQ", VERSION, int(start_us)))
    head += _message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    for key, text in (info or {}).items():
        raw = text.encode("utf-8")
        head += _keyed("I", f"char[{len(raw)}] {key}", raw)
    formats: dict[str, list[Field]] = {}
    for topic in topics:
        known = formats.setdefault(topic.name, topic.fields)
        if known != topic.fields:
            raise ValueError(f"topic {topic.name} is given two different formats")
    for name, fields in formats.items():
        head += _message("F", f"{name}:{''.join(f.text() + ';' for f in fields)}".encode("ascii"))
    for name, value in (params or {}).items():
        head += _parameter(name, value)
    for msg_id, topic in enumerate(topics):
        head += _message("A", struct.pack("<BH", topic.multi_id, msg_id) + topic.name.encode("ascii"))
    for stamp, text in messages:
        head += _message("L", struct.pack("<BQ", LOG_LEVEL_INFO, int(stamp)) + text.encode("utf-8"))
    path = Path(path)
    with open(path, "wb") as f:
        f.write(bytes(head))
        f.write(_data(topics))
    return path
