"""A board of several IMUs, each mounted at its own small rotation, moved together by one rig.

The rig (``mocks.rig``) moves the board; IMU k's axes are turned from the board's by ``R_k``
(v_imu = R_k v_board), so it feels the board's specific force and rate turned by R_k. Its truth then
is the mounted one: M_k R_k for each triad (and G_k R_k for the g-sensitivity), written back as a
scale and a misalignment, M R = diag(d) (I + S) with d = diag(M R) and S = diag(d)^-1 M R - I, so
``mocks.rig.simulate`` samples it unchanged.

The relative rotation a calibration can recover is between the IMUs' own axes, which their
accelerometers define (``station.engines.calibration.imu_alignment``): the triangular split of each
mounted correction, (M_k R_k)^-1 = Q_k C'_k, gives the board-to-own rotation Q_k^T, and the truth of
eq. (1) there is R_true = Q_k^T Q_0 (:func:`true_relative_rotation`). With a lower-triangular M_k it is
R_k R_0^T exactly; a general misalignment adds its antisymmetric part (a few mrad).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from mocks.rig import Recording, Segment, simulate
from mocks.truth import SensorTruth, UnitTruth


def rotation_xyz(degrees: Sequence[float]) -> np.ndarray:
    """The rotation exp([theta]x) of the rotation vector ``degrees`` (about x, y, z, in degrees)."""
    theta = np.radians(np.asarray(degrees, float))
    angle = float(np.linalg.norm(theta))
    if angle == 0:
        return np.eye(3)
    k = theta / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def _mounted_sensor(sensor: SensorTruth, rotation: np.ndarray) -> SensorTruth:
    m = sensor.matrix @ rotation
    d = np.diag(m).copy()
    s = m / d[:, None] - np.eye(3)
    np.fill_diagonal(s, 0.0)
    return replace(sensor, scale=d, misalignment=s)


def mounted(truth: UnitTruth, rotation: np.ndarray) -> UnitTruth:
    """``truth`` mounted on the board turned by ``rotation`` (v_imu = rotation @ v_board).

    Parameters
    ----------
    truth : UnitTruth
        The IMU in its own axes (no nonlinearity, no thermal scale or misalignment).
    rotation : ndarray, (3, 3)

    Returns
    -------
    UnitTruth
    """
    r = np.asarray(rotation, float)
    return replace(truth, accel=_mounted_sensor(truth.accel, r), gyro=_mounted_sensor(truth.gyro, r),
                   g_sensitivity=truth.g_sensitivity @ r)


def own_axes(truth: UnitTruth, convention: str = "lower") -> np.ndarray:
    """Q^T: board vectors into the mounted IMU's own axes (its accelerometer's triangular frame).

    The correction C = (M R)^-1 split as C = Q C' with C' triangular of positive diagonal: ``upper`` by QR
    of C, ``lower`` by QR of C with rows and columns reversed (written here from numpy alone, apart from
    the station's ``common.triangular_correction`` it checks).
    """
    c = np.linalg.inv(truth.accel.matrix)
    if convention == "upper":
        q, r = np.linalg.qr(c)
    elif convention == "lower":
        flip = np.eye(3)[::-1]
        q0, r0 = np.linalg.qr(flip @ c @ flip)
        q, r = flip @ q0 @ flip, flip @ r0 @ flip
    else:
        raise ValueError(f"convention {convention!r}: use 'lower' or 'upper'")
    signs = np.where(np.diag(r) < 0, -1.0, 1.0)
    return (q * signs).T


def true_relative_rotation(first: UnitTruth, other: UnitTruth, convention: str = "lower") -> np.ndarray:
    """R_true with v_other = R_true v_first, both in their own axes (module docstring)."""
    return own_axes(other, convention) @ own_axes(first, convention).T


def simulate_board(truths: Sequence[UnitTruth], segments: Sequence[Segment],
                   rates_hz: Sequence[float] | None = None, seed: int = 0) -> list[Recording]:
    """Every mounted IMU through the same segments (same motion, own noise), one recording each.

    Parameters
    ----------
    truths : sequence of UnitTruth
        The mounted IMUs (:func:`mounted`).
    segments : sequence of Segment
    rates_hz : sequence of float, optional
        Each IMU's rate (default 200 Hz each).
    seed : int

    Returns
    -------
    list of Recording
    """
    rates = list(rates_hz) if rates_hz is not None else [200.0] * len(truths)
    return [simulate(truth, segments, rate_hz=rate, seed=seed * 101 + k)
            for k, (truth, rate) in enumerate(zip(truths, rates, strict=True))]


def write_board_ulog(path: str | Path, recordings: Sequence[Recording], device_ids: Sequence[int],
                     uuid: str = "SIMBOARD") -> Path:
    """The recordings as a PX4 ULog: ``sensor_accel``/``sensor_gyro`` instance k per IMU.

    Parameters
    ----------
    path : str or Path
    recordings : sequence of Recording
    device_ids : sequence of int
        Each IMU's device id (accelerometer and gyroscope alike).
    uuid : str
        ``sys_uuid``: the board's name in the captures' serials.

    Returns
    -------
    Path
    """
    from mocks import ulog_writer as ul
    from mocks.autopilot_sweep import BOOT_US, PUBLISH_LATENCY_US

    topics = []
    params: dict[str, float | int] = {"SENS_BOARD_ROT": 0, "TC_A_ENABLE": 0, "TC_G_ENABLE": 0}
    for k, (rec, dev) in enumerate(zip(recordings, device_ids, strict=True)):
        sample = BOOT_US + np.round(rec.t * 1e6).astype(np.uint64)
        common = {"timestamp": sample + PUBLISH_LATENCY_US, "timestamp_sample": sample,
                  "temperature": rec.temp, "samples": 1, "device_id": dev}
        for name, fields, values in (("sensor_accel", ul.SENSOR_ACCEL, rec.acc),
                                     ("sensor_gyro", ul.SENSOR_GYRO, rec.gyro)):
            data = ul.records(fields, len(sample), x=values[:, 0], y=values[:, 1], z=values[:, 2], **common)
            topics.append(ul.Topic(name, k, fields, data))
        params[f"CAL_ACC{k}_ID"] = int(dev)
        params[f"CAL_GYRO{k}_ID"] = int(dev)
    info = {"sys_name": "PX4", "ver_hw": "IMU_STATION_BOARD", "sys_uuid": uuid}
    return ul.write_ulog(path, topics, params, info)
