"""Several IMUs on one board: what a decoder of several IMU instances returns.

A board may carry two or three IMUs and send each one's samples in the same stream: MAVLink's
``SCALED_IMU`` / ``SCALED_IMU2`` / ``SCALED_IMU3`` (instances 0, 1, 2) and the ``id`` of
``HIGHRES_IMU`` and ``RAW_IMU``, or one frame of a board's own that carries several IMUs' values
(a frame description whose fields give ``imu: k``). A decoder that can tell the instances apart
has ``decode_instances()``; until it is called it decodes one IMU as it always did (the fast path
of a single stream pays nothing). Once it is called, every ``feed`` returns an
:class:`InstancesDecoded`: ``samples`` are instance 0's, as a single stream's would be (so the
link statistics and everything that knows one stream are unchanged), and ``instances`` holds the
batches of the instances 1 and up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocols.base import Decoded

MAX_INSTANCE = 255
"""The largest IMU instance number (MAVLink's ``id`` is a uint8)."""


@dataclass
class InstancesDecoded(Decoded):
    """What one ``feed`` of a decoder of several IMU instances completed.

    ``samples`` are instance 0's; ``instances`` maps each other instance (1 and up) that completed
    samples in this feed to its batch (``SAMPLE_DTYPE`` or ``MAG_SAMPLE_DTYPE``), on the same
    device clock.
    """

    instances: dict[int, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return super().__len__() + sum(len(b) for b in self.instances.values())


def mavlink_instance(message: str, imu_id: int) -> int:
    """The IMU instance of a MAVLink IMU message: ``SCALED_IMU`` 0, ``SCALED_IMU2`` 1, ``SCALED_IMU3`` 2,
    ``HIGHRES_IMU`` and ``RAW_IMU`` their ``id`` field.

    Parameters
    ----------
    message : str
        The message name (one of ``protocols.mavlink.IMU_MESSAGES``).
    imu_id : int
        Its ``id`` field (0 for the messages without one).

    Returns
    -------
    int
    """
    if message == "SCALED_IMU2":
        return 1
    if message == "SCALED_IMU3":
        return 2
    return imu_id
