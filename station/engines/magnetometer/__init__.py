"""Magnetometer calibration: hard and soft iron and the rotation to the accelerometer,
fitted with the dip-angle constraint; the coverage of field directions a session visited; the
Earth's field at a place and date (World Magnetic Model).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.engines.magnetometer.accel import ALL as ALL
    from station.engines.magnetometer.accel import NO_Z_BIAS as NO_Z_BIAS
    from station.engines.magnetometer.accel import PoseAccel as PoseAccel
    from station.engines.magnetometer.calibration import MIN_COVERAGE as MIN_COVERAGE
    from station.engines.magnetometer.calibration import WARN_COVERAGE as WARN_COVERAGE
    from station.engines.magnetometer.calibration import MagCalibration as MagCalibration
    from station.engines.magnetometer.calibration import MagCapture as MagCapture
    from station.engines.magnetometer.calibration import MagSettings as MagSettings
    from station.engines.magnetometer.calibration import calibrate_mag as calibrate_mag
    from station.engines.magnetometer.coverage import CELLS as CELLS
    from station.engines.magnetometer.coverage import MagCoverage as MagCoverage
    from station.engines.magnetometer.coverage import cell_bounds as cell_bounds
    from station.engines.magnetometer.coverage import cell_centres as cell_centres
    from station.engines.magnetometer.coverage import cell_index as cell_index
    from station.engines.magnetometer.coverage import direction_label as direction_label
    from station.engines.magnetometer.coverage import field_coverage as field_coverage
    from station.engines.magnetometer.fit import JointProblem as JointProblem
    from station.engines.magnetometer.fit import ellipsoid_fit as ellipsoid_fit
    from station.engines.magnetometer.fit import sphere_fit as sphere_fit
    from station.engines.magnetometer.geomagnetic import field_at as field_at

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "accel": ("ALL", "NO_Z_BIAS", "PoseAccel"),
    "calibration": ("calibrate_mag", "MagCalibration", "MagCapture", "MagSettings", "MIN_COVERAGE",
                    "WARN_COVERAGE"),
    "coverage": ("cell_bounds", "cell_centres", "cell_index", "CELLS", "direction_label", "field_coverage",
                 "MagCoverage"),
    "fit": ("ellipsoid_fit", "JointProblem", "sphere_fit"),
    "geomagnetic": ("field_at",),
})
