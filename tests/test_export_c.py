"""The exported C, compiled with gcc and g++ and linked with an independent harness
(tests/test_export_harness.c), against ``apply_calibration``, ``apply_mag`` and ``estimate_dtemp``
(what ``imu-station apply`` computes), on blobs of this version and on the version 1 blobs of
tests/data/blob-v1. (The thermal scale and misalignment, and version 2 blobs:
tests/test_c_export_thermal_intrinsics.py.)

Tolerances: corrected samples agree with the float64 reference within 2e-6 relative to the
sample's magnitude (max(1, |raw|, |ref|) per row and sensor): float32 parameters and arithmetic give
about 2.5e-7 (a few float32 ulps). The dT filter (float32 state) agrees within 2e-4 of the largest
|dT| (measured 6e-5).
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from export_params import BREAKS, make_params

from protocols.crc import crc32
from station.engines.shared.correction import apply_calibration, apply_mag
from station.engines.thermal.model import estimate_dtemp
from station.export.firmware import blob as blobfmt
from station.export.firmware.c_source import c_comment_text, c_string_literal, write_c_export
from station.export.params.sections import g_sensitivity, mag_calibration

HARNESS = Path(__file__).with_name("test_export_harness.c")
V1_BLOBS = Path(__file__).parent / "data" / "blob-v1"
EXPORTED_UTC = 1_795_000_000
CC = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]
CXX = ["g++", "-std=c++11", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-x", "c++"]
STRICT = ["-Wconversion", "-Wdouble-promotion", "-Wshadow", "-Wcast-align", "-Wundef", "-Wstrict-prototypes",
          "-Wmissing-prototypes"]

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("g++") is None,
                                reason="gcc and g++ are needed to compile the exported C")


def run(cmd: list[str], cwd: Path) -> str:
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def build(out: Path, variant: str) -> Path:
    """Harness + exported code: 'c' all C99, 'cxx' all C++, 'mixed' C library with a C++ harness."""
    exe = out / f"harness_{variant}"
    if variant == "c":
        run([*CC, "-I.", "imu_calib.c", str(HARNESS), "-lm", "-o", str(exe)], out)
    elif variant == "cxx":
        run([*CXX, "-I.", "imu_calib.c", str(HARNESS), "-o", str(exe)], out)
    else:
        run([*CC, "-c", "imu_calib.c", "-o", "lib.o"], out)
        run([*CXX, "-I.", "-c", str(HARNESS), "-o", "harness.o"], out)
        run(["g++", "lib.o", "harness.o", "-lm", "-o", str(exe)], out)
    return exe


@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = tmp_path_factory.mktemp("c_export")
    params = make_params(seed=3, mag="accel", g_sensitivity=True)
    write_c_export(params, out, "bench-7", EXPORTED_UTC)
    return {"dir": out, "params": params, "exe": {v: build(out, v) for v in ("c", "cxx", "mixed")}}


def random_inputs(n: int, seed: int) -> np.ndarray:
    """float32 rows (temp, dtemp, acc xyz, gyro xyz, mag xyz): in range, outside it, on segment
    boundaries, beyond the dT clamp, with unknown (NaN, inf) temperature or rate, and a few samples
    without a field (NaN)."""
    rng = np.random.default_rng(seed)
    rows = np.zeros((n, 11), dtype=np.float32)
    rows[:, 0] = rng.uniform(-30.0, 80.0, n)
    rows[:, 1] = rng.uniform(-2.0, 2.0, n)
    rows[:, 2:5] = rng.normal(0.0, 6.0, (n, 3))
    rows[:, 5:8] = rng.normal(0.0, 2.0, (n, 3))
    rows[:, 8:11] = rng.normal(0.0, 40.0, (n, 3))
    rows[50:53, 8:11] = np.nan
    rows[: len(BREAKS), 0] = BREAKS
    rows[10:20, 0] = np.nan
    rows[20:25, 0] = np.inf
    rows[25:30, 0] = -np.inf
    rows[30:40, 1] = np.nan
    rows[40:45, 1] = np.inf
    return rows


def reference(params, rows: np.ndarray) -> np.ndarray:
    """What ``imu-station apply`` computes (``apply_params``: every section, g-sensitivity, mag)."""
    r = rows.astype(np.float64)
    acc, gyro = apply_calibration(r[:, 2:5], r[:, 5:8], r[:, 0], r[:, 1], params.accel, params.gyro,
                                  params.thermal, g_sensitivity(params))
    return np.hstack([acc, gyro, apply_mag(r[:, 8:11], mag_calibration(params))])


def c_apply(exe: Path, blob: Path, rows: np.ndarray, work: Path) -> tuple[np.ndarray, str]:
    src, dst = work / "in.f32", work / "out.f32"
    rows.astype("<f4").tofile(src)
    stdout = run([str(exe), "apply", str(blob), str(src), str(dst)], work)
    return np.fromfile(dst, dtype="<f4").reshape(-1, 9).astype(np.float64), stdout


def relative_error(got: np.ndarray, ref: np.ndarray, rows: np.ndarray) -> float:
    """The largest error per sensor relative to max(1, |raw|, |ref|) of that row and sensor; a
    sample unknown (NaN) on one side must be unknown on the other."""
    assert np.array_equal(np.isnan(got), np.isnan(ref))
    worst = 0.0
    for k in range(got.shape[1] // 3):
        out, raw = slice(3 * k, 3 * k + 3), slice(2 + 3 * k, 5 + 3 * k)
        scale = np.maximum(1.0, np.maximum(np.abs(ref[:, out]).max(axis=1), np.abs(rows[:, raw]).max(axis=1)))
        err = np.abs(got[:, out] - ref[:, out]).max(axis=1) / scale
        worst = max(worst, float(np.nanmax(err)))
    return worst


@pytest.mark.parametrize("variant", ["c", "cxx", "mixed"])
def test_apply_agrees_with_station_apply(unit: dict, variant: str, tmp_path: Path) -> None:
    rows = random_inputs(4000, seed=11)
    got, stdout = c_apply(unit["exe"][variant], unit["dir"] / "imu_calib.bin", rows, tmp_path)
    assert "unit_equal 1" in stdout, "the header's const initializer differs from the blob"
    assert "unit_same_output 1" in stdout
    assert f"flags {0b111111}" in stdout
    ref = reference(unit["params"], rows)
    assert np.all(np.isfinite(got[:, :6])) and np.isnan(got[50:53, 6:]).all()
    assert relative_error(got, ref, rows) < 2e-6
    # Thermal, g-sensitivity and mag terms really are in play: without each the answers differ far
    # beyond the tolerance.
    p = unit["params"]
    r = rows.astype(np.float64)
    no_thermal = np.hstack([*apply_calibration(r[:, 2:5], r[:, 5:8], None, None, p.accel, p.gyro, None,
                                               g_sensitivity(p)), ref[:, 6:]])
    assert relative_error(no_thermal, ref, rows) > 1e-3
    no_g = np.hstack([*apply_calibration(r[:, 2:5], r[:, 5:8], r[:, 0], r[:, 1], p.accel, p.gyro, p.thermal),
                      ref[:, 6:]])
    assert relative_error(no_g, ref, rows) > 2e-5
    assert relative_error(np.hstack([ref[:, :6], r[:, 8:11]]), ref, rows) > 1e-2


@pytest.mark.parametrize("sections", [
    {"thermal": False},
    {"gyro": False},
    {"accel": False, "thermal": True},
    {"breaks": (0.0, 50.0), "dtemp_terms": False},
    {"breaks": tuple(np.linspace(-20.0, 60.0, 9)), "dtemp_terms": True},
    {"accel": False, "gyro": False, "thermal": False, "mag": "sensor"},
    {"thermal": False, "mag": "accel", "g_sensitivity": True},
    {"accel": False, "thermal": False, "g_sensitivity": True},
])
def test_apply_with_other_sections(sections: dict, tmp_path: Path) -> None:
    params = make_params(seed=5, **sections)
    write_c_export(params, tmp_path, "st", EXPORTED_UTC)
    exe = build(tmp_path, "c")
    rows = random_inputs(600, seed=12)
    got, stdout = c_apply(exe, tmp_path / "imu_calib.bin", rows, tmp_path)
    assert "unit_equal 1" in stdout
    assert f"flags {blobfmt.flags_of(params)}" in stdout
    assert relative_error(got, reference(params, rows), rows) < 2e-6
    if "mag" not in sections:
        # No mag section: imu_calib_apply_mag hands the raw field back bit for bit.
        assert np.array_equal(got[:, 6:].astype(np.float32), rows[:, 8:11], equal_nan=True)


@pytest.mark.parametrize(("name", "seed", "sections"), [
    ("imu_calib_v1_seed7.bin", 7, {}),
    ("imu_calib_v1_seed8_accel.bin", 8, {"gyro": False, "thermal": False}),
])
def test_version_1_blobs_load_and_apply(unit: dict, name: str, seed: int, sections: dict,
                                        tmp_path: Path) -> None:
    """The loader of this version reads the blobs written before the mag section existed
    (tests/data/blob-v1) and corrects as the station does with the same parameters."""
    blob = V1_BLOBS / name
    for variant in ("c", "cxx"):
        assert run([str(unit["exe"][variant]), "load", str(blob)], tmp_path).split() == ["0", "0"]
    rows = random_inputs(600, seed=13)
    got, stdout = c_apply(unit["exe"]["c"], blob, rows, tmp_path)
    params = make_params(seed=seed, **sections)
    assert f"flags {blobfmt.flags_of(params)}" in stdout
    assert relative_error(got, reference(params, rows), rows) < 2e-6
    assert np.array_equal(got[:, 6:].astype(np.float32), rows[:, 8:11], equal_nan=True)


def test_dtemp_filter_matches_station(unit: dict, tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    dt = rng.uniform(0.008, 0.012, 30000)
    dt[[100, 2000, 2001]] = 0.0  # repeated timestamps: the filter holds
    t_s = np.concatenate([[0.0], np.cumsum(dt)])
    temp = 20 + 0.05 * t_s + 0.5 * np.sin(t_s / 20) + rng.normal(0, 0.01, len(t_s))
    temp32 = temp.astype(np.float32)
    # Unknown readings (leading, single, a run): the station holds the last known one, so must C.
    temp32[[0, 1, 500, 9000, 9001, 9002]] = np.nan
    filled = temp32.astype(np.float64)
    known = np.isfinite(filled)
    filled = filled[np.maximum.accumulate(np.where(known, np.arange(len(filled)), 0))]
    filled[: np.argmax(known)] = filled[np.argmax(known)]
    step = np.concatenate([[0.0], np.diff(t_s)]).astype(np.float32)
    ref = estimate_dtemp(np.concatenate([[0.0], np.cumsum(step[1:].astype(np.float64))]), filled,
                         unit["params"].thermal.dtemp_filter)
    src, dst = tmp_path / "in.f32", tmp_path / "out.f32"
    np.stack([step, temp32], axis=1).astype("<f4").tofile(src)
    run([str(unit["exe"]["c"]), "dtemp", str(unit["dir"] / "imu_calib.bin"), str(src), str(dst)], tmp_path)
    got = np.fromfile(dst, dtype="<f4").astype(np.float64)
    assert np.max(np.abs(got - ref)) < 2e-4 * np.max(np.abs(ref))
    assert 0.03 < np.max(ref) < 0.1  # the test signal's rate is really there (0.05 degC/s + wave)


def blob_with(blob: bytes, offset: int, data: bytes, fix_crc: bool) -> bytes:
    out = bytearray(blob)
    out[offset:offset + len(data)] = data
    if fix_crc:
        out[-4:] = struct.pack("<I", crc32(bytes(out[:-4])))
    return bytes(out)


def test_damaged_blobs_rejected_with_distinct_codes(unit: dict, tmp_path: Path) -> None:
    good = (unit["dir"] / "imu_calib.bin").read_bytes()
    first_segment = blobfmt.HEADER_SIZE + 8 + 2 * blobfmt.TRIAD_SIZE + blobfmt.THERMAL_HEAD_SIZE
    v1_accel = (V1_BLOBS / "imu_calib_v1_seed8_accel.bin").read_bytes()
    nine = blobfmt.build_blob(make_params(seed=1, breaks=tuple(np.linspace(-10.0, 60.0, 10))), "st", 0)
    cases = {
        "good": (good, 0),
        "magic": (b"IMUX" + good[4:], -1),
        "version": (blob_with(good, 4, struct.pack("<H", 4), fix_crc=True), -2),
        "version_crc_untouched": (blob_with(good, 4, struct.pack("<H", 4), fix_crc=False), -2),
        "version_0": (blob_with(good, 4, struct.pack("<H", 0), fix_crc=True), -2),
        "version_3_called_1": (blob_with(good, 4, struct.pack("<H", 1), fix_crc=True), -6),
        "version_3_called_2": (blob_with(good, 4, struct.pack("<H", 2), fix_crc=True), -6),
        "singular_mag": (blob_with(good, len(good) - 4 - 320 - 84, bytes(36), fix_crc=True), -6),
        "nan_g_sensitivity": (blob_with(good, len(good) - 4 - 320 - 4, struct.pack("<f", np.nan),
                                        fix_crc=True), -6),
        "nan_intrinsics": (blob_with(good, len(good) - 8, struct.pack("<f", np.nan), fix_crc=True), -6),
        "version_1_fixture": ((V1_BLOBS / "imu_calib_v1_seed7.bin").read_bytes(), 0),
        "version_1_truncated": (v1_accel[:-1], -3),
        "truncated": (good[:-1], -3),
        "header_only": (good[:blobfmt.HEADER_SIZE], -3),
        "tiny": (good[:5], -3),
        "padded": (good + b"\0", -3),
        "bitflip_payload": (blob_with(good, 120, bytes([good[120] ^ 0x10]), fix_crc=False), -4),
        "bitflip_serial": (blob_with(good, 33, bytes([good[33] ^ 0x01]), fix_crc=False), -4),
        "bitflip_crc": (good[:-1] + bytes([good[-1] ^ 0x80]), -4),
        "too_many_segments": (nine, -5),
        "t_min_above_t_max": (blob_with(good, first_segment, struct.pack("<f", 99.0), fix_crc=True), -6),
    }
    paths = []
    for name, (data, _) in cases.items():
        path = tmp_path / f"{name}.bin"
        path.write_bytes(data)
        paths.append(str(path))
    for variant in ("c", "cxx"):
        lines = run([str(unit["exe"][variant]), "load", *paths], tmp_path).split()
        results = dict(zip(cases, zip(lines[0::2], lines[1::2], strict=True), strict=True))
        for name, (_, code) in cases.items():
            rc, untouched = results[name]
            assert int(rc) == code, f"{name}: {rc}"
            assert untouched == ("0" if code == 0 else "1"), f"{name}: *out was written on failure"
    # The station's own reader refuses the same blobs.
    for name, (data, code) in cases.items():
        if code == 0:
            blobfmt.parse_blob(data)
        elif name != "too_many_segments":
            with pytest.raises(blobfmt.BlobError):
                blobfmt.parse_blob(data)


HOSTILE = {
    "serial": '"*/ #include <x> \n',
    "model": "*/ int injected_symbol = 1; /* ??/ \\",
    "firmware": 'v1\r\n#error boom\n// \\\n?""?/**/é',
}


def test_hostile_unit_strings_cannot_break_or_inject(tmp_path: Path) -> None:
    station = "*/\n#x é"
    params = make_params(seed=2, device=dict(HOSTILE))
    write_c_export(params, tmp_path, station, EXPORTED_UTC)
    header = (tmp_path / "imu_calib.h").read_text()
    for text in (*HOSTILE.values(), station):
        assert c_string_literal(text) in header
    directives = [line.split()[0] for line in header.splitlines() if line.lstrip().startswith("#")]
    assert set(directives) <= {"#ifndef", "#define", "#include", "#ifdef", "#if", "#error", "#endif"}
    assert sum(line.startswith("#error") for line in header.splitlines()) == 1  # ours, under #if
    for variant in ("c", "cxx"):
        exe = build(tmp_path, variant)
        stdout = run([str(exe), "strings"], tmp_path)
        got = {line.split()[0]: bytes(int(h, 16) for h in line.split()[1:]) for line in stdout.splitlines()}
        for key in HOSTILE:
            assert got[key] == HOSTILE[key].encode("utf-8")
        assert got["station"] == station.encode("utf-8")
        assert got["unit_serial"] == HOSTILE["serial"].encode("utf-8")
    run(["gcc", "-std=c99", "-c", "imu_calib.c", "-o", "lib.o"], tmp_path)
    assert "injected_symbol" not in run(["nm", "lib.o"], tmp_path)


def test_comment_and_literal_escaping() -> None:
    assert c_string_literal('a"b\\c?\n') == '"a\\042b\\134c\\077\\012"'
    assert c_string_literal("é") == '"\\303\\251"'
    for text in ("*/", "/*", "*//*", "/*/", "**/", "x*/*/y"):
        escaped = c_comment_text(text)
        assert "*/" not in escaped and "/*" not in escaped


def test_exported_code_is_plain_c99_without_allocation(unit: dict) -> None:
    out = unit["dir"]
    allowed = {"<stdint.h>", "<stddef.h>", "<string.h>", "<math.h>", '"imu_calib.h"'}
    for name in ("imu_calib.h", "imu_calib.c"):
        text = (out / name).read_text()
        includes = set(re.findall(r"^#include\s+(\S+)", text, flags=re.M))
        assert includes <= allowed, includes
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf|fopen|static\s+imu_calib_t)\b", text)
    run([*CC, *STRICT, "-c", "imu_calib.c", "-o", "strict.o"], out)
    run([*CXX, "-Wconversion", "-Wshadow", "-c", "imu_calib.c", "-o", "strict_cxx.o"], out)
