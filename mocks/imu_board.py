"""A simulated board of several IMUs: one truth per IMU instance, one rig, one link.

A flight controller carries two or three IMUs on one board and streams each one's samples in the same
byte stream (``protocols.instances``). :class:`ImuBoard` is such a board for
:class:`~mocks.pty_server.PtyServer`: each instance is a :class:`~mocks.device.SimDevice` of its own
``UnitTruth`` (its own biases, scale, misalignment and noise), all on the same rig (the same scenario,
so the same motion) and sampled at the same instants, and the board sends them as

- MAVLink (``protocol="mavlink"``): per sample instant, instance 0 as ``SCALED_IMU``, 1 as
  ``SCALED_IMU2``, 2 as ``SCALED_IMU3`` (``message="HIGHRES_IMU"`` or ``"RAW_IMU"``: that message
  with ``id`` = the instance), as ArduPilot does;
- or the frames of a frame description whose fields give ``imu: k`` (``protocol=`` the
  :class:`~protocols.frame_description.FrameDescription`): one frame carries every instance.

What :meth:`ImuBoard.produce` returns (and ``PtyServer(record=True).sent()`` keeps) is a board batch:
one record per sample instant with a ``SAMPLE_DTYPE`` field ``imu0``, ``imu1``, ... per instance, the
truth a test compares each instance's capture with. The board streams from power-up and answers no
command (an autopilot's MAVLink stream is not the native protocol).

    with PtyServer(ImuBoard(seed=3), speed=4.0) as srv:
        imu-station capture --port srv.port_path --protocol mavlink --instances all -o board.csv
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocks.device import SimDevice
from mocks.rig import UnitSampler
from mocks.truth import UnitTruth
from protocols.base import SAMPLE_DTYPE
from protocols.frame import encode_frames
from protocols.frame_description import FrameDescription
from protocols.mavlink import encode_samples

SCALED_MESSAGES = ("SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
"""The MAVLink message of instances 0, 1, 2 (a board of more instances: HIGHRES_IMU or RAW_IMU)."""


def board_dtype(count: int) -> np.dtype:
    """The record of one sample instant of a board of ``count`` IMUs: ``imu0``, ``imu1``, ... each a sample.

    Parameters
    ----------
    count : int

    Returns
    -------
    numpy.dtype
    """
    return np.dtype([(f"imu{k}", SAMPLE_DTYPE) for k in range(count)])


class ImuBoard:
    """A board of several simulated IMUs streaming through one link (module docstring).

    Parameters
    ----------
    truths : sequence of UnitTruth, optional
        One per instance (default: ``count`` random units of seeds ``seed``, ``seed + 1``, ...).
    count : int
        Instances when ``truths`` is None.
    seed : int
        Seeds the units, the rig's scenario (the same for every instance) and each instance's noise.
    rate_hz : float
        The sample rate of every instance (a telemetry rate: tens of hertz).
    scenario : str
        A scenario of ``mocks.device.SCENARIOS``, the same motion for every instance.
    protocol : str or FrameDescription
        ``"mavlink"``, or the frame of several IMUs to send.
    message : str
        With MAVLink: ``"SCALED_IMU"`` (instances as SCALED_IMU, SCALED_IMU2, SCALED_IMU3), ``"HIGHRES_IMU"``
        or ``"RAW_IMU"`` (instance in ``id``).
    """

    def __init__(self, truths: Sequence[UnitTruth] | None = None, *, count: int = 3, seed: int = 0,
                 rate_hz: float = 50.0, scenario: str = "still", protocol: str | FrameDescription = "mavlink",
                 message: str = "SCALED_IMU", system: int = 1, component: int = 1):
        if truths is None:
            truths = [UnitTruth.random(seed + k) for k in range(count)]
        if not truths:
            raise ValueError("a board needs at least one IMU")
        if protocol == "mavlink" and message == "SCALED_IMU" and len(truths) > len(SCALED_MESSAGES):
            raise ValueError(f"SCALED_IMU messages carry {len(SCALED_MESSAGES)} instances; use "
                             "message='HIGHRES_IMU' for more")
        if isinstance(protocol, FrameDescription) and protocol.instances != tuple(range(len(truths))):
            raise ValueError(f"the frame carries instances {protocol.instances}, the board "
                             f"{tuple(range(len(truths)))}")
        self.imus = [SimDevice(truth, seed=seed, rate_hz=rate_hz, scenario=scenario) for truth in truths]
        # The same seed gave every instance the same rig timeline (one board, one motion); the noise of
        # each is its own.
        for k, imu in enumerate(self.imus[1:], 1):
            imu.sampler = UnitSampler(imu.truth, imu.timeline, rate_hz, seed * 7919 + 104_729 * k)
        self.protocol = protocol
        self.message = message
        self.system, self.component = system, component
        self.dtype = board_dtype(len(self.imus))
        self.commands: dict[str, int] = {}
        self.encoder_name = "imu-board"

    @property
    def truths(self) -> list[UnitTruth]:
        """Each instance's truth, by instance."""
        return [imu.truth for imu in self.imus]

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host: the board answers nothing (counted, as ``SimDevice`` counts commands).

        Parameters
        ----------
        data : bytes

        Returns
        -------
        bytes
            Always empty.
        """
        if data:
            self.commands["ignored bytes"] = self.commands.get("ignored bytes", 0) + len(data)
        return b""

    def produce(self, t_s: float) -> np.ndarray:
        """Every sample instant due at or before ``t_s``: a board batch (:func:`board_dtype`).

        Parameters
        ----------
        t_s : float
            Device time, s.

        Returns
        -------
        numpy.ndarray
        """
        batches = [imu.produce(t_s) for imu in self.imus]
        n = min(len(b) for b in batches)  # one rate and one clock: every instance has as many
        out = np.zeros(n, dtype=self.dtype)
        for k, batch in enumerate(batches):
            out[f"imu{k}"] = batch[:n]
        return out

    def encode_frames(self, batch: np.ndarray) -> list[bytes]:
        """The bytes of each sample instant (every instance's message, or the one frame), for fault injection.

        Parameters
        ----------
        batch : numpy.ndarray
            A board batch.

        Returns
        -------
        list of bytes
        """
        if isinstance(self.protocol, FrameDescription):
            data = self.encode_samples(batch)
            size = self.protocol.length
            return [data[i : i + size] for i in range(0, len(data), size)]
        count = len(self.imus)
        return [b"".join(self._mavlink(record[f"imu{k}"].reshape(1), k) for k in range(count))
                for record in batch]

    def encode_samples(self, batch: np.ndarray) -> bytes:
        """A board batch as the bytes the board sends.

        Parameters
        ----------
        batch : numpy.ndarray

        Returns
        -------
        bytes
        """
        if isinstance(self.protocol, FrameDescription):
            values: dict[str, np.ndarray] = {}
            first = batch["imu0"]
            values["seq"] = first["seq"].astype(np.float64)
            values["t"] = first["t_us"] * 1e-6
            for k in range(len(self.imus)):
                s = batch[f"imu{k}"]
                tag = "" if k == 0 else f".imu{k}"
                values[f"temp{tag}"] = s["temp"].astype(np.float64)
                for i, axis in enumerate("xyz"):
                    values[f"a{axis}{tag}"] = s["acc"][:, i].astype(np.float64)
                    values[f"g{axis}{tag}"] = s["gyro"][:, i].astype(np.float64)
            return encode_frames(self.protocol, values)
        return b"".join(self.encode_frames(batch))

    def _mavlink(self, sample: np.ndarray, instance: int) -> bytes:
        if self.message == "SCALED_IMU":
            return encode_samples(sample, SCALED_MESSAGES[instance], self.system, self.component)
        return encode_samples(sample, self.message, self.system, self.component, imu_id=instance)
