"""OpenVINS' IMU file, ``kalibr_imu_chain.yaml``, from the ``noise`` section.

OpenVINS (``ov_msckf``, ``VioManagerOptions::print_and_load_noise``) reads its four IMU noise values from
the file its ``estimator_config.yaml`` names as ``relative_config_imu``, under ``imu0``:
``gyroscope_noise_density`` (rad/s/sqrt(Hz)), ``gyroscope_random_walk`` (rad/s^2/sqrt(Hz)),
``accelerometer_noise_density`` (m/s^2/sqrt(Hz)) and ``accelerometer_random_walk`` (m/s^3/sqrt(Hz)): the
continuous-time densities of Kalibr's model (its docs, "Sensor Calibration", give Kalibr's table), which
its propagation discretises at the IMU's period (sigma / sqrt(dt) and sigma sqrt(dt)). So N and K are
written as they are, times the inflation factor. The file is OpenCV YAML (``cv::FileStorage``: the
``%YAML:1.0`` first line), laid out as OpenVINS' own ``config/euroc_mav/kalibr_imu_chain.yaml``; the IMU
intrinsics in it are the identity, for samples already corrected (``imu-station apply`` or the firmware
export), with ``model: kalibr``.
"""

from __future__ import annotations

from typing import Any

from station.export.estimators.inflation import header_lines
from station.export.estimators.kalibr import KEYS, UNIT, filter_values

IDENTITY = ("    - [ 1.0, 0.0, 0.0 ]", "    - [ 0.0, 1.0, 0.0 ]", "    - [ 0.0, 0.0, 1.0 ]")
ZERO = ("    - [ 0.0, 0.0, 0.0 ]",) * 3
KEY_ORDER = (("accel", "N"), ("accel", "K"), ("gyro", "N"), ("gyro", "K"))
"""OpenVINS' own file's order."""


def openvins_values(noise: dict[str, Any], factor: float = 1.0) -> dict[str, float]:
    """The four values OpenVINS reads, by key: the largest axis's N and K times ``factor``.

    Parameters
    ----------
    noise : dict
        The noise section.
    factor : float
        The inflation factor.

    Returns
    -------
    dict
        ``gyroscope_noise_density`` etc. -> value in Kalibr's units.
    """
    v = filter_values(noise)
    return {KEYS[key]: factor * v[key] for key in KEY_ORDER}


def openvins_imu_chain(noise: dict[str, Any], rostopic: str = "/imu0", update_rate: float | None = None,
                       factor: float = 1.0) -> str:
    """The ``kalibr_imu_chain.yaml`` text OpenVINS reads.

    Parameters
    ----------
    noise : dict
        The noise section.
    rostopic : str
        The IMU topic.
    update_rate : float, optional
        The IMU's rate, Hz (default: the record's).
    factor : float
        The inflation factor (:mod:`station.export.estimators.inflation`).

    Returns
    -------
    str
        The file's text.
    """
    values = openvins_values(noise, factor)
    rate = update_rate if update_rate is not None else noise["record"]["rate_hz"]
    lines = ["%YAML:1.0", "# IMU noise for OpenVINS (relative_config_imu), from imu-station allan:",
             "# continuous-time densities, largest axis; intrinsics identity for samples already corrected.",
             *(f"# {line}" for line in header_lines(factor)), "", "imu0:", "  T_i_b:",
             "    - [1.0, 0.0, 0.0, 0.0]", "    - [0.0, 1.0, 0.0, 0.0]", "    - [0.0, 0.0, 1.0, 0.0]",
             "    - [0.0, 0.0, 0.0, 1.0]"]
    for key in KEY_ORDER:
        lines.append(f"  {KEYS[key]}: {values[KEYS[key]]:.6e}  # [{UNIT[key]}]")
    lines += [f"  rostopic: {rostopic}", "  time_offset: 0.0", f"  update_rate: {float(rate):.6g}",
              '  model: "kalibr"', "  Tw:", *IDENTITY, "  R_IMUtoGYRO:", *IDENTITY, "  Ta:", *IDENTITY,
              "  R_IMUtoACC:", *IDENTITY, "  Tg:", *ZERO]
    return "\n".join(lines) + "\n"
