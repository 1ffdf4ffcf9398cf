"""The connection the TUI works on: a device, and the simulated rig when ``--simulate``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from serial.tools import list_ports

from drivers import open_device
from drivers.interface import Device
from station.acquisition.operator import Rig
from station.tui.config import TuiConfig

SIMULATED = "simulated unit"


@dataclass
class PortEntry:
    """A serial port as pyserial lists it: device path, description, and what else is known."""

    device: str
    description: str
    details: str = ""

    def line(self) -> str:
        """The port on one line: path, description, then maker, serial number, USB ids, location."""
        text = f"{self.device:<20} {self.description}"
        return text + (f"  ({self.details})" if self.details else "")


def _known(value: object) -> str:
    # pyserial writes "n/a" where the system knows nothing
    text = str(value or "").strip()
    return "" if text.lower() == "n/a" else text


def available_ports() -> list[PortEntry]:
    """Serial ports of this machine with what is known of them (pyserial's list_ports).

    Returns
    -------
    list of PortEntry
        Sorted by device path; ``details`` holds the maker, product, serial number, USB
        vendor:product ids and location where the system reports them.
    """
    entries = []
    for p in sorted(list_ports.comports()):
        description = _known(p.description)
        details = [_known(p.manufacturer)]
        if _known(p.product) not in description:  # Linux often repeats the product as the description
            details.append(_known(p.product))
        if _known(p.serial_number):
            details.append(f"SN {_known(p.serial_number)}")
        if p.vid is not None and p.pid is not None:
            details.append(f"USB {p.vid:04X}:{p.pid:04X}")
        if _known(p.location):
            details.append(f"at {_known(p.location)}")
        entries.append(PortEntry(p.device, "" if description == p.device else description,
                                 ", ".join(d for d in details if d)))
    return entries


@dataclass
class Session:
    """An open device; ``rig`` moves the simulated unit (None on a real port)."""

    device: Device
    name: str
    rig: Rig | None = None
    closers: list[Any] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)

    def close(self) -> None:
        """Close the device and everything opened with it (the simulated unit's pty)."""
        self.device.close()
        for closer in self.closers:
            closer()


def open_session(config: TuiConfig, port: str | None) -> Session:
    """Open ``port``, or the simulated unit when ``port`` is None or :data:`SIMULATED`, and ask who it is."""
    if port is None or port == SIMULATED:
        session = open_simulated(config)
    else:
        session = Session(open_device(port, protocol=config.protocol), port)
    try:
        session.info = session.device.get_info() if config.protocol == "native" else dict(session.device.info)
    except Exception:
        session.close()
        raise
    return session


def open_simulated(config: TuiConfig) -> Session:
    """The simulated unit served on a pseudo-terminal, opened like any port; its rig is the unit itself."""
    from mocks.device import SimDevice
    from mocks.pty_server import PtyServer

    device = SimDevice(seed=config.seed, rate_hz=config.rate_hz, scenario="still")
    server = PtyServer(device, speed=config.speed).start()
    try:
        port = open_device(server.port_path, protocol="native")
    except Exception:
        server.stop()
        raise
    clock = f", clock x{config.speed:g}" if config.speed != 1 else ""
    return Session(port, f"{SIMULATED} (seed {config.seed}{clock}) on {server.port_path}", rig=device,
                   closers=[server.stop])
