"""The device interface everything above ``drivers/`` uses: a real unit and the simulator alike.

A device delivers samples as numpy batches of ``protocols.base.SAMPLE_DTYPE`` in arrival order,
keeps :class:`~drivers.link_stats.LinkStats`, knows what the unit said about itself, and sends
commands that wait for their answer. When the link breaks, every sample received before the
break is delivered first; the next read then raises the error (``PortLost``).

A board of several IMUs (``protocols.instances``): :meth:`Device.read` delivers one instance, as from a
board of one; a device opened with ``instances=True`` also keeps the other instances' batches for
:meth:`Device.take_instances`. :attr:`Device.imu_instances` says which instances the unit streams.
"""

from __future__ import annotations

import abc
from collections.abc import Iterator
from typing import Any

import numpy as np

from drivers.link_stats import LinkStats


class Device(abc.ABC):
    """One IMU on one link. Use as a context manager, or call :meth:`close`."""

    #: the port path or URL it was opened with
    port: str
    #: the protocol name (``protocols.registry``); ``frame:<name>`` for a frame description (its ``name``)
    protocol: str

    @abc.abstractmethod
    def read(self, timeout: float | None = None) -> np.ndarray:
        """Every sample received since the last read, as one batch (empty on timeout).

        Raises the link's error (``PortLost``, ...) once everything received before it was
        delivered.
        """

    def batches(self, timeout: float = 0.1) -> Iterator[np.ndarray]:
        """Non-empty batches until the device is closed; raises the link's error like :meth:`read`."""
        while not self.closed:
            batch = self.read(timeout)
            if len(batch):
                yield batch

    def take_instances(self) -> dict[int, np.ndarray]:
        """The samples of the IMU instances other than :meth:`read`'s received since the last call, by
        instance (never waits; a device not opened with ``instances=True`` keeps none: ``{}``)."""
        return {}

    @property
    def imu_instances(self) -> dict[int, int]:
        """The IMU instances the unit streams, with the samples seen of each, when its protocol tells
        several apart (MAVLink, a frame description with ``imu:``); ``{}`` otherwise."""
        return {}

    @property
    def imu_instance(self) -> int | None:
        """The IMU instance :meth:`read` delivers, when the protocol tells instances apart (else None)."""
        return None

    @property
    @abc.abstractmethod
    def stats(self) -> LinkStats:
        """A snapshot of the link statistics."""

    @property
    @abc.abstractmethod
    def info(self) -> dict[str, Any]:
        """The last DEVICE_INFO the unit sent (empty until it sent one)."""

    @property
    @abc.abstractmethod
    def closed(self) -> bool:
        """True after :meth:`close`."""

    @abc.abstractmethod
    def get_info(self, timeout: float = 1.0, retries: int = 2) -> dict[str, Any]:
        """Ask the unit who it is: serial, model, firmware, rate_hz; asked again up to ``retries`` times
        when no answer comes within ``timeout``."""

    @abc.abstractmethod
    def restart(self, timeout: float = 1.0) -> None:
        """Restart the unit as at power-up (native RESTART), sent once; ``CommandUnsupported`` for a
        protocol without it, ``CommandRejected`` (status ``ACK_UNKNOWN``) for a unit that cannot."""

    @abc.abstractmethod
    def set_rate(self, rate_hz: int, timeout: float = 1.0) -> None:
        """Set the output data rate; raises ``CommandRejected`` if the unit refuses it."""

    @abc.abstractmethod
    def start(self, timeout: float = 1.0) -> None:
        """Start streaming samples."""

    @abc.abstractmethod
    def stop(self, timeout: float = 1.0) -> None:
        """Stop streaming samples."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop the reader and release the port. Safe to call twice."""

    def __enter__(self) -> Device:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
