"""The numerics and models every engine shares: the triad model and its correction, input
checks, Levenberg-Marquardt, quaternions, the Earth model and static-interval detection.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.engines.shared.correction import apply_calibration as apply_calibration
    from station.engines.shared.correction import apply_mag as apply_mag
    from station.engines.shared.earth import earth_rate_vertical as earth_rate_vertical
    from station.engines.shared.earth import normal_gravity as normal_gravity
    from station.engines.shared.levenberg_marquardt import LsqResult as LsqResult
    from station.engines.shared.levenberg_marquardt import least_squares_lm as least_squares_lm
    from station.engines.shared.samples import as_samples as as_samples
    from station.engines.shared.samples import check_rate as check_rate
    from station.engines.shared.sensor_model import SensorCalibration as SensorCalibration
    from station.engines.shared.static_detect import moving_variance_norm as moving_variance_norm
    from station.engines.shared.static_detect import static_intervals as static_intervals
    from station.engines.shared.static_detect import variance_norm as variance_norm

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "correction": ("apply_calibration", "apply_mag"),
    "earth": ("earth_rate_vertical", "normal_gravity"),
    "levenberg_marquardt": ("least_squares_lm", "LsqResult"),
    "samples": ("as_samples", "check_rate"),
    "sensor_model": ("SensorCalibration",),
    "static_detect": ("moving_variance_norm", "static_intervals", "variance_norm"),
})
