"""The parameter blob: its documented layout byte by byte, a lossless round trip to float32, the
version 1 and 2 blobs of tests/data/blob-v1 and blob-v2 still read, and refusal of damaged or
impossible content with a message that says what is wrong. (The version 3 thermal intrinsics block:
tests/test_blob_thermal_intrinsics.py.)"""

from __future__ import annotations

import datetime as dt
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from export_params import make_params

from station.engines.thermal.model import ThermalSegment
from station.export.firmware import blob as blobfmt
from station.export.params.file import ParamsFile

V1_BLOBS = Path(__file__).parent / "data" / "blob-v1"
V2_BLOBS = Path(__file__).parent / "data" / "blob-v2"


def test_layout_matches_the_documented_table() -> None:
    params = make_params(seed=1, mag="accel", g_sensitivity=True)
    data = blobfmt.build_blob(params, "bench-7", 1_795_000_123)
    assert data[0:4] == b"IMUC"
    version, header_size, total, schema, flags = struct.unpack_from("<HHIHH", data, 4)
    assert (version, header_size, total, schema) == (3, 96, len(data), 1)
    assert flags == 0b111111
    created, exported = struct.unpack_from("<qq", data, 16)
    assert created == int(dt.datetime(2026, 11, 22, 10, tzinfo=dt.UTC).timestamp())
    assert exported == 1_795_000_123
    assert data[32:64] == b"SN-0042".ljust(32, b"\0")
    assert data[64:80] == b"bench-7".ljust(16, b"\0")
    assert data[80:96] == bytes(16)
    assert struct.unpack_from("<I", data, len(data) - 4)[0] == zlib.crc32(data[:-4])
    t_ref, tau = struct.unpack_from("<ff", data, 96)
    assert (t_ref, tau) == (25.0, 12.0)
    correction = np.array(struct.unpack_from("<9f", data, 104)).reshape(3, 3)
    assert np.allclose(correction, params.accel.correction, rtol=1e-6)
    assert struct.unpack_from("<3f", data, 104 + 36) == tuple(np.float32(params.accel.bias).tolist())
    n, dt_min, dt_max = struct.unpack_from("<Iff", data, 104 + 96)
    assert (n, dt_min, dt_max) == (3, -0.5, 0.5)
    seg0 = struct.unpack_from("<23f", data, 104 + 96 + 12)
    assert seg0[:2] == (-10.0, 13.5)
    assert np.array_equal(np.array(seg0[2:]), np.float32(params.thermal.accel.segments[0].coeffs).ravel())
    mag_at = 104 + 96 + 2 * (12 + 3 * 92)
    mag = params.other["mag"]
    assert np.array_equal(struct.unpack_from("<9f", data, mag_at), np.float32(mag["correction"]).ravel())
    assert np.array_equal(struct.unpack_from("<3f", data, mag_at + 36), np.float32(mag["bias"]))
    assert np.array_equal(struct.unpack_from("<9f", data, mag_at + 48),
                          np.float32(params.gyro.extra["g_sensitivity"]).ravel())
    # Version 3: two thermal intrinsics blocks, here without polynomials: K = 1, S = 0, zeros.
    intrinsics_at = mag_at + 48 + 36
    for k in range(2):
        block = struct.unpack_from("<40f", data, intrinsics_at + 160 * k)
        assert block == (1.0, 1.0, 1.0, *[0.0] * 37)
    assert len(data) == 96 + 8 + 2 * 48 + 2 * (12 + 3 * 92) + 48 + 36 + 2 * 160 + 4


def test_round_trip_to_float32() -> None:
    params = make_params(seed=2, mag="accel", g_sensitivity=True)
    back = blobfmt.parse_blob(blobfmt.build_blob(params, "st", 0))
    assert back.serial == "SN-0042" and back.station_id == "st" and back.flags == 63
    assert back.format_version == 3 and back.reference_matrix == {}
    mag = params.other["mag"]
    assert np.allclose(back.mag.correction, mag["correction"], rtol=1e-6, atol=1e-7)
    assert np.allclose(back.mag.bias, mag["bias"], rtol=1e-7)
    assert np.allclose(back.g_sensitivity, params.gyro.extra["g_sensitivity"], rtol=1e-7, atol=0)
    assert np.allclose(back.accel.correction, params.accel.correction, rtol=1e-6, atol=1e-7)
    assert np.allclose(back.gyro.bias, params.gyro.bias, rtol=1e-7)
    temp = np.linspace(-20, 70, 50)
    dtemp = np.linspace(-2, 2, 50)
    for name in ("accel", "gyro"):
        ours = getattr(params.thermal, name).evaluate(temp, dtemp, 25.0)
        theirs = getattr(back.thermal, name).evaluate(temp, dtemp, back.reference_temp)
        assert np.allclose(ours, theirs, rtol=1e-6, atol=1e-9)


def test_sections_absent_become_identity_and_zero_segments() -> None:
    params = make_params(seed=3, gyro=False, thermal=False)
    data = blobfmt.build_blob(params, "st", 0)
    back = blobfmt.parse_blob(data)
    assert back.flags == blobfmt.FLAG_ACCEL and back.thermal is None
    assert back.mag is None and back.g_sensitivity is None
    assert np.array_equal(back.gyro.matrix, np.eye(3)) and np.array_equal(back.gyro.bias, np.zeros(3))
    tail = struct.unpack_from("<21f", data, len(data) - 4 - 320 - 84)
    assert tail == (1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, *[0] * 9)  # identity mag, zero G


def test_a_mag_section_alone_is_a_blob() -> None:
    params = make_params(seed=4, accel=False, gyro=False, thermal=False, mag="sensor", noise=True)
    back = blobfmt.parse_blob(blobfmt.build_blob(params, "st", 0))
    assert back.flags == blobfmt.FLAG_MAG and back.thermal is None and back.g_sensitivity is None
    assert np.allclose(back.mag.matrix, params.other["mag"]["matrix"], rtol=1e-6, atol=1e-7)
    for cal in (back.accel, back.gyro):
        assert np.array_equal(cal.matrix, np.eye(3)) and np.array_equal(cal.bias, np.zeros(3))


@pytest.mark.parametrize(("name", "seed", "sections"), [
    ("imu_calib_v1_seed7.bin", 7, {}),
    ("imu_calib_v1_seed8_accel.bin", 8, {"gyro": False, "thermal": False}),
])
def test_version_1_blobs_still_read(name: str, seed: int, sections: dict) -> None:
    """Blobs written by the station before format version 2 (tests/data/blob-v1/README.md)."""
    data = (V1_BLOBS / name).read_bytes()
    assert struct.unpack_from("<H", data, 4)[0] == 1
    back = blobfmt.parse_blob(data)
    params = make_params(seed=seed, **sections)
    assert back.format_version == 1 and back.mag is None and back.g_sensitivity is None
    assert back.flags == blobfmt.flags_of(params) and back.station_id == "v1-fixture"
    assert np.allclose(back.accel.correction, params.accel.correction, rtol=1e-6, atol=1e-7)
    assert np.array_equal(back.accel.bias, np.float32(params.accel.bias))
    if params.thermal is not None:
        temp, dtemp = np.linspace(-20, 70, 40), np.linspace(-1, 1, 40)
        for triad in ("accel", "gyro"):
            ours = getattr(params.thermal, triad).evaluate(temp, dtemp, 25.0)
            assert np.allclose(getattr(back.thermal, triad).evaluate(temp, dtemp, back.reference_temp), ours,
                               rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize(("name", "sections"), [
    ("imu_calib_v2_seed7_mag_g.bin", {"seed": 7, "mag": "accel", "g_sensitivity": True}),
    ("imu_calib_v2_seed9.bin", {"seed": 9}),
])
def test_version_2_blobs_still_read(name: str, sections: dict) -> None:
    """Blobs written by the station before format version 3 (tests/data/blob-v2/README.md): every
    section as it was, no thermal intrinsics."""
    data = (V2_BLOBS / name).read_bytes()
    assert struct.unpack_from("<H", data, 4)[0] == 2
    back = blobfmt.parse_blob(data)
    params = make_params(**sections)
    assert back.format_version == 2 and back.flags == blobfmt.flags_of(params)
    assert back.station_id == "v2-fixture" and back.reference_matrix == {}
    assert back.thermal is not None and back.thermal.scale == {} and back.thermal.misalignment == {}
    assert np.allclose(back.gyro.correction, params.gyro.correction, rtol=1e-6, atol=1e-7)
    assert np.array_equal(back.gyro.bias, np.float32(params.gyro.bias))
    assert (back.mag is None) == ("mag" not in sections)
    if back.mag is not None:
        assert np.allclose(back.mag.correction, params.other["mag"]["correction"], rtol=1e-6, atol=1e-7)
        assert np.allclose(back.g_sensitivity, params.gyro.extra["g_sensitivity"], rtol=1e-7, atol=0)
    temp, dtemp = np.linspace(-20, 70, 40), np.linspace(-1, 1, 40)
    for triad in ("accel", "gyro"):
        ours = getattr(params.thermal, triad).evaluate(temp, dtemp, 25.0)
        assert np.allclose(getattr(back.thermal, triad).evaluate(temp, dtemp, back.reference_temp), ours,
                           rtol=1e-6, atol=1e-9)


def test_long_strings_cut_on_a_character_boundary() -> None:
    params = make_params(seed=4, device={"serial": "é" * 20})
    back = blobfmt.parse_blob(blobfmt.build_blob(params, "station-with-a-long-name", 0))
    assert back.serial == "é" * 15 and back.station_id == "station-with-a-"


@pytest.mark.parametrize(("damage", "message"), [
    (lambda b: b"ABCD" + b[4:], "bad magic"),
    (lambda b: b[:4] + struct.pack("<H", 9) + b[6:], "version 9 is unknown"),
    (lambda b: b[:-3], "bytes long but"),
    (lambda b: b[:6], "shorter than"),
    (lambda b: b[:200] + bytes([b[200] ^ 4]) + b[201:], "CRC-32 mismatch"),
])
def test_damage_refused_with_a_reason(damage, message: str) -> None:
    data = blobfmt.build_blob(make_params(seed=5), "st", 0)
    with pytest.raises(blobfmt.BlobError, match=message):
        blobfmt.parse_blob(damage(data))


def test_impossible_parameter_files_refused() -> None:
    with pytest.raises(blobfmt.BlobError, match="nothing to export"):
        blobfmt.build_blob(ParamsFile(), "st", 0)
    noise_only = make_params(seed=6, accel=False, gyro=False, thermal=False, noise=True)
    with pytest.raises(blobfmt.BlobError, match="no accel, gyro, thermal or mag section: nothing to export"):
        blobfmt.build_blob(noise_only, "st", 0)
    params = make_params(seed=6)
    segs = params.thermal.accel.segments
    segs[0], segs[1] = segs[1], segs[0]
    with pytest.raises(blobfmt.BlobError, match="increasing order"):
        blobfmt.build_blob(params, "st", 0)
    params = make_params(seed=6)
    params.thermal.gyro.segments[1] = ThermalSegment(20.0, 20.0, np.zeros((3, 7)))
    with pytest.raises(blobfmt.BlobError, match="must be below"):
        blobfmt.build_blob(params, "st", 0)
