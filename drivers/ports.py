"""The serial ports of this machine with what is known of them (pyserial's ``list_ports``).

One function for ``imu-station ports`` and any screen that offers a port to choose.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from serial.tools.list_ports_common import ListPortInfo


@dataclass(frozen=True)
class SerialPort:
    """A serial port and what the system reports of it; None where it reports nothing."""

    device: str
    description: str | None = None
    hwid: str | None = None
    vid: int | None = None
    pid: int | None = None
    serial_number: str | None = None
    manufacturer: str | None = None
    product: str | None = None
    location: str | None = None

    @property
    def usb_id(self) -> str | None:
        """USB ``VID:PID`` in hex (``0403:6001``), None for a port not on USB."""
        return f"{self.vid:04X}:{self.pid:04X}" if self.vid is not None and self.pid is not None else None

    def as_dict(self) -> dict[str, Any]:
        """Every field, and ``usb_id``, for JSON."""
        return {**asdict(self), "usb_id": self.usb_id}

    def line(self) -> str:
        """The port on one line: path, description, then maker, product, serial number, USB ids, location."""
        details = [self.manufacturer]
        if self.product and self.product not in (self.description or ""):
            details.append(self.product)  # Linux often repeats the product as the description
        details += [f"SN {self.serial_number}" if self.serial_number else None,
                    f"USB {self.usb_id}" if self.usb_id else None,
                    f"at {self.location}" if self.location else None]
        known = ", ".join(d for d in details if d)
        return f"{self.device:<20} {self.description or ''}".rstrip() + (f"  ({known})" if known else "")


def _known(value: object) -> str | None:
    # pyserial writes "n/a" where the system knows nothing
    text = str(value).strip() if value is not None else ""
    return None if not text or text.lower() == "n/a" else text


def describe_port(info: ListPortInfo) -> SerialPort:
    """What pyserial's ``ListPortInfo`` knows of a port, "n/a" and repeats of the path dropped.

    Parameters
    ----------
    info : serial.tools.list_ports_common.ListPortInfo
        One entry of ``serial.tools.list_ports.comports()``.

    Returns
    -------
    SerialPort
    """
    description = _known(info.description)
    return SerialPort(
        device=info.device, description=None if description == info.device else description,
        hwid=_known(info.hwid), vid=info.vid, pid=info.pid, serial_number=_known(info.serial_number),
        manufacturer=_known(info.manufacturer), product=_known(info.product), location=_known(info.location))


def list_serial_ports() -> list[SerialPort]:
    """The serial ports of this machine, sorted by device path.

    Pseudo-terminals (``imu-station simulate``) and pyserial URLs (``sim://``) are not listed:
    the system does not enumerate them.

    Returns
    -------
    list of SerialPort
    """
    from serial.tools import list_ports

    return sorted((describe_port(p) for p in list_ports.comports()), key=lambda p: p.device)
