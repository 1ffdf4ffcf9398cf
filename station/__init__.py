"""imu-station: acquisition, calibration and firmware export for IMUs."""

__version__ = "0.1.0"
