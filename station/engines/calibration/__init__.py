"""Intrinsic calibration of the accelerometer and gyroscope triads: bias, scale factor and
misalignment, from a turntable (or guided) sequence of known poses and turns, or hand-held
(Tedaldi, Pretto, Menegatti, ICRA 2014) without any reference.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.engines.calibration.common import CalibrationReport as CalibrationReport
    from station.engines.calibration.common import convert_convention as convert_convention
    from station.engines.calibration.common import covariance as covariance
    from station.engines.calibration.common import pose_vector as pose_vector
    from station.engines.calibration.common import propagate as propagate
    from station.engines.calibration.common import rotation_of as rotation_of
    from station.engines.calibration.common import segments as segments
    from station.engines.calibration.common import triangular_correction as triangular_correction
    from station.engines.calibration.free import FreeCapture as FreeCapture
    from station.engines.calibration.free import FreeSettings as FreeSettings
    from station.engines.calibration.free import calibrate_free as calibrate_free
    from station.engines.calibration.free_accel import acc_correction as acc_correction
    from station.engines.calibration.free_accel import acc_initial_guess as acc_initial_guess
    from station.engines.calibration.free_accel import acc_jacobian as acc_jacobian
    from station.engines.calibration.free_accel import acc_residual as acc_residual
    from station.engines.calibration.free_gyro import GyroBlocks as GyroBlocks
    from station.engines.calibration.free_gyro import GyroModel as GyroModel
    from station.engines.calibration.free_gyro import bias_sensitivity as bias_sensitivity
    from station.engines.calibration.free_gyro import fit_gyroscope as fit_gyroscope
    from station.engines.calibration.free_gyro import gyro_blocks as gyro_blocks
    from station.engines.calibration.free_gyro import gyro_jacobian as gyro_jacobian
    from station.engines.calibration.free_gyro import gyro_residual as gyro_residual
    from station.engines.calibration.turntable import TurntableCapture as TurntableCapture
    from station.engines.calibration.turntable import TurntableSettings as TurntableSettings
    from station.engines.calibration.turntable import accel_calibration as accel_calibration
    from station.engines.calibration.turntable import calibrate_turntable as calibrate_turntable
    from station.engines.calibration.turntable import fit_accelerometer as fit_accelerometer
    from station.engines.calibration.turntable_gsens import fit_g_sensitivity as fit_g_sensitivity

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "common": ("CalibrationReport", "convert_convention", "covariance", "pose_vector", "propagate",
               "rotation_of", "segments", "triangular_correction"),
    "free": ("calibrate_free", "FreeCapture", "FreeSettings"),
    "free_accel": ("acc_correction", "acc_initial_guess", "acc_jacobian", "acc_residual"),
    "free_gyro": ("bias_sensitivity", "fit_gyroscope", "gyro_blocks", "gyro_jacobian", "gyro_residual",
                  "GyroBlocks", "GyroModel"),
    "turntable": ("accel_calibration", "calibrate_turntable", "fit_accelerometer", "TurntableCapture",
                  "TurntableSettings"),
    "turntable_gsens": ("fit_g_sensitivity",),
})
