"""Firmware export in C (``shared/specs/firmware-api.md``): imu_calib.h, imu_calib.c, imu_calib.bin.

The C computes, in float32, what ``station.engines.shared.correction`` computes:

    acc  = M_a(T)^-1 (raw_a - b_a - B_a(T, dT)),   gyro = M_g(T)^-1 (raw_g - b_g - B_g(T, dT) - G acc)
    mag  = M_m^-1 (raw_m - b_m)                       (imu_calib_apply_mag)

with B the piecewise seven-term thermal bias of ``station.engines.thermal.model`` (T clamped
to the calibrated range, dT to its clamp, segment chosen by its t_min), G the gyro's
g-sensitivity at the corrected specific force, and M(T) = diag(K + k(t)) (I + S + s(t)) of
``station.engines.thermal.intrinsics`` (equation (1)) where the thermal section has the triad's
scale or misalignment polynomials: built at the clamped T and inverted by cofactors per sample;
the stored M^-1 where it has neither, or T is unknown. The header carries the
unit's parameters as a ``const imu_calib_t`` initializer; ``imu_calib_load`` reads the same
parameters from the blob (``station.export.firmware.blob``). Strings from the unit only ever reach the
generated code through ``c_string_literal`` and ``c_comment_text``.

Why this module is long: about 630 of its lines are the C header and source
templates (``HEADER_TEMPLATE``, ``SOURCE_TEMPLATE``), kept as Python strings beside the code that
fills them so that the C and the station's reader are changed together (their rules must match).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from station import __version__
from station.common.files import atomic_write_bytes, atomic_write_text
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import TERMS, ThermalBias
from station.export.firmware import blob as blobfmt
from station.export.params.file import SCHEMA, ParamsFile
from station.export.params.sections import mag_calibration

HEADER_NAME = "imu_calib.h"
SOURCE_NAME = "imu_calib.c"
BLOB_NAME = "imu_calib.bin"
DEFAULT_MAX_SEGMENTS = 8


def c_string_literal(text: str) -> str:
    """A C string literal holding the UTF-8 bytes of ``text``, safe in C and C++.

    Only printable ASCII other than ``"``, ``\\`` and ``?`` (trigraphs) passes as itself;
    every other byte becomes a three-digit octal escape, which cannot swallow the next character
    the way a hex escape can.
    """
    out = []
    for byte in text.encode("utf-8"):
        char = chr(byte)
        out.append(char if 0x20 <= byte < 0x7F and char not in '"\\?' else f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def c_comment_text(text: str) -> str:
    """``text`` as it may appear inside a ``/* */`` comment: escaped like a string literal, and with
    no ``*/`` (would end the comment) nor ``/*`` (``-Wcomment``) left in it."""
    out = c_string_literal(text)
    while "*/" in out or "/*" in out:
        out = out.replace("*/", "*\\/").replace("/*", "/\\*")
    return out


def c_float(value: float) -> str:
    """A float32 constant that the compiler reads back to the same bits (10 significant digits)."""
    return f"{float(np.float32(value)):.9e}f"


def _floats(values: object) -> str:
    return ", ".join(c_float(v) for v in np.asarray(values, dtype=np.float64).ravel())


def _matrix(values: object) -> str:
    rows = np.asarray(values, dtype=np.float64)
    return "{" + ", ".join("{" + _floats(row) + "}" for row in rows) + "}"


def _triad_init(cal: SensorCalibration | None) -> str:
    cal = cal or SensorCalibration.identity()
    return "{" + _matrix(cal.correction) + ", {" + _floats(cal.bias) + "}}"


def _thermal_init(triad: ThermalBias | None) -> str:
    if triad is None:
        zero = "{" + c_float(0) + ", " + c_float(0) + ", " + _matrix(np.zeros((3, len(TERMS)))) + "}"
        return f"{{0u, {c_float(0)}, {c_float(0)}, {{{zero}}}}}"
    segments = ", ".join(f"{{{c_float(s.t_min)}, {c_float(s.t_max)}, {_matrix(s.coeffs)}}}"
                         for s in triad.segments)
    return f"{{{len(triad.segments)}u, {c_float(triad.dt_min)}, {c_float(triad.dt_max)}, {{{segments}}}}}"


def _intrinsics_init(params: ParamsFile, name: str) -> str:
    """The ``imu_calib_intrinsics_t`` initializer of a triad: the same float32 values as its blob block."""
    values = blobfmt.intrinsics_values(params, name)
    scale_rows, mis_rows = values[11:20].reshape(3, 3), values[22:40].reshape(6, 3)
    return (f"{{{{{_floats(values[0:3])}}}, {{{_floats(values[3:9])}}}, {c_float(values[9])}, "
            f"{c_float(values[10])}, {_matrix(scale_rows)}, {c_float(values[20])}, {c_float(values[21])}, "
            f"{_matrix(mis_rows)}}}")


def unit_initializer(params: ParamsFile, station_id: str, exported_utc: int) -> str:
    """The ``imu_calib_t`` initializer (C89-style positional, valid C99 and C++) of the unit."""
    triads = blobfmt.thermal_triads(params)
    thermal = params.thermal
    serial = blobfmt.fixed_utf8(str(params.device.get("serial", "")), blobfmt.SERIAL_SIZE, "unit serial")
    station = blobfmt.fixed_utf8(station_id, blobfmt.STATION_ID_SIZE, "station id")
    fields = [
        f"{blobfmt.FORMAT_VERSION}u",
        f"{blobfmt.schema_version()}u",
        f"{blobfmt.flags_of(params)}u",
        f"{blobfmt.unix_seconds(params.created)}LL",
        f"{int(exported_utc)}LL",
        c_string_literal(serial.decode("utf-8")),
        c_string_literal(station.decode("utf-8")),
        c_float(thermal.reference_temp if thermal else 0.0),
        c_float(thermal.dtemp_filter.tau_s if thermal else 0.0),
        _triad_init(params.accel),
        _triad_init(params.gyro),
        _thermal_init(triads["accel"]),
        _thermal_init(triads["gyro"]),
        _triad_init(mag_calibration(params)),
        _matrix(blobfmt.g_sensitivity_or_zero(params)),
        _intrinsics_init(params, "accel"),
        _intrinsics_init(params, "gyro"),
    ]
    return "{ \\\n    " + ", \\\n    ".join(fields) + " \\\n}"


def _describe(params: ParamsFile, station_id: str, exported_utc: int, blob_size: int) -> str:
    device = params.device
    lines = [
        f"Generated by imu-station {__version__} at Unix time {int(exported_utc)} UTC on station "
        f"{c_comment_text(station_id)}.",
        f"Unit serial {c_comment_text(str(device.get('serial', '')))}, "
        f"model {c_comment_text(str(device.get('model', '')))}, "
        f"firmware {c_comment_text(str(device.get('firmware', '')))}.",
        f"Parameter file {SCHEMA}, created {c_comment_text(params.created)}; blob {blob_size} bytes.",
    ]
    for name, cal in (("accel", params.accel), ("gyro", params.gyro), ("mag", mag_calibration(params))):
        if cal is not None:
            number = isinstance(cal.residual_rms, int | float)
            rms = f", residual rms {cal.residual_rms:.3g}" if number else ""
            lines.append(f"{name}: method {c_comment_text(cal.method)}{rms}.")
    return "\n".join(f" * {line}" for line in lines)


HEADER_TEMPLATE = """\
/* imu_calib.h: calibration of one IMU, for firmware. Do not edit: regenerate with
 * 'imu-station export PARAMS --format c -o DIR'.
@DESCRIPTION@
 *
 * Correction (SI units: m/s^2, rad/s, degC, degC/s; microtesla), the same as 'imu-station apply':
 *   acc  = M_a(T)^-1 (raw_acc  - b_a - B_a(T, dT))
 *   gyro = M_g(T)^-1 (raw_gyro - b_g - B_g(T, dT) - G acc)
 *   mag  = M_m^-1 (raw_mag  - b_m)                       (imu_calib_apply_mag)
 *   B(T, dT) = c0 t^3 + c1 t^2 + c2 t + c3 dT^2 + c4 dT + c5 t dT + c6,  t = T - T_ref,
 * per axis, with T clamped to [t_min of the first segment, t_max of the last] and dT to
 * [dt_min, dt_max]; the segment is the last whose t_min <= T. B = 0 when there is no thermal
 * model or T is not finite. dT comes from imu_calib_dtemp_update, the station's own filter.
 *   M(T) = diag(K + k(t)) (I + S + s(t)),  t = clamp(T, t_min, t_max) - T_ref,
 * k and s polynomials in t without constant (coefficients of t, t^2, t^3), each with its own
 * clamp, where the flags hold the triad's thermal scale or misalignment; M(T) is inverted by
 * cofactors on each call. Without them, or with T not finite, M(T) is M(T_ref): the stored M^-1.
 * G is the gyro's g-sensitivity (rad/s per m/s^2) at the corrected specific force acc; zero
 * without one. Without a mag section imu_calib_apply_mag copies the raw field.
 */
#ifndef IMU_CALIB_H
#define IMU_CALIB_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define IMU_CALIB_FORMAT_VERSION 3u       /* written; every version from 1 is read */
#define IMU_CALIB_HEADER_SIZE 96u
#define IMU_CALIB_TERMS 7
#define IMU_CALIB_SERIAL_SIZE 32
#define IMU_CALIB_STATION_ID_SIZE 16
#ifndef IMU_CALIB_MAX_SEGMENTS
#define IMU_CALIB_MAX_SEGMENTS @MAX_SEGMENTS@
#endif
#if IMU_CALIB_MAX_SEGMENTS < @UNIT_SEGMENTS@
#error "this unit's thermal model has @UNIT_SEGMENTS@ segments: IMU_CALIB_MAX_SEGMENTS must be at least that"
#endif

/* flags: which sections the parameter file held */
#define IMU_CALIB_FLAG_ACCEL 1u
#define IMU_CALIB_FLAG_GYRO 2u
#define IMU_CALIB_FLAG_ACCEL_THERMAL 4u
#define IMU_CALIB_FLAG_GYRO_THERMAL 8u
#define IMU_CALIB_FLAG_MAG 16u
#define IMU_CALIB_FLAG_G_SENSITIVITY 32u
#define IMU_CALIB_FLAG_ACCEL_THERMAL_SCALE 64u
#define IMU_CALIB_FLAG_ACCEL_THERMAL_MISALIGNMENT 128u
#define IMU_CALIB_FLAG_GYRO_THERMAL_SCALE 256u
#define IMU_CALIB_FLAG_GYRO_THERMAL_MISALIGNMENT 512u

/* imu_calib_load results */
#define IMU_CALIB_OK 0
#define IMU_CALIB_ERR_MAGIC (-1)    /* not an imu-station parameter blob */
#define IMU_CALIB_ERR_VERSION (-2)  /* blob format version this code does not know */
#define IMU_CALIB_ERR_LENGTH (-3)   /* length given differs from the blob's own, or truncated */
#define IMU_CALIB_ERR_CRC (-4)      /* CRC-32 mismatch: corrupted */
#define IMU_CALIB_ERR_CAPACITY (-5) /* more thermal segments than IMU_CALIB_MAX_SEGMENTS */
#define IMU_CALIB_ERR_CONTENT (-6)  /* CRC good but the content is inconsistent */
#define IMU_CALIB_ERR_ARG (-7)      /* NULL pointer */

typedef struct {
    float t_min;                          /* degC */
    float t_max;                          /* degC */
    float coeffs[3][IMU_CALIB_TERMS];     /* per axis: t^3, t^2, t, dT^2, dT, t*dT, 1 */
} imu_calib_segment_t;

typedef struct {
    uint32_t n_segments;                  /* 0: no thermal model for this triad */
    float dt_min;                         /* degC/s */
    float dt_max;                         /* degC/s */
    imu_calib_segment_t segments[IMU_CALIB_MAX_SEGMENTS];
} imu_calib_thermal_t;

typedef struct {
    float correction[3][3];               /* M^-1, row-major */
    float bias[3];                        /* b, sensor units */
} imu_calib_triad_t;

/* A triad's scale factor and misalignment as functions of T; used where its flags are set. */
typedef struct {
    float scale[3];                       /* K: the diagonal of M(T_ref) */
    float misalignment[6];                /* S: M_ij / K_i, in the order xy, xz, yx, yz, zx, zy */
    float scale_t_min;                    /* degC: T clamped to [t_min, t_max] for k */
    float scale_t_max;
    float scale_coeffs[3][3];             /* k per axis: coefficients of t, t^2, t^3 */
    float misalignment_t_min;             /* degC: T clamped to [t_min, t_max] for s */
    float misalignment_t_max;
    float misalignment_coeffs[6][3];      /* s per entry xy .. zy: coefficients of t, t^2, t^3 */
} imu_calib_intrinsics_t;

typedef struct {
    uint16_t format_version;
    uint16_t schema_version;              /* parameter file schema imu-station/params/N */
    uint32_t flags;
    int64_t created_utc;                  /* parameter file created, Unix seconds */
    int64_t exported_utc;                 /* exported, Unix seconds */
    char serial[IMU_CALIB_SERIAL_SIZE];
    char station_id[IMU_CALIB_STATION_ID_SIZE];
    float reference_temp;                 /* T_ref, degC */
    float dtemp_tau_s;                    /* dT filter time constant, s */
    imu_calib_triad_t accel;
    imu_calib_triad_t gyro;
    imu_calib_thermal_t accel_thermal;
    imu_calib_thermal_t gyro_thermal;
    imu_calib_triad_t mag;                /* M_m^-1 and hard iron, microtesla; identity and zero without */
    float g_sensitivity[3][3];            /* G, rad/s per m/s^2, row-major; zero without */
    imu_calib_intrinsics_t accel_intrinsics; /* K = 1, S = 0 and zeros without (every version 1 or 2 blob) */
    imu_calib_intrinsics_t gyro_intrinsics;
} imu_calib_t;

/* State of the dT estimator; start it with imu_calib_dtemp_init. */
typedef struct {
    float temp_f;                         /* low-passed temperature, degC */
    float dtemp;                          /* low-passed rate, degC/s */
    float last_temp;                      /* last finite reading, stands in for unknown ones */
    int started;
} imu_calib_dtemp_t;

/* Parse a parameter blob. 0 on success; a negative IMU_CALIB_ERR_* code for bad magic, unknown
   version, wrong length or CRC mismatch (checked in that order), then for content that breaks the
   blob's rules (non-finite number, singular correction, negative dT time constant, thermal
   segments out of order or overlapping, too many segments, an empty clamp of a thermal scale or
   misalignment polynomial), leaving *out untouched. */
int imu_calib_load(imu_calib_t *out, const uint8_t *blob, size_t len);

/* Correct one sample: temperature in degC, its rate in degC/s, raw inputs in sensor units.
   The temperature moves the thermal bias and, where the unit has them, the scale factor and
   misalignment (M(T) above). acc and gyro may alias raw_acc and raw_gyro. */
void imu_calib_apply(const imu_calib_t *p, float temp_c, float dtemp_c_per_s,
                     const float raw_acc[3], const float raw_gyro[3],
                     float acc[3], float gyro[3]);

/* Correct one magnetometer sample (microtesla): correction @ (raw - hard iron). A blob without a
   mag section (every format version 1 blob) copies raw to mag. mag may alias raw_mag. */
void imu_calib_apply_mag(const imu_calib_t *p, const float raw_mag[3], float mag[3]);

/* dT the way the station estimates it: a first-order low-pass of T with time constant tau,
   alpha = dt / (tau + dt) on each sample's own dt, then the difference quotient of the filtered
   T low-passed again. Call once per temperature sample with the time since the previous one;
   an unknown (non-finite) reading counts as the last known one, as the station does. */
void imu_calib_dtemp_init(imu_calib_dtemp_t *s);
float imu_calib_dtemp_update(imu_calib_dtemp_t *s, const imu_calib_t *p, float dt_s, float temp_c);

/* A short English text for an imu_calib_load result. */
const char *imu_calib_strerror(int code);

/* This unit. The strings are escaped copies of what the unit reported. */
#define IMU_CALIB_UNIT_SERIAL @SERIAL@
#define IMU_CALIB_UNIT_MODEL @MODEL@
#define IMU_CALIB_UNIT_FIRMWARE @FIRMWARE@
#define IMU_CALIB_STATION_ID @STATION@
#define IMU_CALIB_UNIT_BLOB_SIZE @BLOB_SIZE@u
#define IMU_CALIB_UNIT_INITIALIZER @INITIALIZER@

/* The same parameters as imu_calib.bin, linked in (defined in imu_calib.c). */
extern const imu_calib_t imu_calib_unit;

#ifdef __cplusplus
}
#endif

#endif /* IMU_CALIB_H */
"""

SOURCE_TEMPLATE = """\
/* imu_calib.c: loading and applying an imu-station calibration. C99, no allocation; uses only
 * <stdint.h>, <stddef.h>, <string.h> and <math.h>. Generated by imu-station @VERSION@. */
#include "imu_calib.h"

#include <math.h>
#include <string.h>

/* The blob stores IEEE-754 binary32; a build where float is something else must fail here. */
typedef char imu_calib_float_is_binary32[(sizeof(float) == 4u) ? 1 : -1];

#define IMU_CALIB_CRC_SIZE 4u
#define IMU_CALIB_TRIAD_BYTES 48u
#define IMU_CALIB_THERMAL_HEAD_BYTES 12u
#define IMU_CALIB_MATRIX_BYTES 36u
#define IMU_CALIB_MIN_BLOB_SIZE_V1 (IMU_CALIB_HEADER_SIZE + 8u + 2u * IMU_CALIB_TRIAD_BYTES + \\
                                    2u * IMU_CALIB_THERMAL_HEAD_BYTES + IMU_CALIB_CRC_SIZE)
#define IMU_CALIB_MIN_BLOB_SIZE_V2 (IMU_CALIB_MIN_BLOB_SIZE_V1 + IMU_CALIB_TRIAD_BYTES + \\
                                    IMU_CALIB_MATRIX_BYTES)
#define IMU_CALIB_INTRINSICS_BYTES 160u
#define IMU_CALIB_MIN_BLOB_SIZE_V3 (IMU_CALIB_MIN_BLOB_SIZE_V2 + 2u * IMU_CALIB_INTRINSICS_BYTES)
#define IMU_CALIB_FLAGS_BEFORE_V3 0x3Fu

/* The (row, column) of S's off-diagonal entries, in the order the blob stores them. */
static const unsigned char imu_calib_off_diagonal[6][2] = {{0, 1}, {0, 2}, {1, 0}, {1, 2}, {2, 0}, {2, 1}};

const imu_calib_t imu_calib_unit = IMU_CALIB_UNIT_INITIALIZER;

static uint16_t imu_calib_u16(const uint8_t *b)
{
    return (uint16_t)((unsigned)b[0] | ((unsigned)b[1] << 8));
}

static uint32_t imu_calib_u32(const uint8_t *b)
{
    return (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
}

static int64_t imu_calib_i64(const uint8_t *b)
{
    uint64_t u = (uint64_t)imu_calib_u32(b) | ((uint64_t)imu_calib_u32(b + 4) << 32);
    int64_t v;
    memcpy(&v, &u, sizeof v);
    return v;
}

static uint32_t imu_calib_crc32(const uint8_t *data, size_t len)
{
    uint32_t crc = 0xFFFFFFFFu;
    size_t i;
    int k;
    for (i = 0; i < len; ++i) {
        crc ^= data[i];
        for (k = 0; k < 8; ++k) {
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return ~crc;
}

/* A bounds-checked cursor over the payload: a read past the end clears ok. */
typedef struct {
    const uint8_t *data;
    size_t pos;
    size_t end;
    int ok;
} imu_calib_reader_t;

static uint32_t imu_calib_take_u32(imu_calib_reader_t *r)
{
    uint32_t v;
    if (!r->ok || r->end - r->pos < 4u) {
        r->ok = 0;
        return 0u;
    }
    v = imu_calib_u32(r->data + r->pos);
    r->pos += 4u;
    return v;
}

static float imu_calib_take_f32(imu_calib_reader_t *r)
{
    uint32_t u = imu_calib_take_u32(r);
    float v;
    memcpy(&v, &u, sizeof v);
    if (!isfinite(v)) {
        r->ok = 0;
    }
    return v;
}

static void imu_calib_take_floats(imu_calib_reader_t *r, float *out, size_t n)
{
    size_t i;
    for (i = 0; i < n; ++i) {
        out[i] = imu_calib_take_f32(r);
    }
}

static int imu_calib_take_thermal(imu_calib_reader_t *r, imu_calib_thermal_t *th)
{
    uint32_t i;
    th->n_segments = imu_calib_take_u32(r);
    if (r->ok && th->n_segments > (uint32_t)IMU_CALIB_MAX_SEGMENTS) {
        return IMU_CALIB_ERR_CAPACITY;
    }
    th->dt_min = imu_calib_take_f32(r);
    th->dt_max = imu_calib_take_f32(r);
    if (r->ok && !(th->dt_min <= th->dt_max)) {
        r->ok = 0;
    }
    for (i = 0; r->ok && i < th->n_segments; ++i) {
        imu_calib_segment_t *s = &th->segments[i];
        s->t_min = imu_calib_take_f32(r);
        s->t_max = imu_calib_take_f32(r);
        imu_calib_take_floats(r, &s->coeffs[0][0], 3u * IMU_CALIB_TERMS);
        if (!(s->t_min < s->t_max) || (i > 0u && s->t_min < th->segments[i - 1u].t_max)) {
            r->ok = 0;
        }
    }
    return r->ok ? IMU_CALIB_OK : IMU_CALIB_ERR_CONTENT;
}

/* One polynomial's clamp and rows of coefficients; a clamp that is not a range is refused where the
   flag says the polynomial is there. */
static void imu_calib_take_poly(imu_calib_reader_t *r, float *t_min, float *t_max, float *coeffs, size_t rows,
                                uint32_t present)
{
    *t_min = imu_calib_take_f32(r);
    *t_max = imu_calib_take_f32(r);
    imu_calib_take_floats(r, coeffs, 3u * rows);
    if (present && !(*t_min < *t_max)) {
        r->ok = 0;
    }
}

static void imu_calib_take_intrinsics(imu_calib_reader_t *r, imu_calib_intrinsics_t *in, uint32_t scale_flag,
                                      uint32_t misalignment_flag)
{
    imu_calib_take_floats(r, in->scale, 3u);
    imu_calib_take_floats(r, in->misalignment, 6u);
    imu_calib_take_poly(r, &in->scale_t_min, &in->scale_t_max, &in->scale_coeffs[0][0], 3u, scale_flag);
    imu_calib_take_poly(r, &in->misalignment_t_min, &in->misalignment_t_max, &in->misalignment_coeffs[0][0],
                        6u, misalignment_flag);
}

/* Determinant of a correction matrix, by cofactors in double precision: the station's blob reader
   (station.export.firmware.blob) does the same operations in the same order, so both refuse the same
   blobs. */
static double imu_calib_det(const imu_calib_triad_t *t)
{
    double a = (double)t->correction[0][0], b = (double)t->correction[0][1], c = (double)t->correction[0][2];
    double d = (double)t->correction[1][0], e = (double)t->correction[1][1], f = (double)t->correction[1][2];
    double g = (double)t->correction[2][0], h = (double)t->correction[2][1], k = (double)t->correction[2][2];
    return a * (e * k - f * h) - b * (d * k - f * g) + c * (d * h - e * g);
}

int imu_calib_load(imu_calib_t *out, const uint8_t *blob, size_t len)
{
    imu_calib_t p;
    imu_calib_reader_t r;
    size_t header_size;
    unsigned version;
    int rc;

    if (out == NULL || blob == NULL) {
        return IMU_CALIB_ERR_ARG;
    }
    if (len < 8u) {
        return IMU_CALIB_ERR_LENGTH;
    }
    if (memcmp(blob, "IMUC", 4) != 0) {
        return IMU_CALIB_ERR_MAGIC;
    }
    version = imu_calib_u16(blob + 4);
    if (version < 1u || version > 3u) {
        return IMU_CALIB_ERR_VERSION;
    }
    if (len < (version == 1u ? IMU_CALIB_MIN_BLOB_SIZE_V1
               : (version == 2u ? IMU_CALIB_MIN_BLOB_SIZE_V2 : IMU_CALIB_MIN_BLOB_SIZE_V3))
        || (size_t)imu_calib_u32(blob + 8) != len) {
        return IMU_CALIB_ERR_LENGTH;
    }
    if (imu_calib_crc32(blob, len - IMU_CALIB_CRC_SIZE) != imu_calib_u32(blob + len - IMU_CALIB_CRC_SIZE)) {
        return IMU_CALIB_ERR_CRC;
    }
    header_size = imu_calib_u16(blob + 6);
    if (header_size < IMU_CALIB_HEADER_SIZE || header_size > len - IMU_CALIB_CRC_SIZE) {
        return IMU_CALIB_ERR_CONTENT;
    }

    memset(&p, 0, sizeof p);
    p.format_version = (uint16_t)version;
    p.schema_version = imu_calib_u16(blob + 12);
    p.flags = imu_calib_u16(blob + 14);
    p.created_utc = imu_calib_i64(blob + 16);
    p.exported_utc = imu_calib_i64(blob + 24);
    memcpy(p.serial, blob + 32, IMU_CALIB_SERIAL_SIZE);
    p.serial[IMU_CALIB_SERIAL_SIZE - 1] = '\\0';
    memcpy(p.station_id, blob + 64, IMU_CALIB_STATION_ID_SIZE);
    p.station_id[IMU_CALIB_STATION_ID_SIZE - 1] = '\\0';

    r.data = blob;
    r.pos = header_size;
    r.end = len - IMU_CALIB_CRC_SIZE;
    r.ok = 1;
    p.reference_temp = imu_calib_take_f32(&r);
    p.dtemp_tau_s = imu_calib_take_f32(&r);
    imu_calib_take_floats(&r, &p.accel.correction[0][0], 9u);
    imu_calib_take_floats(&r, p.accel.bias, 3u);
    imu_calib_take_floats(&r, &p.gyro.correction[0][0], 9u);
    imu_calib_take_floats(&r, p.gyro.bias, 3u);
    if (r.ok && (imu_calib_det(&p.accel) == 0.0 || imu_calib_det(&p.gyro) == 0.0)) {
        r.ok = 0;
    }
    rc = imu_calib_take_thermal(&r, &p.accel_thermal);
    if (rc == IMU_CALIB_OK) {
        rc = imu_calib_take_thermal(&r, &p.gyro_thermal);
    }
    if (rc != IMU_CALIB_OK) {
        return rc;
    }
    if (version >= 2u) {
        imu_calib_take_floats(&r, &p.mag.correction[0][0], 9u);
        imu_calib_take_floats(&r, p.mag.bias, 3u);
        imu_calib_take_floats(&r, &p.g_sensitivity[0][0], 9u);
        if (!r.ok || imu_calib_det(&p.mag) == 0.0) {
            return IMU_CALIB_ERR_CONTENT;
        }
    } else {
        /* Version 1 has neither: the identity copies the field, a zero G removes nothing. */
        p.mag.correction[0][0] = p.mag.correction[1][1] = p.mag.correction[2][2] = 1.0f;
    }
    if (version >= 3u) {
        imu_calib_take_intrinsics(&r, &p.accel_intrinsics, p.flags & IMU_CALIB_FLAG_ACCEL_THERMAL_SCALE,
                                  p.flags & IMU_CALIB_FLAG_ACCEL_THERMAL_MISALIGNMENT);
        imu_calib_take_intrinsics(&r, &p.gyro_intrinsics, p.flags & IMU_CALIB_FLAG_GYRO_THERMAL_SCALE,
                                  p.flags & IMU_CALIB_FLAG_GYRO_THERMAL_MISALIGNMENT);
        if (!r.ok) {
            return IMU_CALIB_ERR_CONTENT;
        }
    } else {
        /* Before version 3 those flag bits meant nothing: none of their blocks exists. */
        p.flags &= IMU_CALIB_FLAGS_BEFORE_V3;
        p.accel_intrinsics.scale[0] = p.accel_intrinsics.scale[1] = p.accel_intrinsics.scale[2] = 1.0f;
        p.gyro_intrinsics.scale[0] = p.gyro_intrinsics.scale[1] = p.gyro_intrinsics.scale[2] = 1.0f;
    }
    if (r.pos != r.end || p.dtemp_tau_s < 0.0f) {
        return IMU_CALIB_ERR_CONTENT;
    }
    memcpy(out, &p, sizeof p);
    return IMU_CALIB_OK;
}

static float imu_calib_clamp(float v, float lo, float hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

static void imu_calib_thermal_bias(const imu_calib_thermal_t *th, float t_ref, float temp_c, float dtemp,
                                   float out[3])
{
    const imu_calib_segment_t *s;
    float T, d, t, terms[IMU_CALIB_TERMS];
    uint32_t i, n = th->n_segments;
    int a, k;

    out[0] = out[1] = out[2] = 0.0f;
    /* Unknown temperature: no thermal term rather than a guess. */
    if (n == 0u || !isfinite(temp_c)) {
        return;
    }
    T = imu_calib_clamp(temp_c, th->segments[0].t_min, th->segments[n - 1u].t_max);
    d = imu_calib_clamp(isnan(dtemp) ? 0.0f : dtemp, th->dt_min, th->dt_max);
    s = &th->segments[0];
    for (i = 1u; i < n; ++i) {
        if (T >= th->segments[i].t_min) {
            s = &th->segments[i];
        }
    }
    t = T - t_ref;
    terms[0] = t * t * t;
    terms[1] = t * t;
    terms[2] = t;
    terms[3] = d * d;
    terms[4] = d;
    terms[5] = t * d;
    terms[6] = 1.0f;
    for (a = 0; a < 3; ++a) {
        float sum = 0.0f;
        for (k = 0; k < IMU_CALIB_TERMS; ++k) {
            sum += s->coeffs[a][k] * terms[k];
        }
        out[a] = sum;
    }
}

static void imu_calib_correct(const imu_calib_triad_t *c, const float raw[3], const float extra[3],
                              float out[3])
{
    float d[3];
    int i;
    for (i = 0; i < 3; ++i) {
        d[i] = raw[i] - c->bias[i] - extra[i];
    }
    for (i = 0; i < 3; ++i) {
        out[i] = c->correction[i][0] * d[0] + c->correction[i][1] * d[1] + c->correction[i][2] * d[2];
    }
}

/* k(t) or s(t) of one component: c0 t + c1 t^2 + c2 t^3, by Horner. */
static float imu_calib_poly(const float c[3], float t)
{
    return t * (c[0] + t * (c[1] + t * c[2]));
}

/* M(T)^-1 (raw - b - extra) with M(T) = diag(K + k(t)) (I + S + s(t)) built at the clamped T and
   inverted by cofactors; the stored M^-1 without the triad's polynomials or a finite T. A
   determinant that is zero or not finite (polynomials that cancel K, far outside any fit) also
   falls back to the stored M^-1 rather than give infinities. */
static void imu_calib_correct_at(const imu_calib_triad_t *c, const imu_calib_intrinsics_t *in,
                                 uint32_t scale_on, uint32_t misalignment_on, float t_ref, float temp_c,
                                 const float raw[3], const float extra[3], float out[3])
{
    float k[3], u[3][3], m[3][3], adj[3][3], d[3], det, t;
    int i, j;
    if ((!scale_on && !misalignment_on) || !isfinite(temp_c)) {
        imu_calib_correct(c, raw, extra, out);
        return;
    }
    for (i = 0; i < 3; ++i) {
        k[i] = in->scale[i];
        for (j = 0; j < 3; ++j) {
            u[i][j] = i == j ? 1.0f : 0.0f;
        }
    }
    for (i = 0; i < 6; ++i) {
        u[imu_calib_off_diagonal[i][0]][imu_calib_off_diagonal[i][1]] = in->misalignment[i];
    }
    if (scale_on) {
        t = imu_calib_clamp(temp_c, in->scale_t_min, in->scale_t_max) - t_ref;
        for (i = 0; i < 3; ++i) {
            k[i] += imu_calib_poly(in->scale_coeffs[i], t);
        }
    }
    if (misalignment_on) {
        t = imu_calib_clamp(temp_c, in->misalignment_t_min, in->misalignment_t_max) - t_ref;
        for (i = 0; i < 6; ++i) {
            u[imu_calib_off_diagonal[i][0]][imu_calib_off_diagonal[i][1]] +=
                imu_calib_poly(in->misalignment_coeffs[i], t);
        }
    }
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            m[i][j] = k[i] * u[i][j];
        }
    }
    adj[0][0] = m[1][1] * m[2][2] - m[1][2] * m[2][1];
    adj[0][1] = m[0][2] * m[2][1] - m[0][1] * m[2][2];
    adj[0][2] = m[0][1] * m[1][2] - m[0][2] * m[1][1];
    adj[1][0] = m[1][2] * m[2][0] - m[1][0] * m[2][2];
    adj[1][1] = m[0][0] * m[2][2] - m[0][2] * m[2][0];
    adj[1][2] = m[0][2] * m[1][0] - m[0][0] * m[1][2];
    adj[2][0] = m[1][0] * m[2][1] - m[1][1] * m[2][0];
    adj[2][1] = m[0][1] * m[2][0] - m[0][0] * m[2][1];
    adj[2][2] = m[0][0] * m[1][1] - m[0][1] * m[1][0];
    det = m[0][0] * adj[0][0] + m[0][1] * adj[1][0] + m[0][2] * adj[2][0];
    if (det == 0.0f || !isfinite(det)) {
        imu_calib_correct(c, raw, extra, out);
        return;
    }
    for (i = 0; i < 3; ++i) {
        d[i] = raw[i] - c->bias[i] - extra[i];
    }
    for (i = 0; i < 3; ++i) {
        out[i] = (adj[i][0] * d[0] + adj[i][1] * d[1] + adj[i][2] * d[2]) / det;
    }
}

void imu_calib_apply(const imu_calib_t *p, float temp_c, float dtemp_c_per_s,
                     const float raw_acc[3], const float raw_gyro[3],
                     float acc[3], float gyro[3])
{
    float bias_acc[3], bias_gyro[3];
    imu_calib_thermal_bias(&p->accel_thermal, p->reference_temp, temp_c, dtemp_c_per_s, bias_acc);
    imu_calib_thermal_bias(&p->gyro_thermal, p->reference_temp, temp_c, dtemp_c_per_s, bias_gyro);
    imu_calib_correct_at(&p->accel, &p->accel_intrinsics, p->flags & IMU_CALIB_FLAG_ACCEL_THERMAL_SCALE,
                         p->flags & IMU_CALIB_FLAG_ACCEL_THERMAL_MISALIGNMENT, p->reference_temp, temp_c,
                         raw_acc, bias_acc, acc);
    if (p->flags & IMU_CALIB_FLAG_G_SENSITIVITY) {
        /* The bias the specific force adds, at the corrected sample; acc may alias raw_acc, which is
           why it is read only after the accel correction is complete. */
        int i;
        for (i = 0; i < 3; ++i) {
            bias_gyro[i] += p->g_sensitivity[i][0] * acc[0] + p->g_sensitivity[i][1] * acc[1]
                + p->g_sensitivity[i][2] * acc[2];
        }
    }
    imu_calib_correct_at(&p->gyro, &p->gyro_intrinsics, p->flags & IMU_CALIB_FLAG_GYRO_THERMAL_SCALE,
                         p->flags & IMU_CALIB_FLAG_GYRO_THERMAL_MISALIGNMENT, p->reference_temp, temp_c,
                         raw_gyro, bias_gyro, gyro);
}

void imu_calib_apply_mag(const imu_calib_t *p, const float raw_mag[3], float mag[3])
{
    static const float none[3] = {0.0f, 0.0f, 0.0f};
    if (!(p->flags & IMU_CALIB_FLAG_MAG)) {
        float copy[3];
        memcpy(copy, raw_mag, sizeof copy);
        memcpy(mag, copy, sizeof copy);
        return;
    }
    imu_calib_correct(&p->mag, raw_mag, none, mag);
}

void imu_calib_dtemp_init(imu_calib_dtemp_t *s)
{
    s->temp_f = 0.0f;
    s->dtemp = 0.0f;
    s->last_temp = 0.0f;
    s->started = 0;
}

float imu_calib_dtemp_update(imu_calib_dtemp_t *s, const imu_calib_t *p, float dt_s, float temp_c)
{
    float alpha, step;
    if (!s->started) {
        if (!isfinite(temp_c)) {
            return 0.0f;
        }
        s->temp_f = temp_c;
        s->last_temp = temp_c;
        s->dtemp = 0.0f;
        s->started = 1;
        return 0.0f;
    }
    if (isfinite(temp_c)) {
        s->last_temp = temp_c;
    } else {
        temp_c = s->last_temp;
    }
    if (!(dt_s > 0.0f)) {
        return s->dtemp;
    }
    alpha = dt_s / (p->dtemp_tau_s + dt_s);
    /* The filtered step itself, not the difference of two rounded temperatures: float32 keeps
       its precision where the per-sample change is a millionth of the temperature. */
    step = alpha * (temp_c - s->temp_f);
    s->temp_f += step;
    s->dtemp += alpha * (step / dt_s - s->dtemp);
    return s->dtemp;
}

const char *imu_calib_strerror(int code)
{
    switch (code) {
    case IMU_CALIB_OK: return "ok";
    case IMU_CALIB_ERR_MAGIC: return "bad magic: not an imu-station parameter blob";
    case IMU_CALIB_ERR_VERSION: return "unknown blob format version";
    case IMU_CALIB_ERR_LENGTH: return "wrong length: truncated or padded blob";
    case IMU_CALIB_ERR_CRC: return "CRC-32 mismatch: corrupted blob";
    case IMU_CALIB_ERR_CAPACITY: return "more thermal segments than IMU_CALIB_MAX_SEGMENTS";
    case IMU_CALIB_ERR_CONTENT: return "inconsistent blob content";
    case IMU_CALIB_ERR_ARG: return "NULL argument";
    default: return "unknown error";
    }
}
"""


def _fill(template: str, values: dict[str, str]) -> str:
    for key, value in values.items():
        template = template.replace(f"@{key}@", value)
    return template


def render(params: ParamsFile, station_id: str, exported_utc: int) -> dict[str, bytes]:
    """The three files of the C export, by name (header, source, blob)."""
    blob = blobfmt.build_blob(params, station_id, exported_utc)
    triads = blobfmt.thermal_triads(params)
    unit_segments = max([len(t.segments) for t in triads.values() if t is not None], default=1)
    device = params.device
    header = _fill(HEADER_TEMPLATE, {
        "DESCRIPTION": _describe(params, station_id, exported_utc, len(blob)),
        "MAX_SEGMENTS": str(max(DEFAULT_MAX_SEGMENTS, unit_segments)),
        "UNIT_SEGMENTS": str(unit_segments),
        "SERIAL": c_string_literal(str(device.get("serial", ""))),
        "MODEL": c_string_literal(str(device.get("model", ""))),
        "FIRMWARE": c_string_literal(str(device.get("firmware", ""))),
        "STATION": c_string_literal(station_id),
        "BLOB_SIZE": str(len(blob)),
        "INITIALIZER": unit_initializer(params, station_id, exported_utc),
    })
    source = _fill(SOURCE_TEMPLATE, {"VERSION": __version__})
    return {HEADER_NAME: header.encode("ascii"), SOURCE_NAME: source.encode("ascii"), BLOB_NAME: blob}


def write_c_export(params: ParamsFile, out_dir: str | Path, station_id: str, exported_utc: int) -> list[Path]:
    """Write ``imu_calib.h``, ``imu_calib.c`` and ``imu_calib.bin`` into ``out_dir``, each atomically."""
    out_dir = Path(out_dir)
    written = []
    for name, data in render(params, station_id, exported_utc).items():
        path = out_dir / name
        if name == BLOB_NAME:
            atomic_write_bytes(path, data)
        else:
            atomic_write_text(path, data.decode("ascii"))
        written.append(path)
    return written
