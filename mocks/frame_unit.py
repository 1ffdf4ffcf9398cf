"""A simulated unit that streams a board's own frames, as a frame description describes them.

:func:`speak_frames` turns a :class:`~mocks.device.SimDevice` into a board whose samples go out as
the frames of a description (``shared/specs/frame-description.md``): ``run --simulate --protocol
frame:FILE.yaml`` and the tests serve it on a pty like any simulated unit. Such a board has no
commands the station sends; it streams from power-up.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mocks.device import SimDevice
from protocols.frame import encode_frames
from protocols.frame_description import FrameDescription


def frame_encoder(desc: FrameDescription) -> Callable[[np.ndarray], bytes]:
    """The encoder of samples (``SAMPLE_DTYPE``) into the frames of ``desc``, back to back.

    Parameters
    ----------
    desc : FrameDescription
        The frame; the fields it describes carry the samples' values (a counter and a clock wrap
        at their types' ranges, as a board's would).

    Returns
    -------
    callable
        ``samples -> bytes``.
    """
    def encode(samples: np.ndarray) -> bytes:
        values = {"seq": samples["seq"].astype(np.float64), "t": samples["t_us"] * 1e-6,
                  "temp": samples["temp"].astype(np.float64)}
        for i, axis in enumerate("xyz"):
            values[f"a{axis}"] = samples["acc"][:, i].astype(np.float64)
            values[f"g{axis}"] = samples["gyro"][:, i].astype(np.float64)
        return encode_frames(desc, values)

    return encode


def speak_frames(device: SimDevice, desc: FrameDescription) -> SimDevice:
    """Make ``device`` stream the frames of ``desc`` instead of native ones; returns it.

    Parameters
    ----------
    device : SimDevice
        The simulated unit (it still answers native commands, which the station does not send to a
        frame-described board).
    desc : FrameDescription
        The frame.

    Returns
    -------
    SimDevice
        ``device``.
    """
    device.encoder_name = f"frame:{desc.name}"  # no fixed size in FRAME_SIZES: faults encode frame by frame
    device.encode_samples = frame_encoder(desc)
    return device
