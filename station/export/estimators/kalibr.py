"""IMU noise parameters for Kalibr (imu.yaml), VINS-Fusion and ORB-SLAM3, from the ``noise`` section.

All three take continuous-time densities, one number per sensor:
- noise density = N (white noise): gyro rad/s/sqrt(Hz), accel m/s^2/sqrt(Hz);
- random walk = K (rate random walk): gyro rad/s^2/sqrt(Hz), accel m/s^3/sqrt(Hz).
Kalibr's wiki (IMU Noise Model) defines exactly these; VINS-Fusion calls them gyr_n/acc_n and gyr_w/acc_w,
ORB-SLAM3 IMU.NoiseGyro/NoiseAcc and IMU.GyroWalk/AccWalk. The largest axis is taken (the conservative
choice for a filter). Kalibr's documentation advises inflating the values of a still bench recording for
a moving vehicle: every writer here multiplies them by an explicit factor (``--inflate``, default 1, the
values as measured; :mod:`station.export.estimators.inflation`) and states it in the file.
"""

from __future__ import annotations

from typing import Any

from station.errors import EngineInputError
from station.export.estimators.inflation import header_lines

KEYS = {("gyro", "N"): "gyroscope_noise_density", ("gyro", "K"): "gyroscope_random_walk",
        ("accel", "N"): "accelerometer_noise_density", ("accel", "K"): "accelerometer_random_walk"}
UNIT = {("gyro", "N"): "rad/s/sqrt(Hz)", ("gyro", "K"): "rad/s^2/sqrt(Hz)",
        ("accel", "N"): "m/s^2/sqrt(Hz)", ("accel", "K"): "m/s^3/sqrt(Hz)"}


def filter_values(noise: dict[str, Any]) -> dict[tuple[str, str], float]:
    """The four numbers (largest axis of N and K per sensor); refuses when the record does not show one.

    Where the section has them, the values equivalent to each axis's whole model over the filter's time
    scale (``filter_equivalent``, :mod:`station.engines.allan.equivalent`) are taken; N and K themselves
    otherwise. A K of zero (a model with nothing that drifts) counts as not shown."""
    out = {}
    for (sensor, term) in KEYS:
        sensor_noise = noise.get(sensor) or {}
        source = sensor_noise.get("filter_equivalent") or sensor_noise
        values = [v for v in (source.get(term) or []) if v is not None and (term != "K" or v > 0)]
        if not values:
            reasons = {r for r in (sensor_noise.get("reasons", {}).get(term) or []) if r}
            why = "; ".join(sorted(reasons)) or "the noise section has no such term"
            raise EngineInputError(f"cannot write filter noise parameters: {sensor} {term} is unknown "
                                   f"({why}). Record a longer still period (several hours) and run "
                                   "'imu-station allan' again")
        out[(sensor, term)] = max(values)
    return out


def kalibr_yaml(noise: dict[str, Any], rostopic: str = "/imu0", update_rate: float | None = None,
                factor: float = 1.0) -> str:
    """Kalibr's imu.yaml (``kalibr_calibrate_imu_camera --imu``), each value times the inflation factor."""
    v = filter_values(noise)
    rate = update_rate if update_rate is not None else noise["record"]["rate_hz"]
    lines = ["# IMU noise model for Kalibr, from imu-station allan (still recording of "
             f"{noise['record']['duration_s'] / 3600:.3g} h).",
             "# Continuous-time densities, largest axis. Kalibr advises inflating bench values for motion.",
             *_equivalent_note(noise), *(f"# {line}" for line in header_lines(factor))]
    for key, name in KEYS.items():
        lines.append(f"{name}: {factor * v[key]:.6e}  # {key[1]} [{UNIT[key]}]")
    lines.append(f"rostopic: {rostopic}")
    lines.append(f"update_rate: {float(rate):.6g}  # Hz")
    return "\n".join(lines) + "\n"


def _equivalent_note(noise: dict[str, Any]) -> list[str]:
    """A comment saying the values cover the whole noise model, and over which time scale."""
    eq = (noise.get("gyro") or {}).get("filter_equivalent")
    if not eq:
        return []
    return [f"# N and K equivalent to the whole model (Gauss-Markov terms included) from {eq['step_s']:.3g} "
            f"s to {max(eq['horizon_s']):.4g} s (imu-station docs: methods/allan)."]


def vins_snippet(noise: dict[str, Any], factor: float = 1.0) -> str:
    """The IMU noise lines of a VINS-Fusion / VINS-Mono config (YAML), each times the inflation ``factor``."""
    v = {key: factor * value for key, value in filter_values(noise).items()}
    return ("# VINS-Fusion IMU noise (continuous time), from imu-station allan\n"
            + "".join(f"# {line}\n" for line in header_lines(factor))
            + f"acc_n: {v[('accel', 'N')]:.6e}   # accelerometer noise density [m/s^2/sqrt(Hz)]\n"
            f"gyr_n: {v[('gyro', 'N')]:.6e}   # gyroscope noise density [rad/s/sqrt(Hz)]\n"
            f"acc_w: {v[('accel', 'K')]:.6e}   # accelerometer random walk [m/s^3/sqrt(Hz)]\n"
            f"gyr_w: {v[('gyro', 'K')]:.6e}   # gyroscope random walk [rad/s^2/sqrt(Hz)]\n")


def orbslam3_snippet(noise: dict[str, Any], update_rate: float | None = None, factor: float = 1.0) -> str:
    """The IMU lines of an ORB-SLAM3 settings file (OpenCV YAML), each times the inflation ``factor``."""
    v = {key: factor * value for key, value in filter_values(noise).items()}
    rate = update_rate if update_rate is not None else noise["record"]["rate_hz"]
    return ("# ORB-SLAM3 IMU noise (continuous time), from imu-station allan\n"
            + "".join(f"# {line}\n" for line in header_lines(factor))
            + f"IMU.NoiseGyro: {v[('gyro', 'N')]:.6e}  # rad/s/sqrt(Hz)\n"
            f"IMU.NoiseAcc: {v[('accel', 'N')]:.6e}  # m/s^2/sqrt(Hz)\n"
            f"IMU.GyroWalk: {v[('gyro', 'K')]:.6e}  # rad/s^2/sqrt(Hz)\n"
            f"IMU.AccWalk: {v[('accel', 'K')]:.6e}  # m/s^3/sqrt(Hz)\n"
            f"IMU.Frequency: {float(rate):.6g}  # Hz\n")
