"""The simulated unit's other wire formats: Xsens MTData2, MAVLink, text lines.

Importing this module registers them in :data:`mocks.device.ENCODERS`, so a ``SimDevice``
(and ``imu-station simulate --protocol NAME``) can speak as the units people own:

=================  =====================================================================
name               what the unit sends for each sample
=================  =====================================================================
xsens              MTData2: PacketCounter, SampleTimeFine, Acceleration, RateOfTurn,
                   Temperature (float32), as an MTi at its output rate
xsens-fp1632       the same in fixed point 16.32
mavlink            HIGHRES_IMU (MAVLink 2), as PX4 streams it
mavlink-scaled     SCALED_IMU (mG, mrad/s, cdegC)
mavlink-raw        RAW_IMU (ArduPilot's units: mG, mrad/s)
ascii              CSV lines ``t,ax,ay,az,gx,gy,gz,temp`` in SI units
motioncal          PJRC MotionCal ``Raw:`` lines
vnymr              VectorNav ``$VNYMR`` sentences
=================  =====================================================================

The MAVLink encoders need pymavlink; without it they are not registered.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np

from mocks.device import ENCODERS
from protocols import ascii_lines, mavlink, xsens

EXTRA_ENCODERS: dict[str, Callable[[np.ndarray], bytes]] = {
    "xsens": xsens.encode_samples,
    "xsens-fp1632": partial(xsens.encode_samples, precision="fp1632"),
    "ascii": partial(ascii_lines.encode_samples, kind="csv"),
    "motioncal": partial(ascii_lines.encode_samples, kind="motioncal"),
    "vnymr": partial(ascii_lines.encode_samples, kind="vnymr"),
}
if mavlink.pymavlink_available():
    EXTRA_ENCODERS["mavlink"] = partial(mavlink.encode_samples, message="HIGHRES_IMU")
    EXTRA_ENCODERS["mavlink-scaled"] = partial(mavlink.encode_samples, message="SCALED_IMU")
    EXTRA_ENCODERS["mavlink-raw"] = partial(mavlink.encode_samples, message="RAW_IMU")

# The decoder (``protocols.registry`` name) that reads each encoder's bytes.
DECODER_OF = {"xsens": "xsens", "xsens-fp1632": "xsens", "ascii": "ascii", "motioncal": "ascii",
              "vnymr": "ascii", "mavlink": "mavlink", "mavlink-scaled": "mavlink", "mavlink-raw": "mavlink"}

ENCODERS.update(EXTRA_ENCODERS)
