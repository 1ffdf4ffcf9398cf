"""The exported C with thermal scale-factor and misalignment polynomials (``thermal.scale``,
``thermal.misalignment``): ``imu_calib_apply`` builds M(T) = diag(K + k(t)) (I + S + s(t)) at the
clamped T, inverts it and applies it, from the blob (version 3) and from the header's linked-in
parameters alike, compiled with gcc and g++ and driven by tests/test_export_harness.c.

References: ``apply_calibration`` (what ``imu-station apply`` computes), and, independently of the
station's intrinsics code, samples made from a known truth with numpy.polyval's M(T) (the C must
give the truth back). Tolerance: 2e-6 relative to max(1, |raw|, |ref|) per row and sensor, as for
the static export (tests/test_export_c.py): float32 parameters, a float32 M(T) and its float32
cofactor inverse give a few float32 ulps (measured: see ``test_apply_with_thermal_intrinsics``).
Version 2 blobs (tests/data/blob-v2, written before version 3) still load and give what the
station computes from the parameters they were written from.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from export_params import add_thermal_intrinsics, make_params
from test_export_c import EXPORTED_UTC, build, c_apply, random_inputs, reference, relative_error, run

from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.intrinsics import OFF_DIAGONAL, TempPolynomial
from station.export.firmware import blob as blobfmt
from station.export.firmware.c_source import write_c_export

V2_BLOBS = Path(__file__).parent / "data" / "blob-v2"
TOLERANCE = 2e-6
CLAMP = (-10.0, 60.0)

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None or shutil.which("g++") is None,
                                reason="gcc and g++ are needed to compile the exported C")


def spanning_inputs(n: int, seed: int) -> np.ndarray:
    """``random_inputs`` with temperatures from 30 degC below the clamp to 30 above it, the clamp's
    ends and T_ref exactly, and unknown temperatures kept where ``random_inputs`` puts them."""
    rows = random_inputs(n, seed)
    rng = np.random.default_rng(seed + 1)
    known = np.isfinite(rows[:, 0])
    rows[known, 0] = rng.uniform(CLAMP[0] - 30.0, CLAMP[1] + 30.0, int(known.sum()))
    rows[60:66, 0] = [CLAMP[0], CLAMP[1], 25.0, CLAMP[0] - 0.5, CLAMP[1] + 0.5, 25.0 + 1e-3]
    return rows


@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = tmp_path_factory.mktemp("c_intrinsics")
    params = add_thermal_intrinsics(make_params(seed=3, mag="accel", g_sensitivity=True), clamp=CLAMP)
    write_c_export(params, out, "bench-7", EXPORTED_UTC)
    return {"dir": out, "params": params, "exe": {v: build(out, v) for v in ("c", "cxx", "mixed")}}


@pytest.mark.parametrize("variant", ["c", "cxx", "mixed"])
def test_apply_with_thermal_intrinsics(unit: dict, variant: str, tmp_path: Path) -> None:
    rows = spanning_inputs(4000, seed=21)
    got, stdout = c_apply(unit["exe"][variant], unit["dir"] / "imu_calib.bin", rows, tmp_path)
    assert "unit_equal 1" in stdout, "the header's const initializer differs from the blob"
    assert "unit_same_output 1" in stdout, "the header export and the blob give different samples"
    assert f"flags {0b1111111111}" in stdout
    params = unit["params"]
    ref = reference(params, rows)
    error = relative_error(got, ref, rows)
    print(f"C vs apply_calibration, thermal intrinsics, {variant}: max relative error {error:.3g}")
    assert error < TOLERANCE
    # M(T) really is in play: the static matrix alone misses by far more than the tolerance.
    static = make_params(seed=3, mag="accel", g_sensitivity=True)
    assert relative_error(reference(static, rows), ref, rows) > 1e-3


def test_beyond_the_clamp_is_the_clamp_end(unit: dict, tmp_path: Path) -> None:
    """Beyond the calibrated range T is held at its end (thermal bias and M(T) alike, both clamped to
    [-10, 60] here): the C gives bit for bit the sample at the end."""
    rng = np.random.default_rng(5)
    base = spanning_inputs(200, seed=22)
    base[:, 1] = 0.0
    outside = np.repeat(base[:100], 2, axis=0)
    outside[0::2, 0] = rng.uniform(CLAMP[1], CLAMP[1] + 60.0, 100)
    outside[1::2, 0] = CLAMP[1]
    below = np.repeat(base[100:], 2, axis=0)
    below[0::2, 0] = rng.uniform(CLAMP[0] - 60.0, CLAMP[0], 100)
    below[1::2, 0] = CLAMP[0]
    rows = np.vstack([outside, below]).astype(np.float32)
    got, _ = c_apply(unit["exe"]["c"], unit["dir"] / "imu_calib.bin", rows, tmp_path)
    assert np.array_equal(got[0::2], got[1::2], equal_nan=True)
    assert relative_error(got, reference(unit["params"], rows), rows) < TOLERANCE


def polyval_matrix(cal: SensorCalibration, scale: TempPolynomial | None, misalignment: TempPolynomial | None,
                   temp: float, t_ref: float) -> np.ndarray:
    """M(T) written out with numpy.polyval, not the station's intrinsics module."""
    def poly(p: TempPolynomial, row: int) -> float:
        t = min(max(temp, p.t_min), p.t_max) - t_ref
        highest = np.zeros(4)
        for j, power in enumerate(p.powers):
            highest[3 - power] += p.coeffs[row, j]
        return float(np.polyval(highest, t))

    k = np.diag(cal.matrix).copy()
    unit_s = cal.matrix / k[:, None]
    if scale is not None:
        k += [poly(scale, i) for i in range(3)]
    if misalignment is not None:
        for c, (i, j) in enumerate(OFF_DIAGONAL):
            unit_s[i, j] += poly(misalignment, c)
    return np.diag(k) @ unit_s


@pytest.mark.parametrize("kw", [
    {"scale_powers": (1,), "misalignment": False},
    {"scale_powers": (2, 3), "misalignment_powers": (1, 3)},
    {"triads": ("gyro",), "scale_powers": (1, 2)},
    {"triads": ("accel",), "misalignment_powers": (3,)},
])
def test_truth_comes_back(kw: dict, tmp_path: Path) -> None:
    """Samples made from a known truth with M(T) and a bias (no thermal bias, no g-sensitivity): the C
    returns the truth, for each mix of powers and triads."""
    params = add_thermal_intrinsics(make_params(seed=6, thermal=False), seed=6, clamp=CLAMP, **kw)
    write_c_export(params, tmp_path, "st", EXPORTED_UTC)
    exe = build(tmp_path, "c")
    rng = np.random.default_rng(7)
    n = 800
    temp = rng.uniform(CLAMP[0] - 20.0, CLAMP[1] + 20.0, n)
    true = np.hstack([rng.normal(0.0, 6.0, (n, 3)), rng.normal(0.0, 2.0, (n, 3))])
    rows = np.zeros((n, 11))
    rows[:, 0] = temp
    for k, name in enumerate(("accel", "gyro")):
        cal = getattr(params, name)
        scale, misalignment = blobfmt.intrinsics_of(params, name)
        for i in range(n):
            m = polyval_matrix(cal, scale, misalignment, temp[i], params.thermal.reference_temp)
            rows[i, 2 + 3 * k:5 + 3 * k] = m @ true[i, 3 * k:3 * k + 3] + cal.bias
    rows = rows.astype(np.float32)
    got, stdout = c_apply(exe, tmp_path / "imu_calib.bin", rows, tmp_path)
    assert "unit_equal 1" in stdout and "unit_same_output 1" in stdout
    assert relative_error(got[:, :6], true, rows) < TOLERANCE
    assert relative_error(got, reference(params, rows), rows) < TOLERANCE


def test_a_singular_m_of_t_falls_back_to_the_static_correction(tmp_path: Path) -> None:
    """K_x + k_x(t) = 0 at T = 33 degC exactly (K_x = 1, k_x = -t / 8): M(T) has no inverse there, and
    the C gives the correction at T_ref rather than infinities; a degree away it is M(T) again."""
    params = make_params(seed=8, thermal=False, gyro=False)
    params.accel = SensorCalibration.from_parts(np.ones(3), np.zeros((3, 3)), [0.1, -0.2, 0.05])
    add_thermal_intrinsics(params, triads=("accel",), misalignment=False, clamp=CLAMP)
    params.thermal.scale["accel"] = TempPolynomial(*CLAMP, (1,), [[-0.125], [0.0], [0.0]])
    write_c_export(params, tmp_path, "st", EXPORTED_UTC)
    exe = build(tmp_path, "c")
    rows = np.zeros((2, 11), dtype=np.float32)
    rows[:, 0] = [33.0, 34.0]
    rows[:, 2:5] = [1.0, 2.0, 3.0]
    got, _ = c_apply(exe, tmp_path / "imu_calib.bin", rows, tmp_path)
    assert np.allclose(got[0, :3], [0.9, 2.2, 2.95], rtol=1e-6)
    assert np.allclose(got[1, :3], [0.9 / (1 - 9 / 8), 2.2, 2.95], rtol=1e-6)


@pytest.mark.parametrize(("name", "sections"), [
    ("imu_calib_v2_seed7_mag_g.bin", {"seed": 7, "mag": "accel", "g_sensitivity": True}),
    ("imu_calib_v2_seed9.bin", {"seed": 9}),
])
def test_version_2_blobs_give_the_old_result(unit: dict, name: str, sections: dict, tmp_path: Path) -> None:
    """The version 3 loader reads the blobs of version 2 (tests/data/blob-v2) and corrects as the
    station does with the parameters they were written from: no M(T), the static matrix."""
    blob = V2_BLOBS / name
    for variant in ("c", "cxx"):
        assert run([str(unit["exe"][variant]), "load", str(blob)], tmp_path).split() == ["0", "0"]
    rows = spanning_inputs(600, seed=23)
    params = make_params(**sections)
    got, stdout = c_apply(unit["exe"]["c"], blob, rows, tmp_path)
    assert f"flags {blobfmt.flags_of(params)}" in stdout
    assert relative_error(got, reference(params, rows), rows) < TOLERANCE
