"""imu-station: acquisition, calibration and firmware export for IMUs."""

__version__ = "0.1.0"

from station.common import moved as _moved  # noqa: E402  (old module paths, for one release)

_moved.install()
