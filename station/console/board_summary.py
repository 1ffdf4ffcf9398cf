"""What ``imu-station calibrate`` prints for a board of several IMUs: each IMU's rotation relative to the
first with its 1-sigma, in degrees, and the same as JSON."""

from __future__ import annotations

from typing import IO, Any

import numpy as np

from station.engines.calibration.imu_alignment import RelativeRotation

DEG = 180.0 / np.pi


def rotation_dict(instance: int, rotation: RelativeRotation) -> dict[str, Any]:
    """One IMU's rotation as ``--json`` prints it (angles in degrees, the matrix to the first).

    Parameters
    ----------
    instance : int
    rotation : RelativeRotation

    Returns
    -------
    dict
    """
    return {"instance": instance, "rotation_to_first": rotation.to_first.tolist(),
            "angle_deg": rotation.angle * DEG,
            "rotation_vector_deg": (rotation.rotation_vector * DEG).tolist(),
            "sigma_deg": (rotation.sigma * DEG).tolist(), "poses": rotation.poses, "turns": rotation.turns,
            "residual_rms": rotation.residual_rms, "scale2": rotation.scale2}


def print_rotations(first: int, rotations: dict[int, RelativeRotation], out: IO[str]) -> None:
    """A table of each IMU's rotation relative to IMU ``first``: about x, y, z (deg, +- 1-sigma), angle.

    Parameters
    ----------
    first : int
        The reference IMU's instance.
    rotations : dict of int to RelativeRotation
    out : text stream
    """
    from station.common.table import format_table

    rows = []
    for instance, rot in sorted(rotations.items()):
        vector, sigma = rot.rotation_vector * DEG, rot.sigma * DEG
        rows.append([f"IMU {instance}", *[f"{v:+.4f} ± {s:.2g}" for v, s in zip(vector, sigma, strict=True)],
                     f"{rot.angle * DEG:.4f}", f"{rot.poses} / {rot.turns}"])
    title = (f"rotation of each IMU relative to IMU {first} (v_k = R v_{first}, each in its own axes; "
             f"rotation vector about IMU {first}'s axes, deg, ± 1-sigma)")
    out.write(format_table(title, ("IMU", "x (deg)", "y (deg)", "z (deg)", "angle (deg)", "poses / turns"),
                           rows, (False, True, True, True, True, True)) + "\n")
