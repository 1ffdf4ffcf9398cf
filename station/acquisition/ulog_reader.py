"""PX4 ULog files decoded into numpy structured arrays: parameters, info, dropouts and chosen topics.

The format (PX4 ``docs/en/dev_log/ulog_file_format.md``): a 16-byte header (``ULog`` 0x01 0x12 0x35,
version, uint64 start time), then messages, each a 3-byte header (uint16 size of what follows, uint8
type) and its payload. The definitions (``F`` formats ``name:type field;...``, ``P`` parameters, ``I``
info, ``B`` flag bits) come first; the data section holds ``A`` subscriptions (uint8 multi_id, uint16
msg_id, name) and ``D`` data (uint16 msg_id, then the fields packed without alignment, the trailing
padding left out), with ``L``/``C`` logging, ``O`` dropouts, ``S`` sync and changed ``P`` between them.

Every message must be found in order (each header gives the next one's offset), so one compiled loop
walks the headers (numba: a few ns a message, where per-message Python costs about 1 us) and records
where each is; a topic's ``D`` payloads are then copied into one array and viewed with the numpy dtype
built from its format, so fields come out as the logger wrote them, bit for bit what pyulog reads.
Where a message has an unknown type (a corrupt stretch) the walk resumes after the next sync magic, as
pyulog does; a message cut by the end of the file ends the walk.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from station.errors import InputFileError

MAGIC = b"ULog\x01\x12\x35"
SYNC_MAGIC = bytes([0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x12])
HEADER_BYTES = 16
# message types of the format: B F I M P Q A R D L C S O
KNOWN_TYPES = b"BFIMPQARDLCSO"
D = ord("D")
NO_ID = 0xFFFF
WALK_ROWS = 1 << 20

BASE_TYPES = {"int8_t": "i1", "uint8_t": "u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4",
              "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8",
              "bool": "i1", "char": "S1"}  # bool as a byte 0/1, as pyulog gives it


@dataclass
class UlogData:
    """What :func:`read_ulog` found: the chosen topics as structured arrays keyed by (name, multi_id)."""

    path: Path
    topics: dict[tuple[str, int], np.ndarray]
    params: dict[str, float]
    info: dict[str, object]
    dropouts: list[tuple[int, int]] = field(default_factory=list)  # (timestamp us before it, duration ms)
    corrupt_bytes: int = 0
    truncated: bool = False
    short_messages: int = 0  # data messages shorter than their format: skipped
    subscriptions: list[tuple[str, int]] = field(default_factory=list)  # every topic of the log


def is_ulog(path: str | Path) -> bool:
    """Whether the file starts with the ULog magic.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _walk_kernel():
    """The compiled header walk (numba loads here, when a ULog is read, not at import)."""
    import numba

    @numba.njit(nogil=True, cache=True, boundscheck=False)
    def walk(buf, start, valid, pos_out, type_out, id_out):  # pragma: no cover - compiled
        # status: 0 end of file, 1 unknown type at p, 2 message cut by the end at p, 3 output full
        n = 0
        p = start
        end = len(buf)
        cap = len(pos_out)
        while p + 3 <= end:
            size = np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8)
            kind = buf[p + 2]
            if not valid[kind]:
                return n, p, 1
            if p + 3 + size > end:
                return n, p, 2
            pos_out[n] = p
            type_out[n] = kind
            if kind == 68 and size >= 2:
                id_out[n] = np.int64(buf[p + 3]) | (np.int64(buf[p + 4]) << 8)
            else:
                id_out[n] = 0xFFFF
            n += 1
            p += 3 + size
            if n == cap:
                return n, p, 3
        return n, p, 0

    @numba.njit(nogil=True, cache=True, boundscheck=False)
    def gather(buf, starts, width, out):  # pragma: no cover - compiled
        for i in range(len(starts)):
            s = starts[i]
            for j in range(width):
                out[i, j] = buf[s + j]

    @numba.njit(nogil=True, cache=True, boundscheck=False)
    def scatter(buf, pos, ids, slot_of, widths, bases, rows, out):  # pragma: no cover - compiled
        # one pass over the data messages in file order, each payload appended to its topic's rows
        short = 0
        for k in range(len(pos)):
            msg_id = ids[k]
            if msg_id == 0xFFFF:
                continue
            slot = slot_of[msg_id]
            if slot < 0:
                continue
            p = pos[k]
            size = np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8)
            width = widths[slot]
            if size - 2 < width:
                short += 1
                continue
            at = bases[slot] + rows[slot] * width
            for j in range(width):
                out[at + j] = buf[p + 5 + j]
            rows[slot] += 1
        return short

    return walk, gather, scatter


_KERNELS: tuple | None = None


def _kernels():
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = _walk_kernel()
    return _KERNELS


def gather_rows(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """Rows of ``width`` bytes of ``buf`` from each offset in ``starts``, as one (n, width) array.

    Parameters
    ----------
    buf : ndarray of uint8
        The file's bytes.
    starts : ndarray of int64
        Where each row begins; every row must lie within ``buf``.
    width : int
        Bytes per row.

    Returns
    -------
    ndarray of uint8, (len(starts), width), C-contiguous (view it with the rows' dtype).
    """
    _, gather, _ = _kernels()
    out = np.empty((len(starts), width), np.uint8)
    gather(buf, np.ascontiguousarray(starts, dtype=np.int64), width, out)
    return out


def _walk(buf: np.ndarray, start: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool]:
    """Every message's offset, type and (``D``) msg_id from ``start``; bytes skipped as corrupt; cut end."""
    walk, _, _ = _kernels()
    valid = np.zeros(256, np.bool_)
    valid[np.frombuffer(KNOWN_TYPES, np.uint8)] = True
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    p, corrupt, truncated = start, 0, False
    while True:
        pos = np.empty(WALK_ROWS, np.int64)
        kind = np.empty(WALK_ROWS, np.uint8)
        ids = np.empty(WALK_ROWS, np.int64)
        n, p, status = walk(buf, p, valid, pos, kind, ids)
        parts.append((pos[:n], kind[:n], ids[:n]))
        if status == 3:
            continue
        if status == 1:  # a corrupt stretch: go on after the next sync message, as pyulog does
            found = buf[p:].tobytes().find(SYNC_MAGIC)
            if found < 0:
                corrupt += len(buf) - p
                break
            corrupt += found
            p += found + len(SYNC_MAGIC)
            continue
        truncated = status == 2
        break
    return (np.concatenate([a for a, _, _ in parts]), np.concatenate([b for _, b, _ in parts]),
            np.concatenate([c for _, _, c in parts]), corrupt, truncated)


def _parse_format(text: str) -> tuple[str, list[tuple[str, str, int]]]:
    """``name:type field;type[n] field;...`` as (name, [(type, field, count or 0)])."""
    name, _, body = text.partition(":")
    fields = []
    for item in body.split(";"):
        item = item.strip()
        if not item:
            continue
        kind, _, fname = item.rpartition(" ")
        count = 0
        if kind.endswith("]"):
            kind, _, n = kind[:-1].partition("[")
            count = int(n)
        fields.append((kind, fname, count))
    return name, fields


def _layout(name: str, formats: dict[str, list[tuple[str, str, int]]], prefix: str = "",
            seen: tuple[str, ...] = ()) -> tuple[list[tuple[str, str, int]], int]:
    """Flattened (field name as pyulog names it, numpy type, offset) of a format and its size in bytes;
    padding fields keep their bytes but no name."""
    if name in seen:
        raise ValueError(f"format {name!r} contains itself")
    out: list[tuple[str, str, int]] = []
    offset = 0
    for kind, fname, count in formats[name]:
        for k in range(max(count, 1)):
            label = f"{prefix}{fname}" + (f"[{k}]" if count else "")
            if kind in BASE_TYPES:
                size = np.dtype(BASE_TYPES[kind]).itemsize
                if not fname.startswith("_padding"):
                    out.append((label, BASE_TYPES[kind], offset))
            elif kind in formats:
                inner, size = _layout(kind, formats, label + ".", (*seen, name))
                out += [(n, t, offset + o) for n, t, o in inner]
            else:
                raise ValueError(f"field {fname!r} of {name!r} has the unknown type {kind!r}")
            offset += size
    return out, offset


def topic_dtype(name: str, formats: dict[str, list[tuple[str, str, int]]]) -> np.dtype:
    """The numpy dtype of a topic's data payload (after msg_id), ending at its last field that is not
    padding: the logger leaves trailing padding out.

    Parameters
    ----------
    name : str
        The format's name.
    formats : dict
        Every ``F`` message as :func:`_parse_format` returns it, by name.

    Returns
    -------
    numpy.dtype
    """
    fields, _ = _layout(name, formats)
    width = max((o + np.dtype(t).itemsize for _, t, o in fields), default=0)
    return np.dtype({"names": [n for n, _, _ in fields], "formats": [t for _, t, _ in fields],
                     "offsets": [o for _, _, o in fields], "itemsize": width})


_VALUE = {"int32_t": "<i", "float": "<f", "uint32_t": "<I", "int8_t": "<b", "uint8_t": "<B", "int16_t": "<h",
          "uint16_t": "<H", "int64_t": "<q", "uint64_t": "<Q", "double": "<d", "bool": "<?"}


def _key_value(payload: bytes) -> tuple[str, object]:
    """An ``I`` or ``P`` message's (name, value): ``uint8 key_len, key 'type name', value``."""
    n = payload[0]
    kind, _, name = payload[1:1 + n].decode("utf-8", "replace").rpartition(" ")
    raw = payload[1 + n:]
    if kind.startswith("char"):
        return name, raw.decode("utf-8", "replace").rstrip("\x00")
    if kind in _VALUE:
        return name, struct.unpack_from(_VALUE[kind], raw)[0]
    return name, raw


def read_ulog(path: str | Path, topics: Iterable[str] | None = ("sensor_accel", "sensor_gyro", "sensor_mag")
              ) -> UlogData:
    """Decode a ULog: its initial parameters, info, dropouts and the data of ``topics``.

    Parameters
    ----------
    path : str or Path
    topics : iterable of str, optional
        Topic names whose data to decode (every instance); None decodes all.

    Returns
    -------
    UlogData

    Raises
    ------
    InputFileError
        Not a ULog, or a definition that cannot be read.
    """
    path = Path(path)
    try:
        buf = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputFileError(path, f"cannot be read ({exc.strerror or exc})") from None
    if buf[:len(MAGIC)].tobytes() != MAGIC:
        raise InputFileError(path, "is not a PX4 ULog (it does not start with the ULog magic bytes); give "
                             "the .ulg the vehicle's logger wrote")
    pos, kind, ids, corrupt, truncated = _walk(buf, HEADER_BYTES)
    raw = buf.data
    formats: dict[str, list[tuple[str, str, int]]] = {}
    params: dict[str, float] = {}
    info: dict[str, object] = {}
    subs: dict[int, tuple[str, int]] = {}
    subscriptions: list[tuple[str, int]] = []
    dropouts: list[tuple[int, int]] = []
    in_data = False
    data_pos = pos[kind == D]
    # the few messages that are not data, in order (D messages are gathered below, per topic)
    for i in np.flatnonzero(kind != D):
        p = int(pos[i])
        size = int(buf[p]) | int(buf[p + 1]) << 8
        payload = bytes(raw[p + 3:p + 3 + size])
        letter = chr(kind[i])
        try:
            if letter == "F":
                name, fields = _parse_format(payload.decode("utf-8", "replace"))
                formats[name] = fields
            elif letter == "P" and not in_data:
                name, value = _key_value(payload)
                if isinstance(value, int | float):
                    params[name] = value
            elif letter == "I":
                name, value = _key_value(payload)
                info[name] = value
            elif letter == "A":
                in_data = True
                multi_id, msg_id = struct.unpack_from("<BH", payload)
                subs[msg_id] = (payload[3:].decode("utf-8", "replace"), multi_id)
                subscriptions.append(subs[msg_id])
            elif letter == "O":
                # the time of the data message before it: where in the record the samples went missing
                before = int(np.searchsorted(data_pos, p)) - 1
                last_time = struct.unpack_from("<Q", raw, int(data_pos[before]) + 5)[0] if before >= 0 else 0
                dropouts.append((last_time, struct.unpack_from("<H", payload)[0]))
        except (struct.error, ValueError, IndexError) as exc:
            raise InputFileError(path, f"its '{letter}' message at byte {p} cannot be read ({exc}); the log "
                                 "is damaged") from None
    wanted = None if topics is None else set(topics)
    chosen: list[tuple[int, tuple[str, int], np.dtype]] = []
    for msg_id, (name, multi_id) in subs.items():
        if (wanted is not None and name not in wanted) or name not in formats:
            continue
        try:
            chosen.append((msg_id, (name, multi_id), topic_dtype(name, formats)))
        except ValueError as exc:
            raise InputFileError(path, f"the format of topic {name!r} cannot be read: {exc}") from None
    # every chosen topic's payloads copied in one pass over the file, into one buffer cut per topic
    slot_of = np.full(1 << 16, -1, np.int64)
    for slot, (msg_id, _, _) in enumerate(chosen):
        slot_of[msg_id] = slot
    data_ids = ids[kind == D]
    counts = np.bincount(slot_of[data_ids][slot_of[data_ids] >= 0], minlength=len(chosen))
    widths = np.array([dtype.itemsize for _, _, dtype in chosen], np.int64)
    bases = np.concatenate([[0], np.cumsum(counts * widths)])
    rows = np.zeros(len(chosen), np.int64)
    block = np.empty(int(bases[-1]), np.uint8)
    _, _, scatter = _kernels()
    short = int(scatter(buf, pos, ids, slot_of, widths, bases[:-1].astype(np.int64), rows, block))
    out: dict[tuple[str, int], np.ndarray] = {}
    for slot, (_, key, dtype) in enumerate(chosen):
        n = int(rows[slot])
        if n == 0:  # subscribed, never logged: absent, as pyulog has it
            continue
        part = block[bases[slot]:bases[slot] + n * dtype.itemsize]
        out[key] = part.view(dtype) if dtype.itemsize else np.zeros(n, dtype)
    return UlogData(path, out, params, info, dropouts, corrupt, truncated, short, subscriptions)
