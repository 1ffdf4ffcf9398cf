"""imu-station: acquisition, calibration and firmware export for IMUs."""

import os as _os
import signal as _signal
import sys as _sys


def _quiet_while_starting(signum: int, frame: object) -> None:
    # Ctrl-C or SIGTERM during the imports, before the command's own handling: one line, no traceback
    _sys.stderr.write("imu-station: interrupted while starting\n")
    _os._exit(128 + signum)


if _sys.argv and _os.path.basename(_sys.argv[0]) == "imu-station":  # the command, not a library import
    for _sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(_sig, _quiet_while_starting)

__version__ = "0.1.0"

from station.common import moved as _moved  # noqa: E402  (old module paths, for one release)

_moved.install()
