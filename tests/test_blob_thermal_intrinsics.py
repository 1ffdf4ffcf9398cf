"""Blob format version 3: the thermal intrinsics blocks (module docstring of
``station.export.firmware.blob``) byte by byte, the flags that say which polynomials are there, and
the round trip through ``parse_blob`` to float32: the polynomials read back evaluate as the
parameter file's, and a parameter file rebuilt from the blob corrects as the original does.

Tolerances: a float32 coefficient is within 2^-24 relative of its float64 value, so k(t), s(t) agree
within 2^-24 sum_p |c_p| |t|^p; corrected samples within 1e-6 relative (float32 matrices).
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from export_params import add_thermal_intrinsics, make_params
from test_blob_rules import put

from station.engines.shared.correction import apply_calibration
from station.engines.shared.sensor_model import SensorCalibration
from station.export.firmware import blob as blobfmt

INTRINSICS_FLOATS = 40  # 3 K + 6 S + (2 + 3 x 3) scale + (2 + 6 x 3) misalignment


def intrinsics_blocks(data: bytes) -> list[tuple[float, ...]]:
    """The accel and gyro blocks: the last 2 x 160 bytes before the CRC."""
    start = len(data) - 4 - 2 * 4 * INTRINSICS_FLOATS
    return [struct.unpack_from(f"<{INTRINSICS_FLOATS}f", data, start + 4 * INTRINSICS_FLOATS * k)
            for k in range(2)]


def test_block_layout_matches_the_documented_table() -> None:
    params = add_thermal_intrinsics(make_params(seed=1, mag="accel", g_sensitivity=True), seed=1,
                                    scale_powers=(1, 3), misalignment_powers=(2,), clamp=(-15.0, 55.0))
    data = blobfmt.build_blob(params, "st", 0)
    assert blobfmt.INTRINSICS_SIZE == 4 * INTRINSICS_FLOATS
    assert struct.unpack_from("<H", data, 4)[0] == 3
    assert struct.unpack_from("<H", data, 14)[0] == 0b1111111111
    # The blocks have a fixed size: a blob without polynomials is as long.
    assert len(data) == len(blobfmt.build_blob(make_params(seed=1, mag="accel", g_sensitivity=True), "st", 0))
    for name, block in zip(("accel", "gyro"), intrinsics_blocks(data), strict=True):
        cal = getattr(params, name)
        k = np.diag(cal.matrix)
        assert np.array_equal(block[0:3], np.float32(k))
        s = [cal.matrix[i, j] / k[i] for i, j in ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))]
        assert np.array_equal(block[3:9], np.float32(s))
        scale, mis = params.thermal.scale[name], params.thermal.misalignment[name]
        assert block[9:11] == (-15.0, 55.0) and block[20:22] == (-15.0, 55.0)
        coeffs = np.array(block[11:20]).reshape(3, 3)  # per axis: t, t^2, t^3
        assert np.array_equal(coeffs[:, [0, 2]], np.float32(scale.coeffs)) and not coeffs[:, 1].any()
        coeffs = np.array(block[22:40]).reshape(6, 3)
        assert np.array_equal(coeffs[:, 1], np.float32(mis.coeffs[:, 0])) and not coeffs[:, [0, 2]].any()


@pytest.mark.parametrize(("kw", "flags"), [
    ({}, 0b1111),
    ({"triads": ("gyro",)}, 0b1100),
    ({"triads": ("accel",), "misalignment": False}, 0b0001),
])
def test_flags_say_which_polynomials_are_there(kw: dict, flags: int) -> None:
    params = add_thermal_intrinsics(make_params(seed=2), **kw)
    data = blobfmt.build_blob(params, "st", 0)
    assert struct.unpack_from("<H", data, 14)[0] >> 6 == flags
    back = blobfmt.parse_blob(data)
    assert set(back.thermal.scale) == set(params.thermal.scale)
    assert set(back.thermal.misalignment) == set(params.thermal.misalignment)
    for name, block in zip(("accel", "gyro"), intrinsics_blocks(data), strict=True):
        if name not in params.thermal.scale and name not in params.thermal.misalignment:
            # Neither polynomial: K = 1, S = 0 and zeros, whatever the section's matrix.
            assert block == (1.0, 1.0, 1.0, *[0.0] * 37)
            assert name not in back.reference_matrix


def test_round_trip_to_float32() -> None:
    params = add_thermal_intrinsics(make_params(seed=3, mag="accel", g_sensitivity=True), seed=3,
                                    scale_powers=(1, 2, 3), misalignment_powers=(1, 3))
    back = blobfmt.parse_blob(blobfmt.build_blob(params, "st", 0))
    assert back.format_version == 3
    temp = np.linspace(-40.0, 90.0, 131)
    for key in ("scale", "misalignment"):
        for name, ours in getattr(params.thermal, key).items():
            theirs = getattr(back.thermal, key)[name]
            assert (theirs.t_min, theirs.t_max) == (ours.t_min, ours.t_max)
            a, b = ours.evaluate(temp, 25.0), theirs.evaluate(temp, back.reference_temp)
            # Each coefficient rounded to float32 (relative 2^-24): |a - b| <= 2^-24 sum_p |c_p| |t|^p.
            t = np.abs(np.clip(temp, ours.t_min, ours.t_max) - 25.0)
            bound = np.stack([t**p for p in ours.powers], axis=-1) @ np.abs(ours.coeffs).T * 2.0**-24
            assert np.all(np.abs(a - b) <= bound * (1 + 1e-9) + 1e-15)
            assert np.abs(a).max() > (1e-4 if key == "scale" else 1e-6)  # not a round trip of zeros
    for name in ("accel", "gyro"):
        assert np.allclose(back.reference_matrix[name], getattr(params, name).matrix, rtol=1e-7, atol=1e-9)
    # The blob's parameters, put back into a parameter file's thermal section, correct as the file does.
    rng = np.random.default_rng(4)
    n = 500
    temp = rng.uniform(-30.0, 80.0, n)
    acc, gyro = rng.normal(0.0, 6.0, (n, 3)), rng.normal(0.0, 2.0, (n, 3))
    ours = apply_calibration(acc, gyro, temp, np.zeros(n), params.accel, params.gyro, params.thermal,
                             params.gyro.extra["g_sensitivity"])
    cals = [SensorCalibration(back.reference_matrix[name], getattr(back, name).bias)
            for name in ("accel", "gyro")]
    theirs = apply_calibration(acc, gyro, temp, np.zeros(n), *cals, back.thermal, back.g_sensitivity)
    for a, b in zip(ours, theirs, strict=True):
        assert np.max(np.abs(a - b) / np.maximum(1.0, np.abs(a))) < 1e-6


def test_old_versions_read_without_intrinsics_even_with_the_bits_set() -> None:
    """Bits 6-9 meant nothing before version 3: a version 2 blob that has them set reads with them
    clear (as the C loader reads it), not as a blob with polynomials it does not hold."""
    params = make_params(seed=5)
    v3 = blobfmt.build_blob(params, "st", 0)
    v2 = put(v3[:-4 - 2 * blobfmt.INTRINSICS_SIZE] + bytes(4), 4, struct.pack("<H", 2))
    v2 = put(v2, 8, struct.pack("<I", len(v2)))
    flags = struct.unpack_from("<H", v2, 14)[0]
    back = blobfmt.parse_blob(put(v2, 14, struct.pack("<H", flags | 0b1111000000)))
    assert back.format_version == 2 and back.flags == flags and back.thermal.scale == {}
