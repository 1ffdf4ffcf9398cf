"""Transports: a serial port, pty or pyserial URL; a reader thread; link statistics; device commands.

``open_device(port)`` is the one way in; everything above ``drivers/`` sees the
:class:`~drivers.interface.Device` interface, whatever is behind the port.
"""

from __future__ import annotations

from drivers.errors import (
    CommandError,
    CommandRejected,
    CommandTimeout,
    CommandUnsupported,
    DriverError,
    NoSamples,
    PortBusy,
    PortError,
    PortFlooding,
    PortLost,
    PortNotFound,
    PortPermission,
)
from drivers.interface import Device
from drivers.link_stats import LinkStats
from drivers.serial_device import DEFAULT_BAUDRATE, SerialDevice


def open_device(port: str, protocol: str = "native", baudrate: int = DEFAULT_BAUDRATE,
                **options: object) -> Device:
    """Open the IMU at ``port`` (device path, pty or pyserial URL such as ``sim://``)."""
    return SerialDevice(port, protocol=protocol, baudrate=baudrate, **options)  # type: ignore[arg-type]


__all__ = [
    "CommandError", "CommandRejected", "CommandTimeout", "CommandUnsupported", "Device", "DriverError",
    "LinkStats", "NoSamples", "PortBusy", "PortError", "PortFlooding", "PortLost", "PortNotFound",
    "PortPermission",
    "DEFAULT_BAUDRATE", "SerialDevice", "open_device",
]
