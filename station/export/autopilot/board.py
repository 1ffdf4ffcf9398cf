"""A board of several IMUs (a parameter file's ``imus`` section) as one PX4 or ArduPilot parameter file.

Each IMU is exported as a one-IMU file is, as its own instance (PX4 ``CAL_ACCn_*``/``CAL_GYROn_*``/
``TC_An_*``; ArduPilot ``INS_ACCOFFS_*``, ``INS_ACC2OFFS_*``, ``INS_TCAL2_*``, ...) bound to the device ids
its entry holds, and the lists are joined. Neither autopilot holds a rotation between its IMUs: both take
every IMU's axes for the board's (after the one board rotation, ``SENS_BOARD_ROT``/``AHRS_ORIENTATION``).
An IMU turned from the first by more than :data:`ROTATION_LIMIT_DEG` is reported as a limitation in
degrees: each IMU then reports gravity and rates in slightly different axes, so the attitude each one
gives differs by that angle, and a switch of the estimator from one IMU to another jumps by it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from station.export.autopilot.shared import AutopilotExport, Limitation, Param
from station.export.params.file import ParamsFile
from station.export.params.imus import BoardEntry, board_entries, instance_params

ROTATION_LIMIT_DEG = 0.5
"""The rotation between two IMUs above which an export reports it: a level error of 0.5 deg is the size
PX4's and ArduPilot's own level calibrations (``SENS_BOARD_X_OFF``/``AHRS_TRIM``) are set to correct, so
a larger one is worth correcting by hand (or shows a badly mounted IMU)."""

Build = Callable[[ParamsFile, int, "int | None", "int | None"], AutopilotExport]


def is_board(params: ParamsFile) -> bool:
    """The file lists more than one IMU (``imus``)."""
    return len(board_entries(params)) > 1


def rotation_limitation(entry: BoardEntry, first: int) -> Limitation | None:
    """The IMU's rotation to the first as a limitation, when it exceeds :data:`ROTATION_LIMIT_DEG`."""
    angle = entry.rotation_angle_deg
    if entry.first or angle <= ROTATION_LIMIT_DEG:
        return None
    sigma = ("" if entry.rotation_sigma is None
             else f" (1-sigma {np.degrees(np.max(entry.rotation_sigma)):.2g} deg)")
    return Limitation(f"imu{entry.instance}", "rotation to the first IMU", angle, "deg",
                      f"IMU {entry.instance} is turned {angle:.3g} deg{sigma} from IMU {first}; the "
                      "autopilot takes every IMU's axes for the board's (it holds no rotation per IMU): its "
                      f"attitude from IMU {entry.instance} differs by that much (above "
                      f"{ROTATION_LIMIT_DEG:g} deg is reported)")


def build_board(params: ParamsFile, build: Build, max_instance: int, instance: int = 0,
                device_id: int | None = None, gyro_device_id: int | None = None) -> AutopilotExport:
    """Every IMU of the board (``instance`` 0), or IMU ``instance`` alone, exported by ``build``.

    Parameters
    ----------
    params : ParamsFile
        A board file (:func:`is_board`).
    build : callable
        The target's one-IMU export (``build_px4``, ``build_ardupilot``).
    max_instance : int
        The highest instance the target has parameters for; IMUs above it are left out with a note.
    instance : int
        0: every IMU; N: IMU N alone.
    device_id, gyro_device_id : int, optional
        Override the device ids of the first IMU (every IMU) or of IMU N (one IMU).

    Returns
    -------
    AutopilotExport
        The joined parameters (a name written twice, such as ``TC_A_ENABLE``, once), limitations and pose
        errors per IMU (``accel (IMU 1)``), the notes.

    Raises
    ------
    ValueError
        ``instance`` is not an IMU of the board.
    """
    entries = board_entries(params)
    first = entries[0].instance
    chosen = entries if instance == 0 else [e for e in entries if e.instance == instance]
    if not chosen:
        raise ValueError(f"the board file lists IMUs {', '.join(str(e.instance) for e in entries)}, not "
                         f"{instance}; give one of them with --instance, or leave --instance out for every "
                         "IMU")
    result: AutopilotExport | None = None
    params_out: dict[str, Param] = {}
    notes: list[str] = []
    per_imu: list[list[str]] = []
    for entry in chosen:
        if entry.instance > max_instance:
            notes.append(f"IMU {entry.instance} is left out: the target has parameters for instances "
                         f"0..{max_instance}")
            continue
        overridden = entry.first if instance == 0 else True
        acc_id = device_id if overridden and device_id is not None else entry.device_id
        gyro_id = (gyro_device_id if overridden and gyro_device_id is not None
                   else entry.gyro_device_id if entry.gyro_device_id is not None else acc_id)
        one = build(instance_params(params, entry), entry.instance, acc_id, gyro_id)
        for p in one.params:
            params_out.setdefault(p.name, p)
        tag = f" (IMU {entry.instance})"
        if result is None:
            result = AutopilotExport(one.target, [], offsets=one.offsets)
        result.limitations += [Limitation(lim.triad + tag, lim.what, lim.size, lim.unit, lim.detail)
                               for lim in one.limitations]
        limit = rotation_limitation(entry, first)
        if limit is not None:
            result.limitations.append(limit)
        result.pose_errors.update({name + tag: e for name, e in one.pose_errors.items()})
        for key, lost in one.thermal_intrinsics_lost.items():
            result.thermal_intrinsics_lost[key + tag] = lost
        per_imu.append([f"IMU {entry.instance}: {note}" for note in one.notes])
    if result is None:
        raise ValueError(f"no IMU of the board has an instance the target holds (0..{max_instance})")
    # a note every IMU's export makes is said once, without the IMU's name
    bare = [[n.split(": ", 1)[1] for n in notes_k] for notes_k in per_imu]
    common = set.intersection(*(set(b) for b in bare))
    notes += [n for notes_k in per_imu for n in notes_k if n.split(": ", 1)[1] not in common]
    notes += [n for n in dict.fromkeys(n for b in bare for n in b) if n in common]
    written = ", ".join(str(e.instance) for e in chosen if e.instance <= max_instance)
    notes.append(f"the board's IMUs {written} written as those instances (the file's imus section)")
    result.params = list(params_out.values())
    result.notes = list(dict.fromkeys(notes))
    return result
