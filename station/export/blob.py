"""The parameter blob firmware loads: one unit's calibration, little-endian, CRC-checked.

Layout, format version 1 (every offset in bytes, every number little-endian):

    header (HEADER_SIZE = 96 bytes)
      0   4  magic "IMUC"
      4   2  u16  format version (1)
      6   2  u16  header size (96); the payload starts there
      8   4  u32  total length of the blob, CRC included
     12   2  u16  parameter-file schema version (1 for imu-station/params/1)
     14   2  u16  flags: bit 0 accel section, bit 1 gyro section, bit 2 accel thermal,
                  bit 3 gyro thermal (what the parameter file held)
     16   8  i64  parameter file's ``created``, Unix seconds UTC (0 when unknown)
     24   8  i64  export time, Unix seconds UTC
     32  32  unit serial, UTF-8, NUL-padded (at most 31 bytes, so always NUL-terminated)
     64  16  station id, UTF-8, NUL-padded (at most 15 bytes)
     80  16  reserved, zero
    payload (at ``header size``)
      +0  4  f32  thermal reference temperature T_ref (degC; 0 without a thermal section)
      +4  4  f32  dT filter time constant tau (s; 0 without a thermal section)
      +8     accel triad: f32[9] correction M^-1 row-major, f32[3] bias b
     +56     gyro triad: the same
    +104     accel thermal block, then gyro thermal block, each:
             u32 segment count n (0: no thermal model), f32 dT clamp min, f32 dT clamp max,
             n x (f32 t_min, f32 t_max, f32[3][7] coefficients, axis-major, TERMS order)
    trailer
      4      u32  CRC-32 (IEEE 802.3) of every byte before it

The firmware side (``imu_calib_load`` in the exported C) checks magic, version, length
and CRC in that order, so each failure has its own code.
"""

from __future__ import annotations

import datetime as _dt
import struct
from dataclasses import dataclass

import numpy as np

from protocols.crc import crc32
from station.engines.sensor_model import SensorCalibration
from station.engines.thermal_model import TERMS, DtempFilter, ThermalBias, ThermalModel, ThermalSegment
from station.errors import StationError
from station.export.params_file import SCHEMA, ParamsFile

MAGIC = b"IMUC"
FORMAT_VERSION = 1
HEADER_SIZE = 96
SERIAL_SIZE = 32
STATION_ID_SIZE = 16
N_TERMS = len(TERMS)
SEGMENT_SIZE = 4 * (2 + 3 * N_TERMS)
TRIAD_SIZE = 4 * 12
THERMAL_HEAD_SIZE = 12
CRC_SIZE = 4
MIN_BLOB_SIZE = HEADER_SIZE + 8 + 2 * TRIAD_SIZE + 2 * THERMAL_HEAD_SIZE + CRC_SIZE

FLAG_ACCEL = 1
FLAG_GYRO = 2
FLAG_ACCEL_THERMAL = 4
FLAG_GYRO_THERMAL = 8

_HEADER = struct.Struct("<4sHHIHHqq32s16s16x")
assert _HEADER.size == HEADER_SIZE


class BlobError(StationError):
    """A blob that cannot be built from a parameter file, or read back."""


@dataclass
class BlobContents:
    """What a blob holds, as ``parse_blob`` reads it back (numbers are the stored float32)."""

    flags: int
    schema_version: int
    created_utc: int
    exported_utc: int
    serial: str
    station_id: str
    reference_temp: float
    dtemp_tau_s: float
    accel: SensorCalibration
    gyro: SensorCalibration
    thermal: ThermalModel | None
    format_version: int = FORMAT_VERSION


def schema_version(schema: str = SCHEMA) -> int:
    """The number after the last '/' of a schema name: 1 for ``imu-station/params/1``."""
    return int(schema.rsplit("/", 1)[1])


def unix_seconds(stamp: str) -> int:
    """Unix seconds of an ISO-8601 UTC stamp such as ``2026-11-22T10:00:00Z``; 0 when unparseable."""
    try:
        when = _dt.datetime.fromisoformat(stamp)
    except (TypeError, ValueError):
        return 0
    if when.tzinfo is None:
        when = when.replace(tzinfo=_dt.UTC)
    return int(when.timestamp())


def fixed_utf8(text: str, size: int, what: str) -> bytes:
    """``text`` as UTF-8 cut to ``size - 1`` bytes on a character boundary (room for the NUL)."""
    data = text.encode("utf-8")
    if len(data) < size:
        return data
    cut = data[: size - 1].decode("utf-8", errors="ignore").encode("utf-8")
    if not cut and data:
        raise BlobError(f"{what} {text!r} cannot be stored in {size - 1} bytes")
    return cut


def _f32(values: object) -> list[float]:
    return [float(v) for v in np.asarray(values, dtype=np.float32).ravel()]


def _check_thermal(name: str, triad: ThermalBias) -> None:
    previous_max = None
    for i, seg in enumerate(triad.segments):
        if not (np.isfinite(seg.t_min) and np.isfinite(seg.t_max) and seg.t_min < seg.t_max):
            raise BlobError(f"thermal.{name} segment {i}: t_min {seg.t_min} must be below t_max {seg.t_max}")
        if previous_max is not None and seg.t_min < previous_max - 1e-9:
            raise BlobError(f"thermal.{name} segment {i} starts at {seg.t_min} degC, before the previous "
                            f"segment ends ({previous_max} degC); segments must be in increasing order")
        if not np.all(np.isfinite(seg.coeffs)):
            raise BlobError(f"thermal.{name} segment {i} has a coefficient that is not a finite number")
        previous_max = seg.t_max
    if not (np.isfinite(triad.dt_min) and np.isfinite(triad.dt_max) and triad.dt_min <= triad.dt_max):
        raise BlobError(f"thermal.{name}: the dT clamp [{triad.dt_min}, {triad.dt_max}] is not a range")


def thermal_triads(params: ParamsFile) -> dict[str, ThermalBias | None]:
    """The accel and gyro thermal models of a parameter file (None where absent), validated."""
    out: dict[str, ThermalBias | None] = {"accel": None, "gyro": None}
    if params.thermal is None:
        return out
    for name in out:
        triad = getattr(params.thermal, name)
        if triad is not None:
            _check_thermal(name, triad)
        out[name] = triad
    return out


def _triad_bytes(cal: SensorCalibration | None) -> bytes:
    cal = cal or SensorCalibration.identity()
    return struct.pack("<12f", *_f32(cal.correction), *_f32(cal.bias))


def _thermal_bytes(triad: ThermalBias | None) -> bytes:
    if triad is None:
        return struct.pack("<Iff", 0, 0.0, 0.0)
    out = [struct.pack("<Iff", len(triad.segments), *_f32([triad.dt_min, triad.dt_max]))]
    for seg in triad.segments:
        out.append(struct.pack(f"<{2 + 3 * N_TERMS}f", *_f32([seg.t_min, seg.t_max]), *_f32(seg.coeffs)))
    return b"".join(out)


def flags_of(params: ParamsFile) -> int:
    triads = thermal_triads(params)
    return ((FLAG_ACCEL if params.accel is not None else 0)
            | (FLAG_GYRO if params.gyro is not None else 0)
            | (FLAG_ACCEL_THERMAL if triads["accel"] is not None else 0)
            | (FLAG_GYRO_THERMAL if triads["gyro"] is not None else 0))


def build_blob(params: ParamsFile, station_id: str, exported_utc: int) -> bytes:
    """The blob of ``params`` (layout in the module docstring)."""
    if params.accel is None and params.gyro is None and params.thermal is None:
        raise BlobError("the parameter file has no accel, gyro or thermal section: nothing to export; "
                        "run 'imu-station calibrate' or 'imu-station thermal' first")
    triads = thermal_triads(params)
    thermal = params.thermal
    reference_temp = thermal.reference_temp if thermal is not None else 0.0
    tau = thermal.dtemp_filter.tau_s if thermal is not None else 0.0
    payload = b"".join([
        struct.pack("<ff", *_f32([reference_temp, tau])),
        _triad_bytes(params.accel),
        _triad_bytes(params.gyro),
        _thermal_bytes(triads["accel"]),
        _thermal_bytes(triads["gyro"]),
    ])
    total = HEADER_SIZE + len(payload) + CRC_SIZE
    header = _HEADER.pack(
        MAGIC, FORMAT_VERSION, HEADER_SIZE, total, schema_version(), flags_of(params),
        unix_seconds(params.created), int(exported_utc),
        fixed_utf8(str(params.device.get("serial", "")), SERIAL_SIZE, "unit serial"),
        fixed_utf8(station_id, STATION_ID_SIZE, "station id"),
    )
    body = header + payload
    return body + struct.pack("<I", crc32(body))


def _read_thermal(data: bytes, pos: int, name: str) -> tuple[ThermalBias | None, int]:
    if pos + THERMAL_HEAD_SIZE > len(data) - CRC_SIZE:
        raise BlobError(f"blob ends inside the {name} thermal block")
    n, dt_min, dt_max = struct.unpack_from("<Iff", data, pos)
    pos += THERMAL_HEAD_SIZE
    if pos + n * SEGMENT_SIZE > len(data) - CRC_SIZE:
        raise BlobError(f"blob ends inside the {name} thermal segments ({n} announced)")
    segments = []
    for _ in range(n):
        values = struct.unpack_from(f"<{2 + 3 * N_TERMS}f", data, pos)
        segments.append(ThermalSegment(values[0], values[1], np.array(values[2:])))
        pos += SEGMENT_SIZE
    return (ThermalBias(segments, dt_min, dt_max) if n else None), pos


def parse_blob(data: bytes) -> BlobContents:
    """Read a blob back, with the checks and in the order of the firmware's ``imu_calib_load``."""
    if len(data) < 8:
        raise BlobError(f"blob is {len(data)} bytes, shorter than its fixed header start")
    magic, version, header_size = struct.unpack_from("<4sHH", data, 0)
    if magic != MAGIC:
        raise BlobError(f"bad magic {magic!r}, expected {MAGIC!r}: not an imu-station parameter blob")
    if version != FORMAT_VERSION:
        raise BlobError(f"blob format version {version} is unknown; this station reads {FORMAT_VERSION}")
    if len(data) < MIN_BLOB_SIZE or header_size < HEADER_SIZE:
        raise BlobError(f"blob is {len(data)} bytes, too short for format version {FORMAT_VERSION}")
    (_, _, _, total, schema, flags, created, exported, serial, station) = _HEADER.unpack_from(data, 0)
    if total != len(data):
        raise BlobError(f"blob says it is {total} bytes long but {len(data)} bytes were given")
    (stored_crc,) = struct.unpack_from("<I", data, total - CRC_SIZE)
    if crc32(data[: total - CRC_SIZE]) != stored_crc:
        raise BlobError("blob CRC-32 mismatch: the blob is corrupted")
    pos = header_size
    reference_temp, tau = struct.unpack_from("<ff", data, pos)
    pos += 8
    triads = []
    for _ in range(2):
        values = struct.unpack_from("<12f", data, pos)
        correction = np.array(values[:9]).reshape(3, 3)
        if not np.all(np.isfinite(values)) or abs(np.linalg.det(correction)) < 1e-12:
            raise BlobError("blob holds a correction matrix that is singular or not finite")
        triads.append(SensorCalibration(np.linalg.inv(correction), np.array(values[9:])))
        pos += TRIAD_SIZE
    accel_thermal, pos = _read_thermal(data, pos, "accel")
    gyro_thermal, pos = _read_thermal(data, pos, "gyro")
    if pos != total - CRC_SIZE:
        raise BlobError(f"blob content ends at byte {pos}, not at the CRC (byte {total - CRC_SIZE})")
    for name, triad in (("accel", accel_thermal), ("gyro", gyro_thermal)):
        if triad is not None:
            _check_thermal(name, triad)
    thermal = None
    if accel_thermal is not None or gyro_thermal is not None:
        thermal = ThermalModel(reference_temp, DtempFilter("ema", tau), accel_thermal, gyro_thermal)
    return BlobContents(
        flags=flags, schema_version=schema, created_utc=created, exported_utc=exported,
        serial=serial.rstrip(b"\0").decode("utf-8", errors="replace"),
        station_id=station.rstrip(b"\0").decode("utf-8", errors="replace"),
        reference_temp=reference_temp, dtemp_tau_s=tau, accel=triads[0], gyro=triads[1], thermal=thermal,
        format_version=version,
    )
