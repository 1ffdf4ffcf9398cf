"""A log's magnetometer beside one of its IMUs: the field in microtesla at the IMU's sample times.

- **PX4** ``sensor_mag`` (``multi_id``): the driver's output in gauss (1 G = 100 uT) in the board's axes,
  before the calibration (``CAL_MAGn_*``) and an external magnetometer's ``CAL_MAGn_ROT``, which PX4's
  sensors module applies downstream: nothing to take out.
- **ArduPilot** ``MAG`` (``I``; ``MAG2``/``MAG3`` in older logs), milligauss (1 uT = 10 mG), logged after
  ``AP_Compass_Backend::rotate_field`` and ``correct_field``::

      logged = W ((R raw + COMPASS_OFS) * COMPASS_SCALE) + motor          (1)

  with W symmetric (``COMPASS_DIA_*`` on the diagonal, ``COMPASS_ODI_*`` off it), the scale only where
  set, ``motor`` the message's ``MOX..MOZ`` and R the board rotation (``AHRS_ORIENTATION``) for an
  internal compass, ``COMPASS_ORIENT`` for an external one (``COMPASS_EXTERNAL``). Taken out, eq. (1)
  inverted: ``raw = R^T ((W^-1 (logged - motor)) / COMPASS_SCALE - COMPASS_OFS)``. The parameter names
  are the ArduPilot export's (:func:`station.export.autopilot.ardupilot.compass_names`).

The magnetometer runs slower than the IMU and on its own clock ticks: its field is linearly
interpolated to the IMU's times; IMU samples before its first or after its last sample take that
sample's value (the notes count them). With several magnetometers the first (instance 0) is used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

UT_PER_GAUSS = 100.0
MGAUSS_PER_UT = 10.0
AXES = ("X", "Y", "Z")


@dataclass
class MagSeries:
    """One magnetometer of a log as logged: times (us), field (PX4 gauss, ArduPilot milligauss), motor
    compensation (ArduPilot, milligauss; None for PX4), device id."""

    instance: int
    t_us: np.ndarray
    field: np.ndarray
    motor: np.ndarray | None = None
    device_id: int | None = None


def px4_mags(topics: dict[tuple[str, int], np.ndarray]) -> dict[int, MagSeries]:
    """The ``sensor_mag`` instances of a decoded ULog.

    Parameters
    ----------
    topics : dict
        ``UlogData.topics``.

    Returns
    -------
    dict of int to MagSeries
    """
    out = {}
    for (name, m), rec in topics.items():
        if name != "sensor_mag" or len(rec) == 0:
            continue
        field = np.column_stack([rec[c].astype(np.float64) for c in ("x", "y", "z")])
        device = int(np.median(rec["device_id"])) if "device_id" in (rec.dtype.names or ()) else None
        out[m] = MagSeries(m, rec["timestamp_sample"].astype(np.int64), field, None, device)
    return out


def dataflash_mags(columns: dict[int, dict[str, np.ndarray]]) -> dict[int, MagSeries]:
    """The ``MAG`` instances of a DataFlash log (columns by name, as ``read_dataflash`` gives them).

    Parameters
    ----------
    columns : dict
        ``DataflashData.mags``.

    Returns
    -------
    dict of int to MagSeries
    """
    out = {}
    for i, cols in columns.items():
        if len(cols.get("TimeUS", ())) == 0:
            continue
        field = np.column_stack([cols[f"Mag{a}"] for a in AXES])
        motor = (np.column_stack([cols[f"MO{a}"] for a in AXES]) if all(f"MO{a}" in cols for a in AXES)
                 else None)
        out[i] = MagSeries(i, cols["TimeUS"].astype(np.int64), field, motor)
    return out


def _to_times(mag: MagSeries, field_ut: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, int]:
    """The field at the IMU's times (linear), and how many IMU samples lie outside the magnetometer's span."""
    t_mag = mag.t_us * 1e-6
    outside = int(np.count_nonzero((t_s < t_mag[0]) | (t_s > t_mag[-1])))
    return np.column_stack([np.interp(t_s, t_mag, field_ut[:, j]) for j in range(3)]), outside


def ardupilot_raw(mag: MagSeries, params: dict[str, float]) -> tuple[np.ndarray, list[str]]:
    """Eq. (1) inverted: the compass's field in microtesla before ArduPilot's rotation and correction.

    Parameters
    ----------
    mag : MagSeries
        A DataFlash ``MAG`` instance (milligauss).
    params : dict
        The log's parameters.

    Returns
    -------
    ndarray, (n, 3)
        Microtesla, in the board's axes (internal) or the compass's own (external).
    list of str
        What was taken out.

    Raises
    ------
    ValueError
        A rotation pymavlink's table does not hold, or a singular W.
    """
    from station.acquisition.dataflash_reader import board_rotation
    from station.export.autopilot.ardupilot import compass_names
    from station.export.autopilot.shared import symmetric_from

    n = compass_names(mag.instance)
    offsets = np.array([params.get(f"{n['ofs']}{a}", 0.0) for a in AXES])
    scale = params.get(n["scale"], 0.0) or 1.0
    diagonal = [f"{n['dia']}{a}" for a in AXES]
    # ArduPilot takes all-zero diagonals (never calibrated) as ones
    w = symmetric_from(params, diagonal, [f"{n['odi']}{a}" for a in AXES], 1.0)
    if not np.any(np.diag(w)):
        w[np.diag_indices(3)] = 1.0
    logged = mag.field - (mag.motor if mag.motor is not None else 0.0)
    suffix = "" if mag.instance == 0 else str(mag.instance + 1)
    external = params.get(f"COMPASS_EXTERN{suffix}" if suffix else "COMPASS_EXTERNAL", 0.0)
    orientation = int(params.get(f"COMPASS_ORIENT{suffix}", 0) if external
                      else params.get("AHRS_ORIENTATION", 0))
    rotated = np.linalg.solve(w, logged.T).T / scale - offsets  # R raw, milligauss
    raw = rotated @ board_rotation(orientation) if orientation else rotated
    taken = [f"{n['ofs'].rstrip('_')}, {n['dia'].rstrip('_')}/{n['odi'].rstrip('_')}"
             + (f", {n['scale']}" if scale != 1.0 else "")]
    if mag.motor is not None and np.any(mag.motor):
        taken.append("the motor compensation (MOX..MOZ)")
    if orientation:
        taken.append(f"{'COMPASS_ORIENT' + suffix if external else 'AHRS_ORIENTATION'} {orientation}")
    return raw / MGAUSS_PER_UT, taken


def field_at(mags: dict[int, MagSeries], t_s: np.ndarray, kind: str, params: dict[str, float],
             remove: bool) -> tuple[np.ndarray | None, list[str]]:
    """The first magnetometer's field (microtesla) at the IMU's times ``t_s``, and the notes.

    Parameters
    ----------
    mags : dict of int to MagSeries
        The log's magnetometers (none: the capture has no field).
    t_s : ndarray
        The IMU's sample times, s.
    kind : str
        ``ulog`` or ``dataflash``.
    params : dict
        The log's parameters.
    remove : bool
        Take ArduPilot's correction out (eq. 1).

    Returns
    -------
    ndarray or None, (n, 3)
    list of str

    Raises
    ------
    ValueError
        ArduPilot's correction cannot be undone (see :func:`ardupilot_raw`).
    """
    if not mags or len(t_s) == 0:
        return None, []
    first = min(mags)
    mag = mags[first]
    notes = []
    if kind == "ulog":
        field = mag.field * UT_PER_GAUSS
        device = f" (device {mag.device_id})" if mag.device_id is not None else ""
        notes.append(f"magnetometer: sensor_mag {first}{device}, raw: before PX4's CAL_MAG* (matched by "
                     "device id), nothing taken out")
    elif remove:
        field, taken = ardupilot_raw(mag, params)
        notes.append(f"magnetometer: MAG {first}, {', '.join(taken)} taken out")
    else:
        field = mag.field / MGAUSS_PER_UT
        notes.append(f"magnetometer: MAG {first}, ArduPilot's compass correction left in (as asked)")
    at_imu, outside = _to_times(mag, field, t_s)
    rate = (len(mag.t_us) - 1) / ((mag.t_us[-1] - mag.t_us[0]) * 1e-6) if len(mag.t_us) > 1 else float("nan")
    notes[-1] += f"; {rate:.3g} Hz, linearly interpolated to the IMU's times"
    if outside:
        notes[-1] += f" ({outside} IMU samples outside its span take its first or last value)"
    if len(mags) > 1:
        notes[-1] += f"; magnetometers {sorted(m for m in mags if m != first)} not read"
    return at_imu, notes
