"""Record constant-rate steps on a rate table into a labelled capture (``rate+z:90``), for the
scale-factor nonlinearity and asymmetry of ``imu-station characterise``.

For each axis and rate the table is told ``SPIN <axis> <rate> <hold>`` (``drivers.turntable``): it moves
the axis up, spins up, settles, holds the rate for ``hold`` seconds and spins down, and reports IDLE
once still. The unit's samples are read meanwhile. The rows are labelled from the unit's own samples,
not the table's word: the unit's plateau is the median of its rate about the axis where that is
within 20 % of the asked rate (its scale error and bias shift it from the table's); the steady part
is the longest run within ``STEADY_FRACTION`` of the plateau plus a few noise sigma, and of it the
last ``hold`` seconds carry the step's label (the table settled before them), per the capture CSV
spec.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO

import numpy as np

from drivers import Device
from drivers.turntable import Turntable
from station.acquisition.capture_csv import write_csv
from station.acquisition.sinks import samples_to_capture
from station.errors import StationError

STEADY_FRACTION = 0.002  # a step's samples within 0.2 % of the plateau (and noise) count as steady
NEAR_FRACTION = 0.2  # where the unit's rate is within 20 % of the asked one, its median is the plateau
NOISE_SIGMAS = 6.0
SPIN_TIMEOUT_PAD_S = 60.0  # wall seconds allowed beyond the step's own length (moves, spin-up)
STILL_S = 0.3  # wall seconds read still before each step, for the rate's noise


class RateTableError(StationError):
    """A rate step never reached its rate, or was shorter than asked."""


def rate_label(axis: str, rate_dps: float) -> str:
    """The capture-csv label of a step: ``rate+z:90`` for +90 deg/s about +z, ``rate-z:90`` for -90.

    Parameters
    ----------
    axis : str
        ``x``, ``y`` or ``z``.
    rate_dps : float
        Signed rate, deg/s.

    Returns
    -------
    str
    """
    return f"rate{'+' if rate_dps >= 0 else '-'}{axis}:{abs(rate_dps):g}"


def steady_rows(rate: np.ndarray, asked: float, noise_sd: float, rate_hz: float, hold_s: float) -> slice:
    """The rows of a step to label: the last ``hold_s`` of the longest run within tolerance of the plateau.

    Parameters
    ----------
    rate : ndarray, (N,)
        The unit's rate about the step's axis, rad/s.
    asked : float
        The table's rate, rad/s (signed).
    noise_sd : float
        The rate's noise, rad/s (from the still samples before the step).
    rate_hz : float
        Sample rate.
    hold_s : float
        Seconds the table held the rate once settled.

    Returns
    -------
    slice
        Empty when no run is long enough.
    """
    near = np.abs(rate - asked) < NEAR_FRACTION * abs(asked)
    if not near.any():
        return slice(0, 0)
    plateau = float(np.median(rate[near]))
    inside = np.abs(rate - plateau) < STEADY_FRACTION * abs(plateau) + NOISE_SIGMAS * noise_sd
    edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
    starts, stops = edges[::2], edges[1::2]
    if not len(starts):
        return slice(0, 0)
    longest = int(np.argmax(stops - starts))
    want = int(round(hold_s * rate_hz))
    stop = int(stops[longest])
    start = max(int(starts[longest]), stop - want)
    return slice(start, stop)


def record_rate_steps(device: Device, table: Turntable, output: Path, rates_dps: Sequence[float],
                      axes: str = "xyz", hold_s: float = 5.0, err: IO[str] | None = None,
                      on_step: Callable[[str], None] | None = None) -> Path:
    """Spin the unit through every axis and signed rate, record it, label the steady rows, write ``output``.

    Parameters
    ----------
    device : Device
        The unit, open and streaming.
    table : Turntable
        The rate table carrying it.
    output : Path
        The labelled capture CSV.
    rates_dps : sequence of float
        Positive rates, deg/s; each is run both ways.
    axes : str
        Axes to turn about.
    hold_s : float
        Seconds held at each rate once settled.
    err : text stream, optional
        Where each step is announced.
    on_step : callable, optional
        Called with each step's label before it runs.

    Returns
    -------
    Path
        ``output``.

    Raises
    ------
    RateTableError
        A step whose samples never hold its rate for ``hold_s``.
    """
    batches: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    table.wait_idle()
    for axis in axes:
        for rate in [r for r in rates_dps] + [-r for r in rates_dps]:
            label = rate_label(axis, rate)
            if on_step is not None:
                on_step(label)
            if err is not None:
                print(f"{label}: spinning {hold_s:g} s once steady", file=err)
            table.pose(f"+{axis}")
            table.wait_idle(timeout_s=SPIN_TIMEOUT_PAD_S)
            device.read(0)  # the move
            time.sleep(STILL_S)
            still = device.read(0.2)  # still, axis up: the rate's noise
            table.spin(f"+{axis}", rate, hold_s)
            table.wait_idle(timeout_s=hold_s * 3 + SPIN_TIMEOUT_PAD_S)
            step = np.concatenate([g for g in (still, device.read(0.2)) if len(g)])
            if len(step) < 2:
                raise RateTableError(f"{label}: no samples from the unit during the step; check its link")
            rate_hz = 1e6 / float(np.median(np.diff(step["t_us"].astype(np.float64))))
            index = "xyz".index(axis)
            noise = float(np.std(still["gyro"][:, index])) if len(still) > 2 else 0.0
            gyro = step["gyro"][:, index].astype(float)
            rows = steady_rows(gyro, math.radians(rate), noise, rate_hz, hold_s)
            held = (rows.stop - rows.start) / rate_hz
            if held < 0.9 * hold_s:
                raise RateTableError(f"{label}: the unit held a steady rate near {math.radians(rate):.4g} "
                                     f"rad/s for {held:.3g} s, not the {hold_s:g} s asked: check the table's "
                                     "rate, its mounting (axis) and the unit's range")
            step_labels = np.full(len(step), "", dtype=object)
            step_labels[rows] = label
            batches.append(step)
            labels.append(step_labels)
    capture = samples_to_capture(np.concatenate(batches), np.concatenate(labels), device=device.info,
                                 source=f"rate table {table.port}")
    write_csv(output, capture)
    return output
