"""A board's IMUs, each calibrated on its own, and each one's rotation relative to the first.

The composition of ``imu_alignment`` over one board: the first IMU's calibration gives the still stretches
and the moves (:func:`board_spans`), on the board's one time base; every IMU's samples over them, corrected
into its own axes, give the vectors of eq. (1) there (:func:`board_vectors`); eq. (2) gives each rotation
and eqs. (3) and (4) its covariance (:func:`board_rotations`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from station.engines.calibration.common import CalibrationReport
from station.engines.calibration.imu_alignment import (
    AlignmentVectors,
    RelativeRotation,
    frame_covariance,
    own_axes,
    pose_means,
    relative_rotation,
    select_span,
    turn_integrals,
)
from station.errors import EngineInputError

ABSORBED_PER_TRIAD = 9
"""Parameters each calibration fits to the same vectors beyond the rotation (``a`` of eq. 3, per triad
used): a turntable's 12 accelerometer parameters on the poses less the 3 of the rotation, its 9 gyroscope
parameters on the turns (their rotation from the accelerometer's frame is the fit's own); the hand-held fit's
9 of either triad."""


@dataclass
class BoardImu:
    """One IMU of a board as calibrated: its samples on the board's time base and its calibration.

    Attributes
    ----------
    instance : int
    t : ndarray, (N,)
    acc, gyro : ndarray, (N, 3)
        Raw samples.
    report : CalibrationReport
        Its own calibration (``calibrate_turntable`` or ``calibrate_free``).
    """

    instance: int
    t: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    report: CalibrationReport


def board_spans(report: CalibrationReport) -> tuple[list[tuple[float, float]], list[tuple[float, float]]]:
    """The still stretches and the moves of the first IMU's calibration, as times (s).

    Turntable: every static pose step, and every rotation step (they begin and end still). Hand-held:
    every static interval, and each move from the middle of one interval to the middle of the next, so
    that its ends lie in still stretches whatever the other IMUs' sample instants.

    Parameters
    ----------
    report : CalibrationReport

    Returns
    -------
    tuple
        (still spans, move spans), each a list of (t0, t1).
    """
    statics = [(float(p["t0"]), float(p["t1"])) for p in report.poses if p.get("kind", "static") == "static"]
    if report.method == "turntable":
        turns = [(float(p["t0"]), float(p["t1"])) for p in report.poses if p.get("kind") == "rotation"]
    else:
        mids = [0.5 * (a + b) for a, b in statics]
        turns = list(zip(mids[:-1], mids[1:], strict=True))
    return statics, turns


def board_vectors(imu: BoardImu, statics: Sequence[tuple[float, float]], turns: Sequence[tuple[float, float]],
                  convention: str = "lower") -> AlignmentVectors:
    """What ``imu`` saw in the first IMU's still stretches and moves, in its own axes (:func:`own_axes`).

    Parameters
    ----------
    imu : BoardImu
    statics, turns : sequence of (t0, t1)
        From :func:`board_spans` of the first IMU.
    convention : str
        The triangular convention of the own axes.

    Returns
    -------
    AlignmentVectors
        No turns where the IMU's calibration has no gyroscope matrix.
    """
    accel, gyro = imu.report.accel, imu.report.gyro
    if accel is None:
        raise EngineInputError(f"IMU {imu.instance} has no accelerometer calibration: nothing gives its axes")
    acc_c, gyro_c = own_axes(accel.correction, gyro.correction if gyro is not None else None, convention)
    means, mean_var = pose_means(imu.t, imu.acc, acc_c, accel.bias, statics)
    if gyro is None or gyro_c is None or not turns:
        return AlignmentVectors(means, mean_var)
    still = np.concatenate([imu.gyro[select_span(imu.t, a, b)] for a, b in statics])
    rate_var = float(np.mean(((still - gyro.bias) @ gyro_c.T).var(axis=0, ddof=1)))
    bias_sd = np.asarray(gyro.stddev.get("bias", np.zeros(3)), float)
    bias_var = float(np.mean(bias_sd**2)) if np.all(np.isfinite(bias_sd)) else 0.0
    integrals, var = turn_integrals(imu.t, imu.gyro, gyro_c, gyro.bias, turns, rate_var, bias_var)
    return AlignmentVectors(means, mean_var, integrals, var)


def board_rotations(imus: Sequence[BoardImu], convention: str = "lower") -> dict[int, RelativeRotation]:
    """The rotation of every IMU after the first relative to it (eqs. 1-3), from the first's stretches.

    Parameters
    ----------
    imus : sequence of BoardImu
        The first is the reference (the parameter file's top-level sections).
    convention : str
        The triangular convention of the own axes (the hand-held calibration's).

    Returns
    -------
    dict of int to RelativeRotation
        By instance, the first left out.

    Raises
    ------
    EngineInputError
        Poses that cannot fix a rotation (parallel), an IMU without a calibration or without samples
        in the first's stretches.
    """
    first = imus[0]
    frames = {imu.instance: _frame_of(imu, convention) for imu in imus}
    statics, turns = board_spans(first.report)
    turns = turns if first.report.gyro is not None else []
    reference = board_vectors(first, statics, turns, convention)
    out = {}
    for imu in imus[1:]:
        other = board_vectors(imu, statics, turns, convention)
        if len(other.gyro) != len(reference.gyro):  # one IMU without a gyroscope matrix: poses alone
            reference_used = AlignmentVectors(reference.accel, reference.accel_var)
            other = AlignmentVectors(other.accel, other.accel_var)
        else:
            reference_used = reference
        triads = 1 + (len(other.gyro) > 0)
        try:
            rot = relative_rotation(reference_used, other, ABSORBED_PER_TRIAD * triads)
        except EngineInputError as exc:
            raise EngineInputError(f"IMU {imu.instance} relative to IMU {first.instance}: {exc}") from None
        # each IMU's own axes are only as well known as its calibration: R = (I + [q_k]x) R (I - [q_0]x),
        # so about the first's axes the angle is R^T q_k - q_0
        r = rot.matrix
        rot.covariance = rot.covariance + r.T @ frames[imu.instance] @ r + frames[first.instance]
        out[imu.instance] = rot
    return out


def _frame_of(imu: BoardImu, convention: str) -> np.ndarray:
    """Eq. (4) for the IMU's accelerometer (zero without a matrix 1-sigma)."""
    accel = imu.report.accel
    if accel is None or accel.stddev.get("matrix") is None:
        return np.zeros((3, 3))
    return frame_covariance(accel.matrix, np.asarray(accel.stddev["matrix"], float), convention)
