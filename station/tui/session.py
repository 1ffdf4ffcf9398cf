"""The connection the TUI works on: a device, and the simulated rig when ``--simulate``.

A port is opened as a :class:`~drivers.paced_port.PacedPort`: the screens' workers read it in
their own loops, a batch every 20 ms, with no reader thread waking for every few bytes (a
pyserial URL such as ``sim://`` keeps the threaded device).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.interface import Device
from drivers.paced_port import open_paced
from station.acquisition.operator import Rig
from station.tui.config import TuiConfig

SIMULATED = "simulated unit"


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
        session = Session(open_paced(port, protocol=config.protocol), port)
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

    truth = None
    if config.mag:
        from mocks.mag_sessions import nine_axis_unit

        truth = nine_axis_unit(config.seed)
    device = SimDevice(truth, seed=config.seed, rate_hz=config.rate_hz, scenario="still")
    server = PtyServer(device, speed=config.speed).start()
    try:
        port = open_paced(server.port_path, protocol="native")
    except Exception:
        server.stop()
        raise
    clock = f", clock x{config.speed:g}" if config.speed != 1 else ""
    return Session(port, f"{SIMULATED} (seed {config.seed}{clock}) on {server.port_path}", rig=device,
                   closers=[server.stop])
