"""One set of blob rules: the station's reader (``parse_blob``) and the firmware loader
(``imu_calib_load`` of the exported C, compiled with gcc) accept and refuse the same blobs, with
the same error code, over thousands of corrupted blobs: field mutations with a recomputed CRC (so
they reach the content checks) and random bit flips with and without one, of a version 3 blob
with a mag section, a g-sensitivity and thermal scale and misalignment polynomials, and of the
version 1 and 2 blobs written by the station before (tests/data/blob-v1, tests/data/blob-v2).
"""

from __future__ import annotations

import math
import shutil
import struct
import subprocess
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from export_params import add_thermal_intrinsics, make_params

from protocols.crc import crc32
from station.export.firmware import blob as blobfmt
from station.export.firmware.c_source import DEFAULT_MAX_SEGMENTS, write_c_export

HARNESS = Path(__file__).with_name("test_export_harness.c")
CC = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]
N_FIELD = 2500
N_FLIPS = 1500
N_V1 = 600
N_V2 = 600
V1_BLOB = Path(__file__).parent / "data" / "blob-v1" / "imu_calib_v1_seed7.bin"
V2_BLOB = Path(__file__).parent / "data" / "blob-v2" / "imu_calib_v2_seed7_mag_g.bin"
INTRINSICS = 2 * blobfmt.INTRINSICS_SIZE

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc is needed to compile the loader")

PAYLOAD = blobfmt.HEADER_SIZE
TRIADS = PAYLOAD + 8
ACCEL_THERMAL = TRIADS + 2 * blobfmt.TRIAD_SIZE
NAN = struct.pack("<f", math.nan)
INF = struct.pack("<f", math.inf)


def with_crc(data: bytes | bytearray) -> bytes:
    out = bytearray(data)
    out[-4:] = struct.pack("<I", crc32(bytes(out[:-4])))
    return bytes(out)


def put(blob: bytes, offset: int, data: bytes) -> bytes:
    out = bytearray(blob)
    out[offset:offset + len(data)] = data
    return with_crc(out)


def field_mutation(good: bytes, rng: np.random.Generator) -> bytes:
    """A blob whose CRC is right and one field is wrong (or in an edge case)."""
    n_floats = (len(good) - 4 - PAYLOAD) // 4
    version = struct.unpack_from("<H", good, 4)[0]
    intrinsics = len(good) - 4 - INTRINSICS  # version 3: the accel, then the gyro intrinsics block
    # Version 2 on: the mag triad, then G (before the intrinsics from version 3).
    tail = (intrinsics if version == 3 else len(good) - 4) - blobfmt.TRIAD_SIZE - blobfmt.MATRIX_SIZE
    kinds: list[Callable[[], bytes]] = [
        lambda: put(good, 4, struct.pack("<H", int(rng.choice([0, 1, 2, 3, 4])))),
        # The thermal intrinsics flags (bits 6-9) toggled: in a version 3 blob a clamp of zeros is then
        # refused, in an older one they mean nothing.
        lambda: put(good, 14, struct.pack("<H", struct.unpack_from("<H", good, 14)[0]
                                          ^ (int(rng.integers(1, 16)) << 6))),
        # A clamp bound of a thermal intrinsics polynomial (scale: floats 9, 10; misalignment: 20, 21).
        lambda: put(good, intrinsics + blobfmt.INTRINSICS_SIZE * int(rng.integers(0, 2))
                    + 4 * int(rng.choice([9, 10, 20, 21])),
                    struct.pack("<f", float(rng.choice([-10.0, 60.0, 25.0, -1e30, 1e30, 0.0])))),
        lambda: put(good, tail + 12 * int(rng.integers(0, 3)), bytes(12)),
        lambda: put(good, 6, struct.pack("<H", int(rng.choice([0, 95, 97, 0xFFFF, len(good) - 4,
                                                                len(good)])))),
        lambda: put(good, 8, struct.pack("<I", int(rng.integers(0, 2**32)))),
        lambda: put(good, PAYLOAD + 4 * int(rng.integers(0, n_floats)),
                    [NAN, INF, struct.pack("<f", -math.inf)][int(rng.integers(0, 3))]),
        lambda: put(good, PAYLOAD + 4, struct.pack("<f", float(rng.choice([-1.0, -1e-30, 0.0, -0.0, 1e30])))),
        lambda: put(good, PAYLOAD, struct.pack("<f", float(rng.choice([math.inf, -math.inf, 3e38, -273.0])))),
        lambda: put(good, ACCEL_THERMAL, struct.pack("<I", int(rng.choice([0, 1, 2, 3, 4, 9, 2**31,
                                                                           2**32 - 1])))),
        lambda: put(good, ACCEL_THERMAL + 4, struct.pack("<ff", *sorted(rng.normal(0, 1, 2))[::-1])),
        lambda: put(good, ACCEL_THERMAL + 12 + int(rng.choice([0, 4, 92, 96])),
                    struct.pack("<f", float(rng.choice([-10.0, 13.5, 13.4, 13.6, 37.0, 60.0, 99.0])))),
        lambda: put(good, TRIADS + 48 * int(rng.integers(0, 2)) + 12 * int(rng.integers(0, 3)), bytes(12)),
        lambda: put(good, TRIADS + 48 * int(rng.integers(0, 2)), bytes(36)),
        lambda: with_crc(good[:-4 - 4 * int(rng.integers(1, 30))] + bytes(4)),
        lambda: with_crc(good[:-4] + bytes(4 * int(rng.integers(1, 30))) + bytes(4)),
        lambda: put(good, PAYLOAD + 4 * int(rng.integers(0, n_floats)), rng.bytes(4)),
    ]
    data = kinds[int(rng.integers(0, len(kinds)))]()
    if struct.unpack_from("<I", data, 8)[0] == len(good) and len(data) != len(good):
        data = put(data, 8, struct.pack("<I", len(data)))  # a resized blob that says its new size
    return data


def bit_flips(good: bytes, rng: np.random.Generator) -> bytes:
    out = bytearray(good)
    for _ in range(int(rng.integers(1, 4))):
        bit = int(rng.integers(0, 8 * len(out)))
        out[bit // 8] ^= 1 << (bit % 8)
    return with_crc(out) if rng.random() < 0.7 else bytes(out)


@pytest.fixture(scope="module")
def loader(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("blob_rules")
    params = add_thermal_intrinsics(make_params(seed=3, mag="accel", g_sensitivity=True))
    write_c_export(params, out, "bench-7", 1_795_000_000)
    exe = out / "harness"
    subprocess.run([*CC, "-I.", "imu_calib.c", str(HARNESS), "-lm", "-o", str(exe)], cwd=out, check=True,
                   capture_output=True, timeout=120)
    return exe, out


def c_results(exe: Path, blobs: list[bytes], work: Path) -> list[tuple[int, bool]]:
    """imu_calib_load's result and whether it left *out untouched, per blob."""
    paths = []
    for i, data in enumerate(blobs):
        path = work / f"{i}.bin"
        path.write_bytes(data)
        paths.append(str(path))
    results: list[tuple[int, bool]] = []
    for start in range(0, len(paths), 500):
        proc = subprocess.run([str(exe), "load", *paths[start:start + 500]], capture_output=True, text=True,
                              check=True, timeout=120)
        results += [(int(rc), untouched == "1") for rc, untouched in
                    (line.split() for line in proc.stdout.splitlines())]
    return results


def station_result(data: bytes) -> int:
    try:
        blobfmt.parse_blob(data, max_segments=DEFAULT_MAX_SEGMENTS)
    except blobfmt.BlobError as exc:
        assert exc.code is not None
        return exc.code
    return 0


def test_reader_and_loader_agree_on_corrupted_blobs(loader: tuple[Path, Path], tmp_path: Path) -> None:
    exe, out = loader
    good = (out / "imu_calib.bin").read_bytes()
    rng = np.random.default_rng(22)
    old, v2 = V1_BLOB.read_bytes(), V2_BLOB.read_bytes()
    blobs = [good, old, v2] + [field_mutation(good, rng) for _ in range(N_FIELD)] + \
        [bit_flips(good, rng) for _ in range(N_FLIPS)] + [field_mutation(old, rng) for _ in range(N_V1)] + \
        [field_mutation(v2, rng) for _ in range(N_V2)]
    c_side = c_results(exe, blobs, tmp_path)
    disagreements = []
    for i, (data, (code, untouched)) in enumerate(zip(blobs, c_side, strict=True)):
        assert untouched == (code != 0), f"blob {i}: *out written on failure or untouched on success"
        ours = station_result(data)
        if ours != code:
            disagreements.append((i, ours, code))
    assert not disagreements, disagreements[:10]
    codes = Counter(code for code, _ in c_side)
    # The corpus reaches every rule, not only the CRC.
    for code in (0, blobfmt.ERR_VERSION, blobfmt.ERR_LENGTH, blobfmt.ERR_CRC, blobfmt.ERR_CAPACITY,
                 blobfmt.ERR_CONTENT):
        assert codes[code] > 0, codes
    assert codes[blobfmt.ERR_CONTENT] > 500, codes


@pytest.mark.parametrize(("name", "damage", "code"), [
    ("header size 0xFFFF", lambda b: put(b, 6, struct.pack("<H", 0xFFFF)), blobfmt.ERR_CONTENT),
    ("header size at the CRC", lambda b: put(b, 6, struct.pack("<H", len(b) - 4)), blobfmt.ERR_CONTENT),
    ("NaN dT time constant", lambda b: put(b, PAYLOAD + 4, NAN), blobfmt.ERR_CONTENT),
    ("negative dT time constant", lambda b: put(b, PAYLOAD + 4, struct.pack("<f", -1.0)),
     blobfmt.ERR_CONTENT),
    ("infinite reference temperature", lambda b: put(b, PAYLOAD, INF), blobfmt.ERR_CONTENT),
    ("overlapping segments", lambda b: put(b, ACCEL_THERMAL + 12 + 96, struct.pack("<f", 13.0)),
     blobfmt.ERR_CONTENT),
    ("singular accel correction", lambda b: put(b, TRIADS, bytes(12)), blobfmt.ERR_CONTENT),
    ("nine segments", lambda b: put(b, ACCEL_THERMAL, struct.pack("<I", 9)), blobfmt.ERR_CAPACITY),
    ("singular mag correction", lambda b: put(b, len(b) - 4 - INTRINSICS - 84, bytes(36)),
     blobfmt.ERR_CONTENT),
    ("version 3 content called version 1", lambda b: put(b, 4, struct.pack("<H", 1)), blobfmt.ERR_CONTENT),
    ("version 3 content called version 2", lambda b: put(b, 4, struct.pack("<H", 2)), blobfmt.ERR_CONTENT),
    ("version 3 cut to version 2's length",
     lambda b: put(b[:-INTRINSICS - 4] + bytes(4), 8, struct.pack("<I", len(b) - INTRINSICS)),
     blobfmt.ERR_CONTENT),
    ("empty gyro scale clamp", lambda b: put(b, len(b) - 4 - blobfmt.INTRINSICS_SIZE + 4 * 9,
                                             struct.pack("<ff", 30.0, 30.0)), blobfmt.ERR_CONTENT),
    ("inverted accel misalignment clamp",
     lambda b: put(b, len(b) - 4 - INTRINSICS + 4 * 20, struct.pack("<ff", 60.0, -10.0)),
     blobfmt.ERR_CONTENT),
    ("infinite gyro misalignment coefficient", lambda b: put(b, len(b) - 8, INF), blobfmt.ERR_CONTENT),
])
def test_rules_the_two_sides_disagreed_on(loader: tuple[Path, Path], tmp_path: Path, name: str,
                                          damage: Callable[[bytes], bytes], code: int) -> None:
    exe, out = loader
    data = damage((out / "imu_calib.bin").read_bytes())
    assert c_results(exe, [data], tmp_path) == [(code, True)], name
    with pytest.raises(blobfmt.BlobError) as info:
        blobfmt.parse_blob(data, max_segments=DEFAULT_MAX_SEGMENTS)
    assert info.value.code == code, str(info.value)


def _set(array: np.ndarray, index: tuple[int, int], value: float) -> None:
    array[index] = value


@pytest.mark.parametrize(("name", "spoil"), [
    ("negative dT time constant", lambda p: setattr(p.thermal.dtemp_filter, "tau_s", -1.0)),
    ("reference temperature beyond float32", lambda p: setattr(p.thermal, "reference_temp", 1e39)),
    ("overlapping segments", lambda p: setattr(p.thermal.gyro.segments[1], "t_min", 13.0)),
    ("scale clamp empty in float32", lambda p: add_thermal_intrinsics(p, clamp=(20.0, 20.0 + 1e-9))),
    ("scale coefficient beyond float32",
     lambda p: _set(add_thermal_intrinsics(p).thermal.scale["gyro"].coeffs, (0, 0), 1e39)),
    ("zero accel scale with a scale polynomial",
     lambda p: _set(add_thermal_intrinsics(p).accel.matrix, (1, 1), 0.0)),
])
def test_the_builder_never_writes_a_blob_its_loader_refuses(name: str, spoil: Callable[[Any], None]) -> None:
    params = make_params(seed=4)
    spoil(params)
    with pytest.raises(blobfmt.BlobError) as info:
        blobfmt.build_blob(params, "st", 0)
    assert info.value.code is None, name
