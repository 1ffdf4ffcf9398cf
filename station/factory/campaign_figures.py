"""A campaign's figures from its records: turn-on repeatability per soak and the bias hysteresis.

Bias hysteresis: the unit is still in one pose during every ramp, so gravity and the Earth rate are
the same in every ramp record and the mean reading at a temperature differs between the up and the
down sweep by the hysteresis (and by the T/dT term, the two sweeps' dT having opposite signs).
Binned by the unit's temperature into ``bin_c`` wide bins, over the bins both sweeps visit with at
least ``min_samples`` samples each::

    h_b = mean(y | up, T in b) - mean(y | down, T in b)                                      (1)
    h   = (1/B) sum_b h_b,      h_max = max_b |h_b|                                          (2)

per axis, for the accelerometer (m/s^2) and the gyroscope (rad/s).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

BIN_C = 1.0
MIN_SAMPLES = 20


@dataclass(frozen=True)
class Sweep:
    """One ramp's still record: its direction (+1 up, -1 down), temperature, readings and times (s)."""

    direction: int
    temp: np.ndarray
    acc: np.ndarray
    gyro: np.ndarray
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class Hysteresis:
    """Eq. (2) per triad and axis, over ``bins`` common bins from ``t_min`` to ``t_max`` degC."""

    accel: np.ndarray
    gyro: np.ndarray
    accel_max: np.ndarray
    gyro_max: np.ndarray
    bins: int
    t_min: float
    t_max: float

    def to_dict(self) -> dict[str, object]:
        """The figures as the parameter file's ``characterisation.across_temperature.hysteresis``."""
        return {"accel_bias": self.accel.tolist(), "gyro_bias": self.gyro.tolist(),
                "accel_bias_max": self.accel_max.tolist(), "gyro_bias_max": self.gyro_max.tolist(),
                "bins": self.bins, "bin_c": BIN_C, "t_min": self.t_min, "t_max": self.t_max}


def _binned(sweeps: Sequence[Sweep], edges: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    temp = np.concatenate([s.temp for s in sweeps])
    acc = np.concatenate([s.acc for s in sweeps])
    gyro = np.concatenate([s.gyro for s in sweeps])
    good = np.isfinite(temp)
    idx = np.digitize(temp[good], edges) - 1
    n_bins = len(edges) - 1
    inside = (idx >= 0) & (idx < n_bins)
    idx = idx[inside]
    counts = np.bincount(idx, minlength=n_bins).astype(float)
    means = []
    for values in (acc[good][inside], gyro[good][inside]):
        sums = np.stack([np.bincount(idx, values[:, k], minlength=n_bins) for k in range(3)], axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            means.append(sums / counts[:, None])
    return counts, means[0], means[1]


def bias_hysteresis(sweeps: Sequence[Sweep], bin_c: float = BIN_C, min_samples: int = MIN_SAMPLES
                    ) -> Hysteresis | None:
    """Up minus down sweep mean readings at equal temperature, eqs. (1)-(2).

    Parameters
    ----------
    sweeps : sequence of Sweep
        The ramp records, each with its direction.
    bin_c : float
        Bin width, degC.
    min_samples : int
        Samples each sweep needs in a bin for the bin to count.

    Returns
    -------
    Hysteresis or None
        None when no bin is visited by both an up and a down sweep.
    """
    up = [s for s in sweeps if s.direction > 0 and len(s.temp)]
    down = [s for s in sweeps if s.direction < 0 and len(s.temp)]
    if not up or not down:
        return None
    temps = np.concatenate([s.temp for s in (*up, *down)])
    temps = temps[np.isfinite(temps)]
    if not len(temps):
        return None
    edges = np.arange(np.floor(temps.min() / bin_c) * bin_c, temps.max() + bin_c, bin_c)
    if len(edges) < 2:
        return None
    n_up, acc_up, gyro_up = _binned(up, edges)
    n_down, acc_down, gyro_down = _binned(down, edges)
    common = (n_up >= min_samples) & (n_down >= min_samples)
    if not common.any():
        return None
    d_acc = acc_up[common] - acc_down[common]
    d_gyro = gyro_up[common] - gyro_down[common]
    centres = 0.5 * (edges[:-1] + edges[1:])[common]
    return Hysteresis(d_acc.mean(axis=0), d_gyro.mean(axis=0), np.abs(d_acc).max(axis=0),
                      np.abs(d_gyro).max(axis=0), int(common.sum()), float(centres.min() - bin_c / 2),
                      float(centres.max() + bin_c / 2))
