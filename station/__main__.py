"""``python -m station``: the same as the ``imu-station`` command."""

import sys

from station.cli import main

sys.exit(main())
