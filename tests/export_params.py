"""Parameter files with realistic values for the export tests (the engines' output stands in here).

Intrinsics near identity with millirad misalignment, biases of a MEMS unit, and a thermal model
of several segments holding every term, dT ones included, over -10..60 degC. Optionally a ``mag``
section (hard iron of tens of microtesla, a few percent of soft iron, a rotation of a few degrees
to the accelerometer's axes) and a gyro g-sensitivity of a MEMS gyro (~0.1 deg/s/g), written by
hand from the spec (``shared/specs/params-file.md``) as the engines will.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.intrinsics import TempPolynomial
from station.engines.thermal.model import DtempFilter, ThermalBias, ThermalModel, ThermalSegment
from station.export.params.file import ParamsFile

FIELD_UT = 48.5
G_SENSITIVITY_SD = 0.1 * np.pi / 180 / 9.80665  # 0.1 deg/s per g, in rad/s per m/s^2

# Exact in float32, so a temperature sitting on a boundary picks the same segment everywhere.
BREAKS = (-10.0, 13.5, 37.0, 60.0)
# Per-term spread of the coefficients (TERMS order: t^3, t^2, t, dT^2, dT, t*dT, 1), accel units.
TERM_SCALE = np.array([3e-7, 2e-5, 1e-3, 1e-3, 5e-3, 1e-4, 1e-2])


def thermal_triad(rng: np.random.Generator, breaks: tuple[float, ...], unit: float, dtemp_terms: bool,
                  dt_clamp: float) -> ThermalBias:
    segments = []
    for lo, hi in zip(breaks[:-1], breaks[1:], strict=True):
        coeffs = rng.normal(0.0, 1.0, (3, 7)) * TERM_SCALE * unit
        if not dtemp_terms:
            coeffs[:, 3:6] = 0.0
        segments.append(ThermalSegment(lo, hi, coeffs))
    return ThermalBias(segments, -dt_clamp, dt_clamp)


def sensor(rng: np.random.Generator, scale_sd: float, misalign_sd: float, bias_sd: float,
           method: str) -> SensorCalibration:
    misalignment = rng.normal(0.0, misalign_sd, (3, 3)) * (1 - np.eye(3))
    return SensorCalibration.from_parts(1 + rng.normal(0.0, scale_sd, 3), misalignment,
                                        rng.normal(0.0, bias_sd, 3), method=method, residual_rms=0.004)


def mag_section(rng: np.random.Generator, frame: str = "accel") -> dict:
    """A ``mag`` section: raw = S R^T true + b, S the symmetric soft iron, R the rotation of the
    magnetometer's axes to the accelerometer's (identity for ``frame: sensor``)."""
    soft = np.eye(3) + rng.normal(0.0, 0.03, (3, 3))
    soft = (soft + soft.T) / 2
    rotation = Rotation.from_rotvec(rng.normal(0.0, np.radians(2.0), 3)).as_matrix() if frame == "accel" \
        else np.eye(3)
    matrix = soft @ rotation.T
    return {"matrix": matrix.tolist(), "bias": rng.normal(0.0, 25.0, 3).tolist(),
            "correction": np.linalg.inv(matrix).tolist(), "frame": frame, "field_norm": FIELD_UT,
            "residual_rms": 0.08, "coverage": 0.9, "method": "mag", "stddev": {"bias": [0.02, 0.02, 0.03]}}


def make_params(seed: int = 0, breaks: tuple[float, ...] = BREAKS, dtemp_terms: bool = True,
                accel: bool = True, gyro: bool = True, thermal: bool = True,
                device: dict | None = None, mag: str | None = None, g_sensitivity: bool = False,
                noise: bool = False) -> ParamsFile:
    """Parameters of one unit; ``mag`` (its frame, accel or sensor) adds a mag section,
    ``g_sensitivity`` a gyro g-sensitivity, ``noise`` a noise section (none of them draws from the
    generator before the others, so a seed gives the same accel, gyro and thermal either way)."""
    rng = np.random.default_rng(seed)
    params = ParamsFile(device=device if device is not None else
                        {"serial": "SN-0042", "model": "IMU-9", "firmware": "1.2.3"},
                        created="2026-11-22T10:00:00Z")
    params.accel = sensor(rng, 0.01, 2e-3, 0.15, "six-pose") if accel else None
    params.gyro = sensor(rng, 0.005, 3e-3, 0.01, "turntable") if gyro else None
    if thermal:
        params.thermal = ThermalModel(
            25.0, DtempFilter("ema", 12.0),
            thermal_triad(rng, breaks, 1.0, dtemp_terms, 0.5) if accel else None,
            thermal_triad(rng, breaks, 0.1, dtemp_terms, 1.0) if gyro else None,
        )
    extra = np.random.default_rng(seed + 1000)
    if mag is not None:
        params.other["mag"] = mag_section(extra, mag)
    if g_sensitivity and params.gyro is not None:
        params.gyro.extra["g_sensitivity"] = extra.normal(0.0, G_SENSITIVITY_SD, (3, 3)).tolist()
    if noise:
        terms = {"N": [1e-3, 1.1e-3, 1.2e-3], "K": [1e-5, 1e-5, 2e-5], "B": [3e-5, 3e-5, 4e-5],
                 "Q": None, "R": None}
        params.noise = {sensor: dict(terms) for sensor in ("accel", "gyro")}
    return params


def cubic_params(seed: int = 0) -> ParamsFile:
    """What an autopilot can hold exactly: diagonal accel matrix, unit gyro scale, no misalignment,
    one thermal segment with only t^3, t^2, t and 1 terms."""
    rng = np.random.default_rng(seed)
    params = make_params(seed, breaks=(-5.0, 55.0), dtemp_terms=False)
    params.accel = SensorCalibration.from_parts(1 + rng.normal(0, 0.01, 3), np.zeros((3, 3)),
                                                rng.normal(0, 0.15, 3))
    params.gyro = SensorCalibration.from_parts(np.ones(3), np.zeros((3, 3)), rng.normal(0, 0.01, 3))
    return params


# Per-power spread of the thermal intrinsics polynomials (t, t^2, t^3): a MEMS triad's scale factor
# moves 100-300 ppm/degC, its axes a few microradians per degC.
SCALE_PER_POWER = np.array([2e-4, 2e-6, 2e-8])
MISALIGNMENT_PER_POWER = np.array([3e-6, 5e-8, 5e-10])


def add_thermal_intrinsics(params: ParamsFile, seed: int = 0, clamp: tuple[float, float] = (-10.0, 60.0),
                           scale_powers: tuple[int, ...] = (1, 2, 3),
                           misalignment_powers: tuple[int, ...] = (1, 2),
                           triads: tuple[str, ...] = ("accel", "gyro"),
                           misalignment: bool = True) -> ParamsFile:
    """``params`` with ``thermal.scale`` and ``thermal.misalignment`` polynomials for ``triads``
    (a thermal section at 25 degC is added where the file has none)."""
    rng = np.random.default_rng(seed + 2000)
    if params.thermal is None:
        params.thermal = ThermalModel(25.0, DtempFilter("ema", 12.0))
    for name in triads:
        idx = [p - 1 for p in scale_powers]
        params.thermal.scale[name] = TempPolynomial(
            clamp[0], clamp[1], scale_powers, rng.normal(0.0, 1.0, (3, len(idx))) * SCALE_PER_POWER[idx])
        if misalignment:
            idx = [p - 1 for p in misalignment_powers]
            params.thermal.misalignment[name] = TempPolynomial(
                clamp[0], clamp[1], misalignment_powers,
                rng.normal(0.0, 1.0, (6, len(idx))) * MISALIGNMENT_PER_POWER[idx])
    return params
