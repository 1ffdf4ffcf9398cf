"""The parameter blob firmware loads: one unit's calibration, little-endian, CRC-checked.

Layout, format version 3 (every offset in bytes, every number little-endian):

    header (HEADER_SIZE = 96 bytes)
      0   4  magic "IMUC"
      4   2  u16  format version (3; 1 and 2 are still read)
      6   2  u16  header size (96); the payload starts there
      8   4  u32  total length of the blob, CRC included
     12   2  u16  parameter-file schema version (1 for imu-station/params/1)
     14   2  u16  flags: bit 0 accel section, bit 1 gyro section, bit 2 accel thermal,
                  bit 3 gyro thermal, bit 4 mag section, bit 5 gyro g-sensitivity, bit 6 accel
                  thermal scale, bit 7 accel thermal misalignment, bit 8 gyro thermal scale,
                  bit 9 gyro thermal misalignment (what the parameter file held)
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
     then (format version 2 on; version 1 ends here)
      48     mag triad: f32[9] correction M_m^-1 row-major, f32[3] hard iron b_m (microtesla);
             identity and zero without a mag section
      36     gyro g-sensitivity G: f32[9] row-major, rad/s per m/s^2; zero without one
     then (format version 3 on; version 2 ends here)
     160     accel thermal intrinsics, then 160 gyro thermal intrinsics, each (INTRINSICS_SIZE):
              f32[3] K, the diagonal of the section's matrix M(T_ref) (identity without a section)
              f32[6] S, its misalignment M_ij / K_i, off-diagonal in the order xy, xz, yx, yz, zx, zy
                  (K = 1, S = 0 where the triad has neither a scale nor a misalignment polynomial)
              f32 t_min, f32 t_max, f32[3][3] scale polynomial k: per axis the coefficients of
                  t, t^2, t^3 (0 for a power the fit did not keep)
              f32 t_min, f32 t_max, f32[6][3] misalignment polynomial s: per entry (xy .. zy) the
                  same
             a polynomial whose flag is clear is stored as zeros and never evaluated
    trailer
      4      u32  CRC-32 (IEEE 802.3) of every byte before it

With a triad's scale or misalignment flag set, the correction at temperature T uses
M(T) = diag(K + k(t)) (I + S + s(t)), t = clip(T, t_min, t_max) - T_ref (equation (1) of
``station.engines.thermal.intrinsics``), inverted per sample, instead of the stored M^-1; K and S
are stored apart so the firmware needs no division to build M(T).

The firmware side (``imu_calib_load`` in the exported C) checks magic, version, length
and CRC in that order, so each failure has its own code. Then the content, with one set of
rules that ``parse_blob`` applies exactly as the C does (same order, same error code), and that
``build_blob`` checks on what it writes:

- the header size lies between 96 and the CRC;
- every float is finite; the dT time constant is not negative;
- each correction matrix (accel, gyro; mag from version 2) has a non-zero determinant (cofactor
  expansion in double precision, the same operations on both sides);
- per thermal block: at most the loader's capacity of segments (``IMU_CALIB_MAX_SEGMENTS``,
  ``ERR_CAPACITY``), dT clamp min <= max, each segment t_min < t_max and starting at or after the
  previous segment's t_max (float32 comparisons);
- from version 3, per thermal intrinsics polynomial whose flag is set: t_min < t_max (float32);
- the content ends exactly at the CRC.

A version 1 blob reads as one without a mag section or g-sensitivity (flags bits 4 and 5 clear), a
version 1 or 2 blob as one without thermal intrinsics (flags bits 6 to 9 clear).

Why this module is long: the writer and the reader of one layout belong together, and the reader
mirrors the C loader rule by rule (same order, same error code) for every format version it still
reads; split, the two halves of each rule would drift apart.
"""

from __future__ import annotations

import datetime as _dt
import struct
from dataclasses import dataclass, field

import numpy as np

from protocols.crc import crc32
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.intrinsics import OFF_DIAGONAL, TempPolynomial
from station.engines.thermal.model import TERMS, DtempFilter, ThermalBias, ThermalModel, ThermalSegment
from station.errors import StationError
from station.export.params.file import SCHEMA, ParamsFile
from station.export.params.sections import MAG, g_sensitivity, mag_calibration, present

MAGIC = b"IMUC"
FORMAT_VERSION = 3
READ_VERSIONS = (1, 2, 3)
"""Every format version the loaders read: a new version never drops an older one."""
HEADER_SIZE = 96
SERIAL_SIZE = 32
STATION_ID_SIZE = 16
N_TERMS = len(TERMS)
SEGMENT_SIZE = 4 * (2 + 3 * N_TERMS)
TRIAD_SIZE = 4 * 12
THERMAL_HEAD_SIZE = 12
MATRIX_SIZE = 4 * 9
CRC_SIZE = 4
POWERS = (1, 2, 3)
"""The powers of t a thermal intrinsics polynomial stores coefficients for, in this order."""
INTRINSICS_FLOATS = 3 + 6 + 2 + 3 * len(POWERS) + 2 + 6 * len(POWERS)
INTRINSICS_SIZE = 4 * INTRINSICS_FLOATS
MIN_BLOB_SIZE_V1 = HEADER_SIZE + 8 + 2 * TRIAD_SIZE + 2 * THERMAL_HEAD_SIZE + CRC_SIZE
MIN_BLOB_SIZE_V2 = MIN_BLOB_SIZE_V1 + TRIAD_SIZE + MATRIX_SIZE
MIN_BLOB_SIZE = MIN_BLOB_SIZE_V2 + 2 * INTRINSICS_SIZE
MIN_BLOB_SIZES = {1: MIN_BLOB_SIZE_V1, 2: MIN_BLOB_SIZE_V2, 3: MIN_BLOB_SIZE}

FLAG_ACCEL = 1
FLAG_GYRO = 2
FLAG_ACCEL_THERMAL = 4
FLAG_GYRO_THERMAL = 8
FLAG_MAG = 16
FLAG_G_SENSITIVITY = 32
FLAG_SCALE = {"accel": 64, "gyro": 256}
FLAG_MISALIGNMENT = {"accel": 128, "gyro": 512}
FLAGS_BEFORE_V3 = 0x3F
"""The flags a version 1 or 2 blob can mean: the thermal intrinsics bits read as clear there."""

CARRIED = ("accel", "gyro", "thermal", MAG)
"""The sections a blob holds (the gyro's g-sensitivity rides with the gyro)."""

_HEADER = struct.Struct("<4sHHIHHqq32s16s16x")
assert _HEADER.size == HEADER_SIZE


# imu_calib_load's results (IMU_CALIB_ERR_* in the exported header)
ERR_MAGIC = -1
ERR_VERSION = -2
ERR_LENGTH = -3
ERR_CRC = -4
ERR_CAPACITY = -5
ERR_CONTENT = -6


class BlobError(StationError):
    """A blob that cannot be built from a parameter file, or read back.

    ``code`` is the ``imu_calib_load`` result the firmware gives for the same blob (None when
    building).
    """

    def __init__(self, message: str, code: int | None = None):
        super().__init__(message)
        self.code = code


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
    mag: SensorCalibration | None = None
    """The mag section (None when flags bit 4 is clear, as in every version 1 blob)."""
    g_sensitivity: np.ndarray | None = None
    """G, (3, 3) rad/s per m/s^2 (None when flags bit 5 is clear)."""
    reference_matrix: dict[str, np.ndarray] = field(default_factory=dict)
    """M(T_ref) = diag(K) (I + S) as the thermal intrinsics block holds it, per triad whose scale
    or misalignment flag is set (empty before version 3)."""


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
    # A value beyond float32 becomes inf here, which the read-back of the built blob refuses.
    with np.errstate(over="ignore"):
        return [float(v) for v in np.asarray(values, dtype=np.float32).ravel()]


def _segment_problem(i: int, t_min: float, t_max: float, previous_t_max: float | None) -> str | None:
    """What is wrong with segment ``i`` under the blob's rule (float32 bounds), or None."""
    lo, hi = np.float32(t_min), np.float32(t_max)
    if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
        return f"segment {i}: t_min {t_min} must be below t_max {t_max}"
    if previous_t_max is not None and lo < np.float32(previous_t_max):
        return (f"segment {i} starts at {t_min} degC, before the previous segment ends "
                f"({previous_t_max} degC); segments must be in increasing order")
    return None


def _check_thermal(name: str, triad: ThermalBias) -> None:
    previous_max = None
    for i, seg in enumerate(triad.segments):
        problem = _segment_problem(i, seg.t_min, seg.t_max, previous_max)
        if problem is not None:
            raise BlobError(f"thermal.{name} {problem}")
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


def intrinsics_of(params: ParamsFile, name: str) -> tuple[TempPolynomial | None, TempPolynomial | None]:
    """The scale-factor and misalignment polynomials of triad ``name`` (None where absent)."""
    if params.thermal is None:
        return None, None
    return params.thermal.scale.get(name), params.thermal.misalignment.get(name)


def _poly_floats(poly: TempPolynomial | None, components: int) -> list[float]:
    """t_min, t_max and the (components, 3) coefficients of t, t^2, t^3 of one polynomial; zeros
    without one."""
    if poly is None:
        return [0.0] * (2 + components * len(POWERS))
    coeffs = np.zeros((components, len(POWERS)))
    for j, power in enumerate(poly.powers):
        coeffs[:, POWERS.index(power)] += poly.coeffs[:, j]
    return [poly.t_min, poly.t_max, *coeffs.ravel()]


def intrinsics_values(params: ParamsFile, name: str) -> np.ndarray:
    """The thermal intrinsics block of triad ``name`` (module docstring), float64 before rounding:
    K, S, then the scale and misalignment polynomials (INTRINSICS_FLOATS values).

    K is the diagonal of M(T_ref) and S_ij = M_ij / K_i, the decomposition M = diag(K) (I + S) of
    equation (1) of ``station.engines.thermal.intrinsics``.
    """
    scale, misalignment = intrinsics_of(params, name)
    k0, s0 = np.ones(3), np.zeros(6)
    if scale is not None or misalignment is not None:
        matrix = (getattr(params, name) or SensorCalibration.identity()).matrix
        k0 = np.diag(matrix).copy()
        with np.errstate(divide="ignore", invalid="ignore"):
            unit = matrix / k0[:, None]
        s0 = np.array([unit[i, j] for i, j in OFF_DIAGONAL])
    return np.array([*k0, *s0, *_poly_floats(scale, 3), *_poly_floats(misalignment, 6)])


def _check_intrinsics(params: ParamsFile, name: str) -> None:
    """Refuse, naming the parameter-file entry, what would give a blob its loader refuses."""
    scale, misalignment = intrinsics_of(params, name)
    if scale is None and misalignment is None:
        return
    with np.errstate(over="ignore"):
        values = np.asarray(intrinsics_values(params, name), np.float32)
    if not (np.all(np.isfinite(values[:9])) and np.all(values[:3] != 0)):
        raise BlobError(f"the {name} section's matrix has a zero or non-finite diagonal: M = diag(K) (I + S) "
                        f"of thermal.scale/thermal.misalignment cannot be formed; recalibrate {name}")
    for key, poly in (("scale", scale), ("misalignment", misalignment)):
        if poly is None:
            continue
        if not np.float32(poly.t_min) < np.float32(poly.t_max):
            raise BlobError(f"thermal.{key}.{name}: clamp [{poly.t_min}, {poly.t_max}] degC is empty "
                            "in float32")
        with np.errstate(over="ignore"):
            if not np.all(np.isfinite(np.float32(poly.coeffs))):
                raise BlobError(f"thermal.{key}.{name} has a coefficient that is not a finite float32 number")


def flags_of(params: ParamsFile) -> int:
    """The blob's flags: which sections (accel, gyro, their thermal models, mag, the gyro's
    g-sensitivity, the thermal scale and misalignment of each triad) it carries."""
    triads = thermal_triads(params)
    intrinsics = 0
    for name in ("accel", "gyro"):
        scale, misalignment = intrinsics_of(params, name)
        intrinsics |= (FLAG_SCALE[name] if scale is not None else 0) \
            | (FLAG_MISALIGNMENT[name] if misalignment is not None else 0)
    return (intrinsics
            | (FLAG_ACCEL if params.accel is not None else 0)
            | (FLAG_GYRO if params.gyro is not None else 0)
            | (FLAG_ACCEL_THERMAL if triads["accel"] is not None else 0)
            | (FLAG_GYRO_THERMAL if triads["gyro"] is not None else 0)
            | (FLAG_MAG if mag_calibration(params) is not None else 0)
            | (FLAG_G_SENSITIVITY if g_sensitivity(params) is not None else 0))


def g_sensitivity_or_zero(params: ParamsFile) -> np.ndarray:
    """G of the file, or zeros (what the blob stores without one)."""
    matrix = g_sensitivity(params)
    return np.zeros((3, 3)) if matrix is None else matrix


def build_blob(params: ParamsFile, station_id: str, exported_utc: int) -> bytes:
    """The blob of ``params`` (layout in the module docstring)."""
    if not set(present(params)) & set(CARRIED):
        raise BlobError("the parameter file has no accel, gyro, thermal or mag section: nothing to export; "
                        "run 'imu-station calibrate' or 'imu-station thermal' first")
    triads = thermal_triads(params)
    for name in ("accel", "gyro"):
        _check_intrinsics(params, name)
    thermal = params.thermal
    reference_temp = thermal.reference_temp if thermal is not None else 0.0
    tau = thermal.dtemp_filter.tau_s if thermal is not None else 0.0
    payload = b"".join([
        struct.pack("<ff", *_f32([reference_temp, tau])),
        _triad_bytes(params.accel),
        _triad_bytes(params.gyro),
        _thermal_bytes(triads["accel"]),
        _thermal_bytes(triads["gyro"]),
        _triad_bytes(mag_calibration(params)),
        struct.pack("<9f", *_f32(g_sensitivity_or_zero(params))),
        *(struct.pack(f"<{INTRINSICS_FLOATS}f", *_f32(intrinsics_values(params, name)))
          for name in ("accel", "gyro")),
    ])
    total = HEADER_SIZE + len(payload) + CRC_SIZE
    header = _HEADER.pack(
        MAGIC, FORMAT_VERSION, HEADER_SIZE, total, schema_version(), flags_of(params),
        unix_seconds(params.created), int(exported_utc),
        fixed_utf8(str(params.device.get("serial", "")), SERIAL_SIZE, "unit serial"),
        fixed_utf8(station_id, STATION_ID_SIZE, "station id"),
    )
    body = header + payload
    blob = body + struct.pack("<I", crc32(body))
    try:
        parse_blob(blob)
    except BlobError as exc:
        raise BlobError(f"the parameter file gives a blob the firmware loader refuses: {exc}") from None
    return blob


class _Cursor:
    """The C loader's bounds-checked reader: a short read or a non-finite float clears ``ok`` and
    keeps the first reason; reads after that give 0 and do not move."""

    def __init__(self, data: bytes, pos: int, end: int):
        self.data, self.pos, self.end = data, pos, end
        self.ok = True
        self.why = ""

    def refuse(self, why: str) -> None:
        if self.ok:
            self.ok, self.why = False, why

    def u32(self, what: str) -> int:
        if not self.ok or self.end - self.pos < 4:
            self.refuse(f"blob content ends inside {what}")
            return 0
        (value,) = struct.unpack_from("<I", self.data, self.pos)
        self.pos += 4
        return int(value)

    def f32(self, what: str) -> float:
        (value,) = struct.unpack("<f", struct.pack("<I", self.u32(what)))
        if not np.isfinite(value):
            self.refuse(f"{what} is not a finite number")
        return float(value)

    def floats(self, n: int, what: str) -> list[float]:
        return [self.f32(what) for _ in range(n)]


def _determinant(m: list[float]) -> float:
    """Cofactor expansion in double precision, in the order of the C loader's imu_calib_det."""
    a, b, c, d, e, f, g, h, i = m
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _inverse(m: list[float], det: float) -> np.ndarray:
    a, b, c, d, e, f, g, h, i = m
    adjugate = np.array([[e * i - f * h, c * h - b * i, b * f - c * e],
                         [f * g - d * i, a * i - c * g, c * d - a * f],
                         [d * h - e * g, b * g - a * h, a * e - b * d]])
    return adjugate / det


def _take_thermal(r: _Cursor, name: str, max_segments: int | None) -> ThermalBias | None:
    n = r.u32(f"the {name} thermal block")
    if r.ok and max_segments is not None and n > max_segments:
        raise BlobError(f"the {name} thermal model has {n} segments, more than the loader's "
                        f"{max_segments}", ERR_CAPACITY)
    dt_min = r.f32(f"the {name} dT clamp")
    dt_max = r.f32(f"the {name} dT clamp")
    if r.ok and not dt_min <= dt_max:
        r.refuse(f"the {name} dT clamp [{dt_min}, {dt_max}] is not a range")
    segments: list[ThermalSegment] = []
    while r.ok and len(segments) < n:
        what = f"{name} thermal segment {len(segments)}"
        t_min, t_max = r.f32(what), r.f32(what)
        coeffs = r.floats(3 * N_TERMS, what)
        problem = _segment_problem(len(segments), t_min, t_max, segments[-1].t_max if segments else None)
        if problem is not None:
            r.refuse(f"{name} thermal {problem}")
        segments.append(ThermalSegment(t_min, t_max, np.array(coeffs)))
    if not r.ok:
        raise BlobError(f"blob content is inconsistent: {r.why}", ERR_CONTENT)
    return ThermalBias(segments, dt_min, dt_max) if n else None


def _take_intrinsics(r: _Cursor, name: str, flags: int) -> tuple[np.ndarray, TempPolynomial | None,
                                                                 TempPolynomial | None]:
    """One thermal intrinsics block: M(T_ref) = diag(K) (I + S) and the polynomials its flags say
    are there (a clamp that is not a range refuses the blob, as in the C)."""
    values = np.array(r.floats(INTRINSICS_FLOATS, f"the {name} thermal intrinsics"))
    unit = np.eye(3)
    for c, (i, j) in enumerate(OFF_DIAGONAL):
        unit[i, j] = values[3 + c]
    polys: list[TempPolynomial | None] = []
    start = 9
    for key, components, flag in (("scale", 3, FLAG_SCALE[name]),
                                  ("misalignment", 6, FLAG_MISALIGNMENT[name])):
        block = values[start:start + 2 + components * len(POWERS)]
        start += len(block)
        if not flags & flag:
            polys.append(None)
            continue
        if not (np.float32(block[0]) < np.float32(block[1])):
            r.refuse(f"the {name} thermal {key} clamp [{block[0]}, {block[1]}] is not a range")
        polys.append(TempPolynomial(block[0], block[1], POWERS, block[2:]) if r.ok else None)
    # A refused block (non-finite values) is never used: its matrix need not be formed.
    return (values[:3, None] * unit if r.ok else np.eye(3)), polys[0], polys[1]


def parse_blob(data: bytes, max_segments: int | None = None) -> BlobContents:
    """Read a blob back with exactly the checks, order and error codes of the firmware's ``imu_calib_load``.

    Parameters
    ----------
    data : bytes
        The blob.
    max_segments : int, optional
        The loader's ``IMU_CALIB_MAX_SEGMENTS``: more segments in a thermal block give
        ``ERR_CAPACITY`` as in the C. None reads any number.

    Raises
    ------
    BlobError
        With ``code`` the loader's result for the same bytes.
    """
    if len(data) < 8:
        raise BlobError(f"blob is {len(data)} bytes, shorter than its fixed header start", ERR_LENGTH)
    magic, version = struct.unpack_from("<4sH", data, 0)
    if magic != MAGIC:
        raise BlobError(f"bad magic {magic!r}, expected {MAGIC!r}: not an imu-station parameter blob",
                        ERR_MAGIC)
    if version not in READ_VERSIONS:
        raise BlobError(f"blob format version {version} is unknown; this station reads "
                        f"{', '.join(map(str, READ_VERSIONS))}", ERR_VERSION)
    if len(data) < MIN_BLOB_SIZES[version]:
        raise BlobError(f"blob is {len(data)} bytes, too short for format version {version}", ERR_LENGTH)
    (_, _, header_size, total, schema, flags, created, exported, serial, station) = \
        _HEADER.unpack_from(data, 0)
    if total != len(data):
        raise BlobError(f"blob says it is {total} bytes long but {len(data)} bytes were given", ERR_LENGTH)
    (stored_crc,) = struct.unpack_from("<I", data, total - CRC_SIZE)
    if crc32(data[: total - CRC_SIZE]) != stored_crc:
        raise BlobError("blob CRC-32 mismatch: the blob is corrupted", ERR_CRC)
    end = total - CRC_SIZE
    if not HEADER_SIZE <= header_size <= end:
        raise BlobError(f"blob header size {header_size} is outside {HEADER_SIZE}..{end}", ERR_CONTENT)
    r = _Cursor(data, header_size, end)
    reference_temp = r.f32("the reference temperature")
    tau = r.f32("the dT time constant")
    triads = [r.floats(12, f"the {name} correction or bias") for name in ("accel", "gyro")]
    determinants = [_determinant(values[:9]) for values in triads]
    if r.ok and 0.0 in determinants:
        r.refuse("a correction matrix is singular (determinant 0)")
    accel_thermal = _take_thermal(r, "accel", max_segments)
    gyro_thermal = _take_thermal(r, "gyro", max_segments)
    mag_values, g_values = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0, 0, 0, 0], [0.0] * 9
    if version >= 2:
        mag_values = r.floats(12, "the mag correction or hard iron")
        g_values = r.floats(9, "the gyro g-sensitivity")
        if r.ok and _determinant(mag_values[:9]) == 0.0:
            r.refuse("the mag correction matrix is singular (determinant 0)")
        if not r.ok:
            raise BlobError(f"blob content is inconsistent: {r.why}", ERR_CONTENT)
    if version < 3:
        flags &= FLAGS_BEFORE_V3
    intrinsics = {} if version < 3 else {name: _take_intrinsics(r, name, flags) for name in ("accel", "gyro")}
    if not r.ok:
        raise BlobError(f"blob content is inconsistent: {r.why}", ERR_CONTENT)
    if r.pos != end:
        raise BlobError(f"blob content ends at byte {r.pos}, not at the CRC (byte {end})", ERR_CONTENT)
    if tau < 0:
        raise BlobError(f"blob content is inconsistent: the dT time constant {tau} s is negative",
                        ERR_CONTENT)
    calibrations = [SensorCalibration(_inverse(values[:9], det), np.array(values[9:]))
                    for values, det in zip(triads, determinants, strict=True)]
    scale = {name: got[1] for name, got in intrinsics.items() if got[1] is not None}
    misalignment = {name: got[2] for name, got in intrinsics.items() if got[2] is not None}
    thermal = None
    if accel_thermal is not None or gyro_thermal is not None or scale or misalignment:
        thermal = ThermalModel(reference_temp, DtempFilter("ema", tau), accel_thermal, gyro_thermal,
                               scale=scale, misalignment=misalignment)
    mag = None
    if flags & FLAG_MAG:
        mag_correction = _inverse(mag_values[:9], _determinant(mag_values[:9]))
        mag = SensorCalibration(mag_correction, np.array(mag_values[9:]))
    return BlobContents(
        flags=flags, schema_version=schema, created_utc=created, exported_utc=exported,
        serial=serial.rstrip(b"\0").decode("utf-8", errors="replace"),
        station_id=station.rstrip(b"\0").decode("utf-8", errors="replace"),
        reference_temp=reference_temp, dtemp_tau_s=tau, accel=calibrations[0], gyro=calibrations[1],
        thermal=thermal, format_version=version, mag=mag,
        g_sensitivity=np.array(g_values).reshape(3, 3) if flags & FLAG_G_SENSITIVITY else None,
        reference_matrix={name: got[0] for name, got in intrinsics.items()
                          if got[1] is not None or got[2] is not None},
    )
