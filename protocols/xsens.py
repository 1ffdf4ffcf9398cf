"""Xsens Xbus framing and MTData2 measurement packets (MTi 1/10/100/600-series, MTi-G).

Xbus frame: preamble ``FA`` | bus id ``FF`` | message id | length u8 (``FF`` announces the
extended form: a u16 big-endian length follows) | payload | checksum, chosen so that the byte
sum from the bus id through the checksum is zero modulo 256.

MTData2 (message id ``0x36``) is a list of data items: data id u16 | size u8 | data, all
big-endian. The low two bits of a data id give the precision (float32, fixed point 12.20,
fixed point 16.32, float64), bits 2-3 the coordinate system of orientation and velocity items
(ENU, NED, NWU), the rest the data type. The station keeps the inertial items in the **sensor
frame**: Acceleration, DeltaV, RateOfTurn and DeltaQ are sensor-frame quantities in the Xsens
definition, and the coordinate-system bits, which only rotate orientation and velocity
outputs, are accepted and ignored for them. (A device-side alignment rotation, if one was set,
does rotate them: reset it before calibrating.)

A packet becomes one sample when it carries Acceleration (or DeltaV) or RateOfTurn (or DeltaQ);
a triad the packet lacks is NaN. The high-rate AccelerationHR / RateOfTurnHR come in packets of
their own: the first kind of inertial packet seen (or ``source``: ``normal`` or ``hr``) makes
the samples, the other kind is returned as messages, so two rates never mix. DeltaV and DeltaQ
are turned into mean acceleration and rate over the interval between consecutive inertial
packets (from SampleTimeFine). Packets without inertial data (GNSS, orientation only, status)
are returned as messages, not errors. ``seq`` is the PacketCounter unwrapped past 65535 (a
packet without a counter takes the next number); packets that are not samples (GNSS-only,
the other rate) consume counter values too: they show as gaps in ``seq`` and are counted in
``stats.seq_skipped``, which the link statistics take off their ``lost``. ``t_us`` is the
unwrapped SampleTimeFine (10 kHz ticks) in microseconds; ``temp`` is the last Temperature item
seen (NaN before the first).

MagneticField is **normalised**: an MTi reports the field in arbitrary units (a.u.), 1.0 being the
magnitude of the field where the unit's magnetometer was last calibrated (by Xsens, or by the
user's Magnetic Field Mapper), not microtesla. With ``field_ut`` (``--field UT``, or the protocol
option ``xsens:field=UT``: the local field magnitude) the decoder scales it to microtesla and
returns ``MAG_SAMPLE_DTYPE`` batches from the first packet that carries one on (NaN in samples
whose packet has none); without, the field is left out and the packets that carried one are
counted in ``mag_unscaled``. In all four precisions, like the inertial items.

Why this module is long: the MTData2 data identifiers (the table of item names, formats
and precisions), the decoder and the encoder the simulated unit uses are one protocol's reference;
the table is a third of it, and the decoder and encoder must agree on it line for line. The
decoder's vectorised path for runs of like packets sits beside the per-packet path whose results it
must equal.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.base import (
    MAG_SAMPLE_DTYPE,
    SAMPLE_DTYPE,
    Decoded,
    Message,
    StreamDecoderBase,
    has_mag,
)
from protocols.mag_batches import join_batches, rows_to_batch, with_mag

SYNC = b"\xfa\xff"
PREAMBLE = 0xFA
BUS_ID = 0xFF
EXTENDED_LENGTH = 0xFF
MAX_PAYLOAD = 2048  # the largest extended-length message an MTi sends

MID_MTDATA2 = 0x36
MESSAGE_NAMES = {
    0x00: "ReqDID", 0x01: "DeviceID", 0x10: "GoToMeasurement", 0x11: "GoToMeasurementAck",
    0x12: "ReqFWRev", 0x13: "FirmwareRev", 0x18: "SetBaudrate", 0x19: "SetBaudrateAck",
    0x1C: "ReqProductCode", 0x1D: "ProductCode", 0x30: "GoToConfig", 0x31: "GoToConfigAck",
    0x32: "MTData", 0x34: "ReqData", 0x36: "MTData2", 0x3E: "WakeUp", 0x3F: "WakeUpAck",
    0x40: "Reset", 0x41: "ResetAck", 0x42: "Error", 0x43: "Warning",
    0xC0: "SetOutputConfiguration", 0xC1: "OutputConfiguration",
}

TYPE_MASK = 0xF8F0
COORD_MASK = 0x000C
PRECISION_MASK = 0x0003

FLOAT32, FP1220, FP1632, FLOAT64 = 0, 1, 2, 3
PRECISIONS = {"float32": FLOAT32, "fp1220": FP1220, "fp1632": FP1632, "float64": FLOAT64}
PRECISION_NAMES = {v: k for k, v in PRECISIONS.items()}
PRECISION_SIZE = {FLOAT32: 4, FP1220: 4, FP1632: 6, FLOAT64: 8}
ENU, NED, NWU = 0x0, 0x4, 0x8
COORDINATE_SYSTEMS = {"enu": ENU, "ned": NED, "nwu": NWU}

TEMPERATURE = 0x0810
UTC_TIME = 0x1010
PACKET_COUNTER = 0x1020
SAMPLE_TIME_FINE = 0x1060
SAMPLE_TIME_COARSE = 0x1070
DELTA_V = 0x4010
ACCELERATION = 0x4020
FREE_ACCELERATION = 0x4030
ACCELERATION_HR = 0x4040
RATE_OF_TURN = 0x8020
DELTA_Q = 0x8030
RATE_OF_TURN_HR = 0x8040
MAGNETIC_FIELD = 0xC020

DATA_NAMES = {
    TEMPERATURE: "Temperature", UTC_TIME: "UTCTime", PACKET_COUNTER: "PacketCounter",
    0x1030: "ITOW", SAMPLE_TIME_FINE: "SampleTimeFine", SAMPLE_TIME_COARSE: "SampleTimeCoarse",
    0x2010: "Quaternion", 0x2020: "RotationMatrix", 0x2030: "EulerAngles", 0x3010: "BaroPressure",
    DELTA_V: "DeltaV", ACCELERATION: "Acceleration", FREE_ACCELERATION: "FreeAcceleration",
    ACCELERATION_HR: "AccelerationHR", 0x5020: "AltitudeEllipsoid", 0x5030: "PositionECEF",
    0x5040: "LatLon", 0x7010: "GNSSPVTData", 0x7020: "GNSSSatInfo", RATE_OF_TURN: "RateOfTurn",
    DELTA_Q: "DeltaQ", RATE_OF_TURN_HR: "RateOfTurnHR", 0xC020: "MagneticField", 0xD010: "VelocityXYZ",
    0xE010: "StatusByte", 0xE020: "StatusWord",
}
# Items the decoder reads, with the number of values of the chosen precision each holds.
_VALUE_COUNTS = {
    TEMPERATURE: 1, DELTA_V: 3, ACCELERATION: 3, ACCELERATION_HR: 3, RATE_OF_TURN: 3, DELTA_Q: 4,
    RATE_OF_TURN_HR: 3, MAGNETIC_FIELD: 3,
}

TICKS_PER_SECOND = 10_000  # SampleTimeFine
_US_PER_TICK = 1_000_000 // TICKS_PER_SECOND
_NAN3 = (math.nan, math.nan, math.nan)

# What the framing found at a frame start, when not the frame's end.
_INCOMPLETE, _TOO_LONG, _BAD_SUM = -1, -2, -3
# What an MTData2 packet was to the decoder.
_SAMPLE, _MESSAGE, _UNDATED = 0, 1, 2


_HAS_PRECISION = {TEMPERATURE, 0x2010, 0x2020, 0x2030, DELTA_V, ACCELERATION, FREE_ACCELERATION,
                  ACCELERATION_HR, 0x5020, 0x5030, 0x5040, RATE_OF_TURN, DELTA_Q, RATE_OF_TURN_HR,
                  0xC020, 0xD010}
_HAS_COORDINATES = {0x2010, 0x2020, 0x2030, 0xD010}  # orientation and velocity
_COORDINATE_NAMES = {ENU: "ENU", NED: "NED", NWU: "NWU"}


def item_name(data_id: int) -> str:
    """``Acceleration(float32)``, ``EulerAngles(NED,fp1632)``, ``0x1234`` for unknown ids."""
    kind = data_id & TYPE_MASK
    name = DATA_NAMES.get(kind)
    if name is None:
        return f"0x{data_id:04X}"
    if kind not in _HAS_PRECISION:
        return name
    precision = PRECISION_NAMES[data_id & PRECISION_MASK]
    if kind in _HAS_COORDINATES:
        return f"{name}({_COORDINATE_NAMES.get(data_id & COORD_MASK, '?')},{precision})"
    return f"{name}({precision})"


# ---------------------------------------------------------------------------------- numbers


def _decode_values(data: bytes | memoryview, precision: int, count: int) -> tuple[float, ...]:
    if precision == FLOAT32:
        return struct.unpack(f">{count}f", data)
    if precision == FLOAT64:
        return struct.unpack(f">{count}d", data)
    if precision == FP1220:
        return tuple(v / 1048576.0 for v in struct.unpack(f">{count}i", data))
    # 16.32: the 32-bit fraction first, then the signed 16-bit integer part, both big-endian.
    raw = struct.unpack(">" + "Ih" * count, data)
    return tuple((raw[2 * i + 1] * 4294967296 + raw[2 * i]) / 4294967296.0 for i in range(count))


def _encode_values(values, precision: int) -> bytes:
    if precision == FLOAT32:
        return struct.pack(f">{len(values)}f", *values)
    if precision == FLOAT64:
        return struct.pack(f">{len(values)}d", *values)
    if precision == FP1220:
        words = [max(-(2**31), min(2**31 - 1, round(float(v) * 1048576.0))) for v in values]
        return struct.pack(f">{len(values)}i", *words)
    out = bytearray()
    for v in values:
        fixed = max(-(2**47), min(2**47 - 1, round(float(v) * 4294967296.0)))
        out += struct.pack(">Ih", fixed & 0xFFFFFFFF, fixed >> 32)
    return bytes(out)


# ---------------------------------------------------------------------------------- framing


def checksum(body: bytes) -> int:
    """The byte that makes ``sum(body) + checksum`` zero modulo 256 (body: bus id .. data)."""
    return (-sum(body)) & 0xFF


def encode_frame(msg_id: int, payload: bytes = b"", bus_id: int = BUS_ID) -> bytes:
    """One Xbus message, in the extended-length form when the payload needs it."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD}-byte Xbus limit")
    if len(payload) < EXTENDED_LENGTH:
        body = bytes([bus_id, msg_id, len(payload)]) + payload
    else:
        body = bytes([bus_id, msg_id, EXTENDED_LENGTH]) + struct.pack(">H", len(payload)) + payload
    return bytes([PREAMBLE]) + body + bytes([checksum(body)])


def encode_item(data_id: int, data: bytes) -> bytes:
    """One MTData2 item: ``data_id`` (u16, big-endian), its size (u8) and ``data`` (at most 255 bytes)."""
    if len(data) > 255:
        raise ValueError(f"MTData2 item 0x{data_id:04X} of {len(data)} bytes exceeds 255")
    return struct.pack(">HB", data_id, len(data)) + data


def encode_samples(
    samples: np.ndarray,
    precision: str = "float32",
    deltas: bool = False,
    coordinate_system: str = "enu",
    temperature: bool = True,
    field_ut: float = 50.0,
) -> bytes:
    """MTData2 messages for a batch of ``SAMPLE_DTYPE`` records, as an MTi would send them.

    Each message carries PacketCounter (seq mod 2^16), SampleTimeFine (t_us / 100 mod 2^32),
    Acceleration and RateOfTurn (or, with ``deltas``, DeltaV and DeltaQ over the interval to the
    previous sample) and Temperature, in the given precision and coordinate-system flag; for
    ``MAG_SAMPLE_DTYPE`` records MagneticField too (where finite), normalised: mag / ``field_ut``.
    """
    prec = PRECISIONS[precision]
    flags = prec | COORDINATE_SYSTEMS[coordinate_system]
    with_mag = has_mag(samples)
    samples = np.asarray(samples, dtype=MAG_SAMPLE_DTYPE if with_mag else SAMPLE_DTYPE)
    out = bytearray()
    t_s = samples["t_us"].astype(np.float64) / 1e6
    for i, s in enumerate(samples):
        payload = encode_item(PACKET_COUNTER, struct.pack(">H", int(s["seq"]) & 0xFFFF))
        ticks = (int(s["t_us"]) // _US_PER_TICK) & 0xFFFFFFFF
        payload += encode_item(SAMPLE_TIME_FINE, struct.pack(">I", ticks))
        acc = [float(v) for v in s["acc"]]
        gyro = [float(v) for v in s["gyro"]]
        if deltas:
            dt = t_s[i] - t_s[i - 1] if i else (t_s[1] - t_s[0] if len(samples) > 1 else 0.01)
            payload += encode_item(DELTA_V | flags, _encode_values([a * dt for a in acc], prec))
            payload += encode_item(DELTA_Q | flags, _encode_values(_rate_to_delta_q(gyro, dt), prec))
        else:
            payload += encode_item(ACCELERATION | flags, _encode_values(acc, prec))
            payload += encode_item(RATE_OF_TURN | flags, _encode_values(gyro, prec))
        if temperature and not math.isnan(float(s["temp"])):
            payload += encode_item(TEMPERATURE | prec, _encode_values([float(s["temp"])], prec))
        if with_mag and np.isfinite(s["mag"]).all():
            normalised = [float(v) / field_ut for v in s["mag"]]
            payload += encode_item(MAGNETIC_FIELD | prec, _encode_values(normalised, prec))
        out += encode_frame(MID_MTDATA2, payload)
    return bytes(out)


def _rate_to_delta_q(rate: list[float], dt: float) -> tuple[float, float, float, float]:
    """Rotation quaternion of a constant rate over dt: q = (cos(|w|dt/2), sin(|w|dt/2) w/|w|)."""
    norm = math.sqrt(sum(r * r for r in rate))
    if norm == 0.0:
        return (1.0, 0.0, 0.0, 0.0)
    half = norm * dt / 2.0
    s = math.sin(half) / norm
    return (math.cos(half), rate[0] * s, rate[1] * s, rate[2] * s)


def _delta_q_to_rate(q: tuple[float, ...], dt: float) -> tuple[float, float, float]:
    """Mean rate over dt of the rotation quaternion q: angle 2 atan2(|q_v|, q_0) about q_v."""
    q0, q1, q2, q3 = q
    if q0 < 0.0:  # the same rotation; keep the angle in [0, pi]
        q0, q1, q2, q3 = -q0, -q1, -q2, -q3
    vnorm = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3)
    if vnorm == 0.0:
        return (0.0, 0.0, 0.0)
    k = 2.0 * math.atan2(vnorm, q0) / (vnorm * dt)
    return (q1 * k, q2 * k, q3 * k)


# ---------------------------------------------------------------------------------- packets


@dataclass
class MTData2Packet:
    """The items of one MTData2 message that the station reads; absent items are None."""

    counter: int | None = None
    time_fine: int | None = None
    time_coarse: int | None = None
    acc: tuple[float, ...] | None = None
    delta_v: tuple[float, ...] | None = None
    gyro: tuple[float, ...] | None = None
    delta_q: tuple[float, ...] | None = None
    acc_hr: tuple[float, ...] | None = None
    gyro_hr: tuple[float, ...] | None = None
    temp: float | None = None
    mag: tuple[float, ...] | None = None  # normalised (a.u.), as sent

    @property
    def source(self) -> str | None:
        """``normal`` (Acceleration, RateOfTurn, DeltaV, DeltaQ), ``hr`` (only the high-rate
        AccelerationHR / RateOfTurnHR) or None (no inertial data)."""
        if any(v is not None for v in (self.acc, self.delta_v, self.gyro, self.delta_q)):
            return "normal"
        if self.acc_hr is not None or self.gyro_hr is not None:
            return "hr"
        return None


class BadPacket(ValueError):
    """An MTData2 payload whose items do not fit it or have the wrong size."""


def parse_mtdata2(payload: bytes, seen: dict[str, int] | None = None) -> MTData2Packet:
    """Read the items of an MTData2 payload; unknown items are skipped by their size.

    ``seen`` (optional) counts the items by name, for telling the user what the device sends.
    Raises ``BadPacket`` when an item runs past the payload or a known item has the wrong size.
    """
    packet = MTData2Packet()
    pos, end = 0, len(payload)
    view = memoryview(payload)
    while pos < end:
        if pos + 3 > end:
            raise BadPacket(f"item header cut short at byte {pos}")
        data_id = (payload[pos] << 8) | payload[pos + 1]
        size = payload[pos + 2]
        start = pos + 3
        pos = start + size
        if pos > end:
            raise BadPacket(f"item 0x{data_id:04X} of {size} bytes runs past the payload")
        if seen is not None:
            name = item_name(data_id)
            seen[name] = seen.get(name, 0) + 1
        kind = data_id & TYPE_MASK
        data = view[start:pos]
        if kind == PACKET_COUNTER:
            if size != 2:
                raise BadPacket(f"PacketCounter of {size} bytes")
            packet.counter = (data[0] << 8) | data[1]
        elif kind == SAMPLE_TIME_FINE or kind == SAMPLE_TIME_COARSE:
            if size != 4:
                raise BadPacket(f"{DATA_NAMES[kind]} of {size} bytes")
            value = struct.unpack(">I", data)[0]
            if kind == SAMPLE_TIME_FINE:
                packet.time_fine = value
            else:
                packet.time_coarse = value
        elif kind in _VALUE_COUNTS:
            precision = data_id & PRECISION_MASK
            count = _VALUE_COUNTS[kind]
            if size != count * PRECISION_SIZE[precision]:
                expected = count * PRECISION_SIZE[precision]
                raise BadPacket(f"{item_name(data_id)} of {size} bytes, expected {expected}")
            values = _decode_values(data, precision, count)
            if kind == TEMPERATURE:
                packet.temp = values[0]
            elif kind == ACCELERATION:
                packet.acc = values
            elif kind == ACCELERATION_HR:
                packet.acc_hr = values
            elif kind == DELTA_V:
                packet.delta_v = values
            elif kind == RATE_OF_TURN:
                packet.gyro = values
            elif kind == RATE_OF_TURN_HR:
                packet.gyro_hr = values
            elif kind == MAGNETIC_FIELD:
                packet.mag = values
            else:
                packet.delta_q = values
    return packet


# Frames the vectorised path checks per call (after a damaged frame the next call re-checks at most these).
_RUN_WINDOW = 256
# Fewer frames than this go the per-packet path, quicker for them than the arrays' set-up.
_RUN_MIN = 8
_FIXED_KINDS = {PACKET_COUNTER, SAMPLE_TIME_FINE, TEMPERATURE, ACCELERATION, ACCELERATION_HR, RATE_OF_TURN,
                RATE_OF_TURN_HR, MAGNETIC_FIELD}


@dataclass(frozen=True)
class _Layout:
    """A sample packet's layout: the bytes every frame of it shares, and where its values lie."""

    source: str
    fixed_at: np.ndarray  # frame offsets of the header and item-header bytes
    fixed: np.ndarray  # their values
    values: dict[int, tuple[int, int]]  # item kind -> (frame offset of its data, precision)
    names: tuple[str, ...]  # item names, for items_seen
    record: np.dtype  # a frame as a record: "counter", "time" and each value item's data as "v<kind>"


def _make_layout(payload: bytes, items: list[tuple[int, int]]) -> _Layout | None:
    """The layout of an MTData2 payload whose items the vectorised path reads (every item a fixed-size
    one it knows, once each, with PacketCounter and SampleTimeFine, making samples), else None."""
    kinds = [data_id & TYPE_MASK for data_id, _ in items]
    if len(set(kinds)) != len(kinds) or not set(kinds) <= _FIXED_KINDS:
        return None
    if PACKET_COUNTER not in kinds or SAMPLE_TIME_FINE not in kinds:
        return None
    try:
        packet = parse_mtdata2(payload)
    except BadPacket:
        return None
    source = packet.source
    if source is None:
        return None
    fixed_at, values, at = [0, 1, 2, 3], {}, 4
    counter_at = time_at = 0
    for (data_id, size), kind in zip(items, kinds, strict=True):
        fixed_at += [at, at + 1, at + 2]
        if kind == PACKET_COUNTER:
            counter_at = at + 3
        elif kind == SAMPLE_TIME_FINE:
            time_at = at + 3
        else:
            values[kind] = (at + 3, data_id & PRECISION_MASK)
        at += 3 + size
    header = bytes([PREAMBLE, BUS_ID, MID_MTDATA2, len(payload)]) + payload
    index = np.array(fixed_at)
    # Big-endian values as the frame holds them; FP16.32 (6 bytes a value) as bytes, read by _item_values.
    fields: dict[str, tuple[Any, int]] = {"counter": (">u2", counter_at), "time": (">u4", time_at)}
    for kind, (offset, precision) in values.items():
        count = _VALUE_COUNTS.get(kind, 1)
        form = ("u1", (count, 6)) if precision == FP1632 else (_PRECISION_TYPES[precision], (count,))
        fields[f"v{kind}"] = (form, offset)
    record = np.dtype({"names": list(fields), "formats": [f for f, _ in fields.values()],
                       "offsets": [at for _, at in fields.values()], "itemsize": len(header) + 1})
    return _Layout(source, index, np.frombuffer(header, np.uint8)[index].copy(), values,
                   tuple(item_name(data_id) for data_id, _ in items), record)


_PRECISION_TYPES = {FLOAT32: ">f4", FP1220: ">i4", FLOAT64: ">f8"}
_ALL = np.logical_and.reduce  # ndarray.all without its Python wrapper


def _item_values(data: np.ndarray, precision: int) -> np.ndarray:
    """``(frames, count)`` float64 values of one item of every frame (its record field), as
    ``_decode_values`` reads them."""
    if precision == FP1220:
        return data / 1048576.0
    if precision != FP1632:
        return data.astype(np.float64)
    fraction = np.ascontiguousarray(data[:, :, :4]).view(">u4")[:, :, 0].astype(np.int64)
    integer = np.ascontiguousarray(data[:, :, 4:]).view(">i2")[:, :, 0].astype(np.int64)
    return (integer * 4294967296 + fraction) / 4294967296.0


class XsensDecoder(StreamDecoderBase):
    """Incremental decoder of Xbus messages; MTData2 packets with inertial data become samples.

    ``nominal_rate_hz`` dates packets that carry neither SampleTimeFine nor SampleTimeCoarse
    (``t_us = seq / rate``). ``items_seen`` counts the MTData2 items met, by name. ``field_ut``
    scales the normalised MagneticField to microtesla (see the module docstring).
    """

    name = "xsens"

    def __init__(self, source: str | None = None, nominal_rate_hz: float = 100.0,
                 field_ut: float | None = None) -> None:
        super().__init__()
        if field_ut is not None and not 0.0 < field_ut < 1000.0:
            raise ValueError(f"local field {field_ut} uT is outside 0..1000 uT (the Earth's is 22-67 uT)")
        self.field_ut = field_ut
        self.mag_unscaled = 0  # packets whose MagneticField was left out for want of field_ut
        self._mag = False  # a field was returned: batches are MAG_SAMPLE_DTYPE from then on
        if source not in (None, "normal", "hr"):
            raise ValueError(f"unknown Xsens sample source {source!r}; use normal (Acceleration, RateOfTurn, "
                             f"DeltaV, DeltaQ) or hr (AccelerationHR, RateOfTurnHR)")
        self.source = source
        self.nominal_rate_hz = nominal_rate_hz
        self.other_source_packets = 0  # inertial packets of the source not chosen
        self.items_seen: dict[str, int] = {}
        self.message_ids_seen: dict[int, int] = {}
        self._counter: int | None = None  # unwrapped PacketCounter of the last packet
        self._own_seq = 0  # for packets without PacketCounter
        self._fine: int | None = None  # unwrapped SampleTimeFine of the last sample dated by it
        self._last_inertial_ticks: int | None = None
        self._temp = math.nan
        self._pending: list[tuple[int, int, MTData2Packet]] = []  # delta packets waiting for an interval
        self._layouts: dict[tuple, _Layout | None] = {}  # packet layouts of the vectorised path
        self._last_layout: _Layout | None = None  # the layout of the last run
        # (position, frame size, good, framed) of the frames the vectorised path checked in this feed
        self._run_checked: tuple[int, int, np.ndarray, np.ndarray] | None = None

    @classmethod
    def from_option(cls, option: str) -> XsensDecoder:
        """The decoder of ``xsens:OPTION``: ``normal`` or ``hr`` (the packets that make the samples),
        ``field=UT`` (the local field, for MagneticField in microtesla), or both, comma separated.

        Raises
        ------
        ValueError
            An option that is neither, or a field that is not a number in range.
        """
        source: str | None = None
        field_ut: float | None = None
        for part in filter(None, (p.strip() for p in option.split(","))):
            key, is_field, value = part.partition("=")
            if is_field and key.strip() == "field":
                try:
                    field_ut = float(value)
                except ValueError:
                    raise ValueError(f"xsens option field={value!r}: give the local field in uT, e.g. "
                                     f"field=49.5") from None
            else:
                source = part
        return cls(source=source, field_ut=field_ut)

    def feed(self, data: bytes) -> Decoded:
        """Decode ``data`` after what is buffered (``StreamDecoderBase.feed``)."""
        return self._decode(data, final=False)

    def _decode(self, data: bytes, final: bool) -> Decoded:
        buf = self._buf
        buf += data
        self._run_checked = None
        rows: list[tuple] = []
        messages: list[Message] = []
        stats = self.stats
        pos = 0
        pieces: list[np.ndarray] = []  # batches of the vectorised path, in order with the rows between
        while True:
            pos, found = self._seek_sync(SYNC, pos)
            if not found:
                break
            run = self._sample_run(pos) if not self._pending else None
            if run is not None:
                if rows:
                    pieces.append(rows_to_batch(rows, self._mag))
                    rows = []
                pieces.append(run[0])
                pos = run[1]
                continue
            end = self._frame_end(pos)
            if end == _INCOMPLETE:
                break
            if end == _TOO_LONG:
                stats.length_errors += 1
                pos = self._skip_candidate(SYNC, pos)
                continue
            if end == _BAD_SUM:
                end = self._claimed_end(pos)
                if buf.find(SYNC, pos + 1, end) >= 0:
                    stats.truncated += 1
                else:
                    stats.crc_errors += 1
                pos = self._skip_candidate(SYNC, pos)
                continue
            verdict = self._believe(pos, end, final)
            if verdict is None:
                break
            if not verdict:
                stats.truncated += 1  # a cut frame's header whose checksum passed by chance
                pos = self._skip_candidate(SYNC, pos)
                continue
            header = 6 if buf[pos + 3] == EXTENDED_LENGTH else 4
            msg_id = buf[pos + 2]
            payload = bytes(buf[pos + header : end - 1])
            pos = end
            self.message_ids_seen[msg_id] = self.message_ids_seen.get(msg_id, 0) + 1
            if msg_id != MID_MTDATA2:
                stats.frames += 1
                if msg_id not in MESSAGE_NAMES:
                    stats.unknown_ids += 1
                messages.append(Message(msg_id, payload))
                continue
            try:
                packet = parse_mtdata2(payload, self.items_seen)
            except BadPacket:
                stats.bad_payloads += 1
                continue
            kind = self._on_packet(packet, rows)
            if kind == _UNDATED:
                stats.bad_payloads += 1
                continue
            stats.frames += 1
            if kind == _MESSAGE:
                messages.append(Message(msg_id, payload))
        if pos:
            del buf[:pos]
        samples = rows_to_batch(rows, self._mag)
        if pieces:
            samples = join_batches([*pieces, samples])
            if self._mag:
                samples = with_mag(samples)
        stats.samples += len(samples)
        return Decoded(samples, messages)

    # -------------------------------------------------------------- vectorised path

    def _sample_run(self, pos: int) -> tuple[np.ndarray, int] | None:
        """The samples of a run of like MTData2 packets at ``pos`` and where the run ends, or None.

        Packets of one layout (the same items, in the same order and sizes: what a unit sends) that
        make samples are read at once: every frame's header and item headers, checksum and the
        absence of a frame start inside it are checked on all frames of the run, the values are
        columns of the frame bytes. The result equals the per-packet path's (``_on_packet``); any
        other packet (another layout or source, deltas waiting for an interval, an extended length,
        an undated one, a frame whose header is damaged) ends the run and goes that path; a frame of the
        layout whose checksum fails is skipped as that path would (one CRC error).
        """
        buf = self._buf
        avail = len(buf) - pos
        if avail < 5 or buf[pos + 2] != MID_MTDATA2 or buf[pos + 3] == EXTENDED_LENGTH:
            return None
        size = 5 + buf[pos + 3]
        count = min(avail // size, _RUN_WINDOW)
        if count < _RUN_MIN:
            return None
        frames = np.frombuffer(buf, dtype=np.uint8, count=count * size, offset=pos).reshape(count, size)
        layout = self._last_layout  # a unit sends one layout: the last run's, when the first frame has it
        if layout is None or layout.record.itemsize != size \
                or not _ALL(frames[0, layout.fixed_at] == layout.fixed):
            layout = self._layout(bytes(buf[pos + 4 : pos + size - 1]))
            if layout is None or layout.source != (self.source or layout.source):
                return None
            self._last_layout = layout
        checked = self._run_checked
        if checked is not None and checked[0] <= pos and (pos - checked[0]) % size == 0 \
                and checked[1] == size and (pos - checked[0]) // size < len(checked[2]):
            at = (pos - checked[0]) // size  # checked earlier in this feed
            good, framed = checked[2][at:], checked[3][at:]
            count = len(good)
            frames = frames[:count]
        else:
            framed = (frames[:, layout.fixed_at] == layout.fixed).all(axis=1)
            # A frame start inside a frame: the per-frame path decides which of the two to believe. One
            # frame start a frame in the window (each frame's own) is the usual case: none inside.
            if buf.count(SYNC, pos, pos + count * size) != count:
                framed &= ~((frames[:, 1 : size - 1] == PREAMBLE) & (frames[:, 2:size] == BUS_ID)).any(axis=1)
            good = framed & (frames[:, 1:].sum(axis=1, dtype=np.uint8) == 0)
            self._run_checked = (pos, size, good, framed)
        # The run goes on over frames of the layout whose checksum fails (nothing inside them is a
        # frame start, so the per-frame path skips each as one CRC error), and ends at a good frame.
        n = count if framed.all() else int(framed.argmin())
        if not good[:n].all():
            n = n - int(good[:n][::-1].argmax()) if good[:n].any() else 0
        if n < _RUN_MIN:
            return None
        end = pos + n * size
        records = np.frombuffer(buf, dtype=layout.record, count=n, offset=pos)
        if not good[:n].all():
            records = records[good[:n]]
        damaged, n = n - len(records), len(records)
        values = {kind: _item_values(records[f"v{kind}"], precision)
                  for kind, (_, precision) in layout.values.items()}
        raw = records["counter"].astype(np.int64)
        steps = np.empty(n, dtype=np.int64)
        steps[0] = 0 if self._counter is None else (int(raw[0]) - self._counter) & 0xFFFF
        np.subtract(raw[1:], raw[:-1], out=steps[1:])
        steps[1:] &= 0xFFFF
        counter = (int(raw[0]) if self._counter is None else self._counter) + np.cumsum(steps)
        raw = records["time"].astype(np.int64)
        steps[0] = 0 if self._fine is None else ((int(raw[0]) - self._fine + 2**31) & 0xFFFFFFFF) - 2**31
        np.subtract(raw[1:], raw[:-1], out=steps[1:])
        steps[1:] += 2**31
        steps[1:] &= 0xFFFFFFFF
        steps[1:] -= 2**31
        ticks = (int(raw[0]) if self._fine is None else self._fine) + np.cumsum(steps)
        if ticks.min() < 0:  # an undated packet: counted by the per-packet path
            return None
        if self.source is None:
            self.source = layout.source
        if damaged:
            self.stats.crc_errors += damaged
            self.stats.resyncs += damaged
            self.stats.garbage_bytes += damaged * size
        temp = values.get(TEMPERATURE)
        field = values.get(MAGNETIC_FIELD)
        if field is not None and self.field_ut is None:
            self.mag_unscaled += n
        if field is not None and self.field_ut is not None:
            self._mag = True
        out = np.empty(n, dtype=MAG_SAMPLE_DTYPE if self._mag else SAMPLE_DTYPE)
        out["seq"] = counter & 0xFFFFFFFF
        out["t_us"] = ticks * _US_PER_TICK
        acc_kind, gyro_kind = (ACCELERATION_HR, RATE_OF_TURN_HR) if self.source == "hr" else (
            ACCELERATION, RATE_OF_TURN)
        for name, kind in (("acc", acc_kind), ("gyro", gyro_kind)):
            out[name] = values[kind] if kind in values else np.nan
        out["temp"] = temp[:, 0] if temp is not None else self._temp
        if self._mag:
            out["mag"] = field * self.field_ut if field is not None and self.field_ut is not None else np.nan
        self._counter = int(counter[-1])
        self._own_seq = (int(counter[-1]) & 0xFFFFFFFF) + 1
        self._fine = self._last_inertial_ticks = int(ticks[-1])
        if temp is not None:
            self._temp = float(temp[-1, 0])
        self.message_ids_seen[MID_MTDATA2] = self.message_ids_seen.get(MID_MTDATA2, 0) + n
        for name in layout.names:
            self.items_seen[name] = self.items_seen.get(name, 0) + n
        self.stats.frames += n
        return out, end

    def _layout(self, payload: bytes) -> _Layout | None:
        """The vectorised path's view of a packet layout (cached), or None when it does not take it."""
        items = []
        at = 0
        while at + 3 <= len(payload):
            items.append(((payload[at] << 8) | payload[at + 1], payload[at + 2]))
            at += 3 + payload[at + 2]
        key = (len(payload), tuple(items))
        if key not in self._layouts:
            self._layouts[key] = _make_layout(payload, items) if at == len(payload) else None
        return self._layouts[key]

    # -------------------------------------------------------------- framing

    def _claimed_end(self, pos: int) -> int:
        """Where the frame announced at ``pos`` would end (its header must be in the buffer)."""
        buf = self._buf
        if buf[pos + 3] == EXTENDED_LENGTH:
            return pos + 7 + ((buf[pos + 4] << 8) | buf[pos + 5])
        return pos + 5 + buf[pos + 3]

    def _frame_end(self, pos: int) -> int:
        """End of the frame at ``pos`` (a sync there) when its checksum passes, else one of
        ``_INCOMPLETE`` (bytes missing), ``_TOO_LONG`` (impossible length), ``_BAD_SUM``."""
        buf = self._buf
        if len(buf) - pos < 4 or (buf[pos + 3] == EXTENDED_LENGTH and len(buf) - pos < 6):
            return _INCOMPLETE
        if buf[pos + 3] == EXTENDED_LENGTH and ((buf[pos + 4] << 8) | buf[pos + 5]) > MAX_PAYLOAD:
            return _TOO_LONG
        end = self._claimed_end(pos)
        if len(buf) < end:
            return _INCOMPLETE
        return _BAD_SUM if sum(memoryview(buf)[pos + 1 : end]) & 0xFF else end

    def _valid_at(self, pos: int, final: bool) -> int | None:
        """End of a checksum-valid frame starting exactly at ``pos``; 0 if none; None: wait for bytes."""
        buf = self._buf
        if len(buf) - pos < 2:
            return None if not final and buf[pos:] in (b"", SYNC[:1]) else 0
        if buf[pos : pos + 2] != SYNC:
            return 0
        end = self._frame_end(pos)
        if end == _INCOMPLETE:
            return 0 if final else None
        return max(end, 0)

    def _inner_frames(self, pos: int, end: int, final: bool) -> list[tuple[int, int]] | None:
        """The checksum-valid frames, as ``(start, end)``, that start inside ``buf[pos + 1:end]``
        and inside which no other valid frame starts; None: wait for more bytes."""
        frames = []
        p = self._buf.find(SYNC, pos + 1, end)
        while p >= 0:
            inner = self._valid_at(p, final)
            if inner is None:
                return None
            if inner:
                frames.append((p, inner))
            p = self._buf.find(SYNC, p + 1, end)
        clean = []
        for start, stop in frames:
            p = self._buf.find(SYNC, start + 1, stop)
            swallows = False
            while p >= 0 and not swallows:
                inner = self._valid_at(p, final)
                if inner is None:
                    return None
                swallows = inner > 0
                p = self._buf.find(SYNC, p + 1, stop)
            if not swallows:
                clean.append((start, stop))
        return clean

    def _followed(self, end: int, final: bool) -> bool | None:
        """Whether a valid frame starts right at ``end`` (or the stream ends there); None: wait."""
        if end == len(self._buf):
            return True if final else None
        valid = self._valid_at(end, final)
        return None if valid is None else valid > 0

    def _is_packet(self, start: int, end: int) -> bool:
        """Whether the valid frame ``buf[start:end]`` is an MTData2 packet whose items fit it."""
        buf = self._buf
        if buf[start + 2] != MID_MTDATA2:
            return False
        header = 6 if buf[start + 3] == EXTENDED_LENGTH else 4
        try:
            parse_mtdata2(bytes(buf[start + header : end - 1]))
        except BadPacket:
            return False
        return True

    def _believe(self, pos: int, end: int, final: bool) -> bool | None:
        """Whether the checksum-valid frame ``buf[pos:end]`` is real; None: wait for more bytes.

        An 8-bit checksum passes by chance once in 256, so a frame start in garbage (a cut
        frame's header) can claim a span that covers good frames, and a good frame's payload
        can hold a chance frame. The frame is believed when no valid frame starts inside it.
        When some do (taking those inside which no other starts), the MTData2 packets decide:
        the frame is believed when its items fit it and none of the inner frames' do, and is a
        false start in the opposite case. Otherwise what follows decides: it is believed only
        if a valid frame starts right where it ends and none of the inner ones is followed by
        one. A false start's bytes are read again from the next frame start.
        """
        if self._buf.find(SYNC, pos + 1, end) < 0:
            return True
        inner = self._inner_frames(pos, end, final)
        if inner is None:
            return None
        if not inner:
            return True
        outer_fits = self._is_packet(pos, end)
        inner_fits = any(self._is_packet(start, stop) for start, stop in inner)
        if outer_fits != inner_fits:
            return outer_fits
        followed = self._followed(end, final)
        if not followed:
            return followed  # None: wait for the bytes after it; False: a false start
        for _, stop in inner:
            inner_followed = self._followed(stop, final)
            if inner_followed is None or inner_followed:
                return None if inner_followed is None else False
        return True

    def _on_packet(self, packet: MTData2Packet, rows: list[tuple]) -> int:
        """Track counter, time and temperature; append the sample rows.

        Returns ``_SAMPLE`` (rows appended or a delta packet held for its interval),
        ``_MESSAGE`` (not an inertial packet of the chosen source) or ``_UNDATED`` (an inertial
        packet dated before the stream's clock zero: it cannot be placed in time).
        """
        counter: int | None = None
        if packet.counter is not None:
            if self._counter is None:
                counter = packet.counter
            else:
                counter = self._counter + ((packet.counter - self._counter) & 0xFFFF)
            self._counter = counter
        if packet.temp is not None:
            self._temp = packet.temp
        source = packet.source
        if source is not None and self.source is None:
            self.source = source
        if source is None or source != self.source:
            self.other_source_packets += source is not None
            # Its counter value is not a lost sample: the link statistics must not count it as one.
            self.stats.seq_skipped += packet.counter is not None
            return _MESSAGE
        if counter is not None:
            seq = counter & 0xFFFFFFFF
        else:
            seq = self._own_seq & 0xFFFFFFFF
        if packet.time_fine is not None:
            if self._fine is None:
                ticks = packet.time_fine
            else:
                # A signed step from the last sample's time: the clock wraps forward every 4.97 days,
                # a sample dated a little earlier (a replay, a unit's glitch) steps back.
                ticks = self._fine + (((packet.time_fine - self._fine + 2**31) & 0xFFFFFFFF) - 2**31)
            if ticks < 0:
                return _UNDATED
            # Only samples move the reference: packets of other kinds (GNSS fixes carry the older
            # time of their fix) and undated ones must not shift the unwrapping of the next.
            self._fine = ticks
        elif packet.time_coarse is not None:
            ticks = packet.time_coarse * TICKS_PER_SECOND
        else:
            ticks = round(seq * TICKS_PER_SECOND / self.nominal_rate_hz)
        self._own_seq = seq + 1
        needs_dt = (packet.acc is None and packet.delta_v is not None) or (
            packet.gyro is None and packet.delta_q is not None)
        last = self._last_inertial_ticks
        dt = None if last is None else (ticks - last) / TICKS_PER_SECOND
        self._last_inertial_ticks = ticks
        if needs_dt and not dt:
            self._pending.append((seq, ticks, packet))
            return _SAMPLE
        for p_seq, p_ticks, pending in self._pending:
            rows.append(self._row(p_seq, p_ticks, pending, dt))
        self._pending.clear()
        rows.append(self._row(seq, ticks, packet, dt))
        return _SAMPLE

    def _row(self, seq: int, ticks: int, packet: MTData2Packet, dt: float | None) -> tuple:
        """The sample of a packet; with ``field_ut``, its field in microtesla as a sixth element."""
        row = self._inertial_row(seq, ticks, packet, dt)
        if packet.mag is not None and self.field_ut is None:
            self.mag_unscaled += 1
        if self.field_ut is None:
            return row
        if packet.mag is None:
            return (*row, _NAN3)
        self._mag = True
        return (*row, tuple(v * self.field_ut for v in packet.mag))

    def _inertial_row(self, seq: int, ticks: int, packet: MTData2Packet, dt: float | None) -> tuple:
        if self.source == "hr":
            return (seq, ticks * _US_PER_TICK, packet.acc_hr or _NAN3, packet.gyro_hr or _NAN3, self._temp)
        acc = packet.acc
        if acc is None:
            acc = tuple(v / dt for v in packet.delta_v) if packet.delta_v is not None and dt else _NAN3
        gyro = packet.gyro
        if gyro is None:
            gyro = _delta_q_to_rate(packet.delta_q, dt) if packet.delta_q is not None and dt else _NAN3
        return (seq, ticks * _US_PER_TICK, acc, gyro, self._temp)

    def flush(self) -> Decoded:
        """End of stream: a frame start left waiting for bytes is truncated; what follows it is
        decoded, so a false start inside garbage does not hide a good last frame."""
        out = self._decode(b"", final=True)
        batches, messages = [out.samples], list(out.messages)
        while self._buf:
            if self._buf.startswith(SYNC):
                self.stats.truncated += 1
            del self._buf[: self._skip_candidate(SYNC, 0)]
            out = self._decode(b"", final=True)
            batches.append(out.samples)
            messages += out.messages
        # A lone delta packet has no interval to turn it into a rate: it cannot become a sample.
        if self._pending:
            self.stats.bad_payloads += len(self._pending)
            self._pending.clear()
        samples = join_batches(batches)
        return Decoded(with_mag(samples) if self._mag else samples, messages)
