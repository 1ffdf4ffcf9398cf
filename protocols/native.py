"""Native serial protocol, version 1 (``shared/specs/native-protocol.md``).

Frame: sync ``A5 5A`` | id u8 | length u16 | payload | CRC-16/CCITT-FALSE over id, length
and payload, all little-endian. The decoder takes a fast vectorised path over runs of
well-formed sample frames and a per-frame path for everything else (other messages,
errors and resynchronisation). IMU_MAG_SAMPLE frames (a unit with a magnetometer) take a
vectorised path of their own.
"""

from __future__ import annotations

import json
import struct
from bisect import bisect_left
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.base import (
    EMPTY_SAMPLES,
    MAG_SAMPLE_DTYPE,
    SAMPLE_DTYPE,
    Decoded,
    Message,
    StreamDecoderBase,
    has_mag,
)
from protocols.crc import crc16_ccitt_false, crc16_rows
from protocols.mag_batches import join_batches, with_mag

SYNC = b"\xa5\x5a"
HEADER_SIZE = 5  # sync, id, length
CRC_SIZE = 2
MAX_PAYLOAD = 1024

IMU_SAMPLE = 0x01
DEVICE_INFO = 0x02
ACK = 0x03
IMU_MAG_SAMPLE = 0x04
GET_INFO = 0x10
SET_RATE = 0x11
START_STREAM = 0x12
STOP_STREAM = 0x13
RESTART = 0x14

KNOWN_IDS = {IMU_SAMPLE, DEVICE_INFO, ACK, IMU_MAG_SAMPLE, GET_INFO, SET_RATE, START_STREAM, STOP_STREAM,
             RESTART}
COMMAND_IDS = {GET_INFO, SET_RATE, START_STREAM, STOP_STREAM, RESTART}

ACK_OK = 0
ACK_UNKNOWN = 1
ACK_BAD_ARGUMENT = 2
ACK_BUSY = 3
ACK_STATUS_NAMES = {ACK_OK: "ok", ACK_UNKNOWN: "unknown command", ACK_BAD_ARGUMENT: "bad argument",
                    ACK_BUSY: "busy"}

SAMPLE_PAYLOAD_SIZE = SAMPLE_DTYPE.itemsize  # 40
SAMPLE_FRAME_SIZE = HEADER_SIZE + SAMPLE_PAYLOAD_SIZE + CRC_SIZE  # 47

# A whole sample frame as one record, so a buffer of back-to-back frames is viewed, not parsed.
SAMPLE_FRAME_DTYPE = np.dtype(
    [("sync", "<u2"), ("msg_id", "u1"), ("length", "<u2"), ("payload", SAMPLE_DTYPE), ("crc", "<u2")]
)
assert SAMPLE_FRAME_DTYPE.itemsize == SAMPLE_FRAME_SIZE
_SYNC_U16 = int.from_bytes(SYNC, "little")

# IMU_MAG_SAMPLE: the 40 bytes of IMU_SAMPLE, then the field (f32 mx, my, mz in uT).
MAG_PAYLOAD_SIZE = MAG_SAMPLE_DTYPE.itemsize  # 52
MAG_FRAME_SIZE = HEADER_SIZE + MAG_PAYLOAD_SIZE + CRC_SIZE  # 59
MAG_FRAME_DTYPE = np.dtype(
    [("sync", "<u2"), ("msg_id", "u1"), ("length", "<u2"), ("payload", MAG_SAMPLE_DTYPE), ("crc", "<u2")]
)
assert MAG_FRAME_DTYPE.itemsize == MAG_FRAME_SIZE


def encode_frame(msg_id: int, payload: bytes = b"") -> bytes:
    """One frame: sync, id, length, payload and CRC."""
    if not 0 <= msg_id <= 0xFF:
        raise ValueError(f"message id {msg_id} is not a byte")
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD}-byte limit")
    body = bytes([msg_id]) + struct.pack("<H", len(payload)) + payload
    return SYNC + body + struct.pack("<H", crc16_ccitt_false(body))


def encode_samples(samples: np.ndarray) -> bytes:
    """Sample frames for a batch of records, back to back (vectorised): IMU_SAMPLE for
    ``SAMPLE_DTYPE``, IMU_MAG_SAMPLE for ``MAG_SAMPLE_DTYPE`` (a unit with a magnetometer)."""
    layout = _MAG if has_mag(samples) else _IMU
    samples = np.ascontiguousarray(samples, dtype=layout.frame["payload"])
    frames = np.zeros(len(samples), dtype=layout.frame)
    frames["sync"] = _SYNC_U16
    frames["msg_id"] = layout.msg_id
    frames["length"] = layout.payload_size
    frames["payload"] = samples
    rows = frames.view(np.uint8).reshape(len(samples), layout.frame.itemsize)
    frames["crc"] = crc16_rows(rows[:, 2 : HEADER_SIZE + layout.payload_size])
    return frames.tobytes()


def encode_device_info(info: dict[str, Any]) -> bytes:
    """A DEVICE_INFO frame: ``info`` as compact JSON."""
    return encode_frame(DEVICE_INFO, json.dumps(info, separators=(",", ":")).encode("utf-8"))


def encode_ack(command_id: int, status: int = ACK_OK) -> bytes:
    """An ACK frame answering ``command_id`` with ``status`` (``ACK_OK`` or an error status)."""
    return encode_frame(ACK, bytes([command_id, status]))


def encode_set_rate(rate_hz: int) -> bytes:
    """A SET_RATE command frame; ``ValueError`` if ``rate_hz`` does not fit its u16."""
    if not 1 <= rate_hz <= 0xFFFF:
        raise ValueError(f"rate {rate_hz} Hz does not fit the u16 of SET_RATE")
    return encode_frame(SET_RATE, struct.pack("<H", rate_hz))


@dataclass(frozen=True)
class Ack:
    """An ACK's payload: the command it answers and its status (``ACK_OK`` or an error)."""

    command_id: int
    status: int

    @property
    def ok(self) -> bool:
        """True when the command was accepted."""
        return self.status == ACK_OK


def parse_ack(payload: bytes) -> Ack:
    """The :class:`Ack` in an ACK payload; ``ValueError`` unless it has 2 bytes."""
    if len(payload) != 2:
        raise ValueError(f"ACK payload has {len(payload)} bytes, expected 2")
    return Ack(payload[0], payload[1])


def parse_device_info(payload: bytes) -> dict[str, Any]:
    """The unit's identity from a DEVICE_INFO payload; ``ValueError`` unless it is a JSON object."""
    info = json.loads(payload.decode("utf-8"))
    if not isinstance(info, dict):
        raise ValueError("DEVICE_INFO payload is not a JSON object")
    return info


# Frames the vectorised path checks per call. After a damaged frame the next call re-checks at most
# this many, so a stream with errors costs little more than a clean one.
_SAMPLE_WINDOW = 256


def _sample_crc_tables(msg_id: int = IMU_SAMPLE,
                       payload_size: int = SAMPLE_PAYLOAD_SIZE) -> tuple[int, np.ndarray]:
    """CRC-16/CCITT-FALSE of a sample frame as a sum of per-byte tables.

    The CRC is affine in the message bits: crc(H + P) = crc(H + 0^40) ^ XOR_i T[i, P_i], where
    T[i, v] = crc(0^3 + e_i(v)) ^ crc(0^43) and e_i(v) puts byte v at payload position i. So a
    frame's CRC is 40 table look-ups and XORs, done for all frames at once (52 for IMU_MAG_SAMPLE).
    """
    body = HEADER_SIZE - 2 + payload_size  # id, length and payload: the bytes under the CRC
    header = np.frombuffer(bytes([msg_id]) + struct.pack("<H", payload_size), dtype=np.uint8)
    zero = np.zeros((1, body), dtype=np.uint8)
    rows = np.zeros((payload_size, 256, body), dtype=np.uint8)
    for i in range(payload_size):
        rows[i, :, 3 + i] = np.arange(256)
    tables = crc16_rows(rows.reshape(-1, body)).reshape(payload_size, 256) ^ crc16_rows(zero)[0]
    with_header = zero.copy()
    with_header[0, :3] = header
    return int(crc16_rows(with_header)[0]), tables


_SAMPLE_CRC_BASE, _SAMPLE_CRC_TABLES = _sample_crc_tables()
_SAMPLE_CRC_FLAT = _SAMPLE_CRC_TABLES.ravel()
_TABLE_OFFSETS = (np.arange(SAMPLE_PAYLOAD_SIZE) * 256).astype(np.uint16)  # row i of the flat table


@dataclass(frozen=True)
class _Layout:
    """One sample message for the vectorised path: its id, frame record and CRC tables."""

    msg_id: int
    payload_size: int
    frame: np.dtype
    crc_base: int
    crc_flat: np.ndarray
    offsets: np.ndarray


def _mag_layout() -> _Layout:
    base, tables = _sample_crc_tables(IMU_MAG_SAMPLE, MAG_PAYLOAD_SIZE)
    return _Layout(IMU_MAG_SAMPLE, MAG_PAYLOAD_SIZE, MAG_FRAME_DTYPE, base, tables.ravel(),
                   (np.arange(MAG_PAYLOAD_SIZE) * 256).astype(np.uint16))


_IMU = _Layout(IMU_SAMPLE, SAMPLE_PAYLOAD_SIZE, SAMPLE_FRAME_DTYPE, _SAMPLE_CRC_BASE, _SAMPLE_CRC_FLAT,
               _TABLE_OFFSETS)
_MAG = _mag_layout()
_EMPTY_MAG = np.zeros(0, MAG_SAMPLE_DTYPE)


def decode_sample_frames(buf: bytes | bytearray | memoryview) -> tuple[np.ndarray, int]:
    """Vectorised decode of back-to-back sample frames at the start of ``buf``.

    Returns the samples of the longest prefix of valid sample frames (up to a window of
    frames per call) and the number of bytes they span. Stops at the first frame that is not
    a valid IMU_SAMPLE (other message, bad CRC, garbage); the caller handles what follows.
    """
    return _decode_frames(buf, _IMU)


def decode_mag_frames(buf: bytes | bytearray | memoryview) -> tuple[np.ndarray, int]:
    """:func:`decode_sample_frames` for IMU_MAG_SAMPLE frames: ``MAG_SAMPLE_DTYPE`` records."""
    return _decode_frames(buf, _MAG)


def _decode_frames(buf: bytes | bytearray | memoryview, layout: _Layout) -> tuple[np.ndarray, int]:
    size = layout.frame.itemsize
    empty = _EMPTY_MAG if layout is _MAG else EMPTY_SAMPLES
    count = min(len(buf) // size, _SAMPLE_WINDOW)
    if count == 0:
        return empty, 0
    frames = np.frombuffer(buf, dtype=layout.frame, count=count)
    ok = (frames["sync"] == _SYNC_U16) & (frames["msg_id"] == layout.msg_id)
    ok &= frames["length"] == layout.payload_size
    n_ok = count if ok.all() else int(np.argmin(ok))
    if n_ok == 0:
        return empty, 0
    rows = np.frombuffer(buf, dtype=np.uint8, count=n_ok * size).reshape(n_ok, size)
    payload = rows[:, HEADER_SIZE : HEADER_SIZE + layout.payload_size]
    crc = np.bitwise_xor.reduce(layout.crc_flat[payload + layout.offsets], axis=1) ^ layout.crc_base
    crc_ok = crc == frames["crc"][:n_ok]
    if not crc_ok.all():
        n_ok = int(np.argmin(crc_ok))
    return frames["payload"][:n_ok].copy(), n_ok * size


class _Window:
    """Up to ``_SAMPLE_WINDOW`` frame slots from ``base`` checked at once: which are good sample frames.

    Slots up to ``checked`` have a sample frame's header (sync, id, length); ``bad`` lists those
    among them whose CRC is wrong. A run of good frames starting at any checked slot is then a
    slice, and a damaged frame's CRC is not computed again.
    """

    __slots__ = ("base", "layout", "frames", "checked", "bad")

    def __init__(self, base: int, layout: _Layout, frames: np.ndarray | None, checked: int,
                 bad: list[int]) -> None:
        self.base, self.layout, self.frames, self.checked, self.bad = base, layout, frames, checked, bad

    @classmethod
    def check(cls, buf: bytearray, pos: int, layout: _Layout) -> _Window:
        size = layout.frame.itemsize
        count = min((len(buf) - pos) // size, _SAMPLE_WINDOW)
        # No sample frame's header at pos (a false start, another message): no window, without numpy.
        length = buf[pos + 3] | buf[pos + 4] << 8 if count else 0
        if count == 0 or buf[pos + 2] != layout.msg_id or length != layout.payload_size:
            return cls(pos, layout, None, 0, _NO_BAD)
        frames = np.frombuffer(buf, dtype=layout.frame, count=count, offset=pos)
        ok = (frames["sync"] == _SYNC_U16) & (frames["msg_id"] == layout.msg_id)
        ok &= frames["length"] == layout.payload_size
        checked = count if ok.all() else int(np.argmin(ok))
        if checked == 0:
            return cls(pos, layout, None, 0, _NO_BAD)
        rows = np.frombuffer(buf, dtype=np.uint8, count=checked * size, offset=pos).reshape(checked, size)
        payload = rows[:, HEADER_SIZE : HEADER_SIZE + layout.payload_size]
        crc = np.bitwise_xor.reduce(layout.crc_flat[payload + layout.offsets], axis=1) ^ layout.crc_base
        crc_ok = crc == frames["crc"][:checked]
        bad = _NO_BAD if crc_ok.all() else np.flatnonzero(~crc_ok).tolist()
        return cls(pos, layout, frames, checked, bad)

    @property
    def valid(self) -> bool:
        """Whether the first slot holds a good sample frame."""
        return self.checked > 0 and not (len(self.bad) and self.bad[0] == 0)

    def covers(self, pos: int) -> bool:
        """Whether ``pos`` is a checked slot of this window."""
        off, size = pos - self.base, self.layout.frame.itemsize
        return off >= 0 and off % size == 0 and off // size < self.checked

    def _slot(self, pos: int) -> int:
        return (pos - self.base) // self.layout.frame.itemsize

    def run(self, pos: int) -> tuple[np.ndarray, int]:
        """The samples of the good frames from slot ``pos`` on (a view of the buffer), the bytes they span."""
        if self.frames is None or not self.covers(pos):
            return (_EMPTY_MAG if self.layout is _MAG else EMPTY_SAMPLES), 0
        i = self._slot(pos)
        bad = self.bad
        j = self.checked
        if bad:
            k = bisect_left(bad, i)
            if k < len(bad):
                j = bad[k]
        return self.frames["payload"][i:j], (j - i) * self.layout.frame.itemsize

    def bad_crc(self, pos: int) -> bool:
        """Whether ``pos`` is a checked slot whose frame's CRC is wrong."""
        if not self.bad or not self.covers(pos):
            return False
        i = self._slot(pos)
        k = bisect_left(self.bad, i)
        return k < len(self.bad) and self.bad[k] == i


_NO_BAD: list[int] = []


class NativeDecoder(StreamDecoderBase):
    """Incremental decoder of the native protocol.

    After a bad CRC, an invalid length or a truncated frame it drops the bytes up to the next
    sync candidate after the one it tried, counts the error and goes on, so a good frame that
    follows garbage is never lost. From the first IMU_MAG_SAMPLE on, every batch it returns is
    ``MAG_SAMPLE_DTYPE`` (an IMU_SAMPLE among them has a NaN field), so the batches of one stream
    always join.
    """

    name = "native"
    _mag = False  # an IMU_MAG_SAMPLE was seen: batches are MAG_SAMPLE_DTYPE from then on

    def feed(self, data: bytes) -> Decoded:
        """Decode ``data`` after what is buffered (``StreamDecoderBase.feed``)."""
        buf = self._buf
        buf += data
        batches: list[np.ndarray] = []
        messages: list[Message] = []
        pos = 0
        stats = self.stats
        window: _Window | None = None
        while True:
            pos, found = self._seek_sync(SYNC, pos)
            if not found:
                break
            # A window checked once serves every run in it: after a damaged frame the next frame
            # start is usually the next slot of the window, so nothing is checked twice.
            if window is None or not window.covers(pos):
                window = None  # its view of the buffer goes before a new one is taken
                window = _Window.check(buf, pos, _IMU)
                if not window.valid and len(buf) - pos > 2 and buf[pos + 2] == IMU_MAG_SAMPLE:
                    window = _Window.check(buf, pos, _MAG)
            samples, used = window.run(pos)
            if used:
                self._mag = self._mag or window.layout is _MAG
                batches.append(samples)
                pos += used
                continue
            if len(buf) - pos < HEADER_SIZE:
                break
            msg_id = buf[pos + 2]
            length = buf[pos + 3] | (buf[pos + 4] << 8)
            if length > MAX_PAYLOAD:
                stats.length_errors += 1
                pos = self._skip_candidate(SYNC, pos)
                continue
            end = pos + HEADER_SIZE + length + CRC_SIZE
            if len(buf) < end:
                break
            if window.bad_crc(pos):  # a sample frame whose CRC the window found wrong
                crc_good = False
            else:
                body = bytes(buf[pos + 2 : pos + HEADER_SIZE + length])
                crc_good = crc16_ccitt_false(body) == buf[end - 2] | (buf[end - 1] << 8)
            if not crc_good:
                # A sync inside the claimed frame means this one was cut short by the next.
                if buf.find(SYNC, pos + 1, end) >= 0:
                    stats.truncated += 1
                else:
                    stats.crc_errors += 1
                pos = self._skip_candidate(SYNC, pos)
                continue
            if msg_id in (IMU_SAMPLE, IMU_MAG_SAMPLE):
                # A sample frame with a good CRC but a wrong length: the vectorised path refused it.
                stats.bad_payloads += 1
                pos = end
                continue
            stats.frames += 1
            if msg_id not in KNOWN_IDS:
                stats.unknown_ids += 1
            messages.append(Message(msg_id, bytes(buf[pos + HEADER_SIZE : pos + HEADER_SIZE + length])))
            pos = end
        # The batches are views of the buffer: copied out (joined) before the buffer is cut.
        if self._mag:
            samples = self._joined(batches)
            if len(batches) == 1 and samples is batches[0]:
                samples = samples.copy()
        elif len(batches) == 1:  # a six-axis stream: IMU_SAMPLE records only
            samples = batches[0].copy()
        elif batches:  # joined as raw records: numpy's structured concatenate costs more
            void = np.dtype((np.void, SAMPLE_DTYPE.itemsize))
            samples = np.concatenate([b.view(void) for b in batches]).view(SAMPLE_DTYPE)
        else:
            samples = EMPTY_SAMPLES
        batches.clear()
        window = None  # releases the buffer before it is cut
        if pos:
            del buf[:pos]
        stats.frames += len(samples)
        stats.samples += len(samples)
        return Decoded(samples, messages)

    def flush(self) -> Decoded:
        """End of stream: a frame still waiting for bytes is truncated, and good frames after it
        (held back while its claimed length was pending) are still decoded and returned."""
        batches: list[np.ndarray] = []
        messages: list[Message] = []
        while self._buf:
            if not self._buf.startswith(SYNC):
                self.stats.garbage_bytes += len(self._buf)
                self._buf.clear()
                break
            self.stats.truncated += 1
            del self._buf[: self._skip_candidate(SYNC, 0)]
            rest = self.feed(b"")
            batches.append(rest.samples)
            messages += rest.messages
        return Decoded(self._joined(batches), messages)

    def _joined(self, batches: list[np.ndarray]) -> np.ndarray:
        """The batches as one, widened to ``MAG_SAMPLE_DTYPE`` once the stream carried a field."""
        samples = join_batches(batches)
        if has_mag(samples):
            self._mag = True
        return with_mag(samples) if self._mag else samples
