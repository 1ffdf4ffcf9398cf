"""The connection the TUI works on: a device, and the simulated rig when ``--simulate``.

A port is opened as a :class:`~drivers.paced_port.PacedPort`: the screens' workers read it in
their own loops, a batch every 20 ms, with no reader thread waking for every few bytes (a
pyserial URL such as ``sim://`` keeps the threaded device).

With ``--supply`` the bench supply is opened first and switches the unit on (it may start off), and
the session keeps it for the turn-on screen's power cycles; with ``--table`` the rate table carrying
the unit is opened too (held to ``--table-max-rate`` and ``--table-accel``), for the wizard. A
supply or table that cannot be opened is the connect screen's error, as a port is.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from drivers.errors import DriverError
from drivers.interface import Device
from drivers.paced_port import open_paced
from station.acquisition.operator import Rig
from station.tui.config import TuiConfig

if TYPE_CHECKING:
    from station.instruments.mounted_table import MountedTable
    from station.instruments.power_cycle import SupplyPowerCycle

SIMULATED = "simulated unit"
BOOT_S = 10.0  # wall seconds a unit just switched on by its supply may take to answer


@dataclass
class Session:
    """An open device; ``rig`` moves the simulated unit (None on a real port)."""

    device: Device
    name: str
    rig: Rig | None = None
    closers: list[Any] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    power: SupplyPowerCycle | None = None  # --supply: power-cycles the unit
    table: MountedTable | None = None  # --table: places and turns the unit

    def close(self) -> None:
        """Close the device and everything opened with it (the simulated unit's pty, the instruments)."""
        self.device.close()
        for closer in self.closers:
            closer()


@dataclass
class Instruments:
    """The bench supply and rate table the options name, opened (each None when not asked for)."""

    power: SupplyPowerCycle | None = None
    table: MountedTable | None = None

    def close(self) -> None:
        """Stop the table and release both links (the supply's output stays as it is: the unit powered)."""
        if self.table is not None:
            try:
                self.table.stop()
            except DriverError:
                pass  # a table whose link failed: nothing more can be said to it
            self.table.table.close()
        if self.power is not None:
            self.power.close()


def open_instruments(config: TuiConfig) -> Instruments:
    """Open ``--supply`` (and switch the unit on through it) and ``--table``, each held to its limits.

    Raises
    ------
    StationError
        A URL that names no such instrument, an instrument that cannot be reached or refuses, a
        setting beyond the limits (:class:`~drivers.instruments.errors.LimitRefused`).
    """
    from drivers.instruments import Table
    from station.instruments.limits import Limits, limited
    from station.instruments.open import open_instrument

    opened = Instruments()
    try:
        if config.supply is not None:
            from station.instruments.power_cycle import open_power_cycle

            limits = Limits(max_v=config.supply_max_v, max_a=config.supply_max_a,
                            source="--supply-max-v / --supply-max-a")
            opened.power = open_power_cycle(config.supply, limits, config.supply_volts, config.supply_amps,
                                            config.supply_off_s)
            opened.power.power_on()  # the unit may be off: a supply starts with its output off
        if config.table is not None:
            from station.instruments.mounted_table import MountedTable

            limits = Limits(max_rate_dps=config.table_max_rate_dps, max_accel_dps2=config.table_accel_dps2,
                            source="--table-max-rate / --table-accel")
            table = limited(open_instrument(config.table, kind="table"), limits)
            assert isinstance(table, Table)  # open_instrument(kind="table") gives one
            opened.table = MountedTable(table, config.table_mount, config.table_accel_dps2)
    except BaseException:
        opened.close()
        raise
    return opened


def open_session(config: TuiConfig, port: str | None) -> Session:
    """Open the instruments (:func:`open_instruments`), then ``port``, or the simulated unit when ``port``
    is None or :data:`SIMULATED`, and ask who it is."""
    instruments = open_instruments(config)
    try:
        if port is None or port == SIMULATED:
            session = open_simulated(config)
        else:
            session = Session(open_paced(port, protocol=config.protocol), port)
    except BaseException:
        instruments.close()
        raise
    session.power, session.table = instruments.power, instruments.table
    session.closers.append(instruments.close)
    try:
        session.info = _ask_info(session, config, BOOT_S if instruments.power is not None else 0.0)
    except Exception:
        session.close()
        raise
    return session


def _ask_info(session: Session, config: TuiConfig, boot_s: float) -> dict[str, Any]:
    """Who the unit is; a unit its supply just switched on is asked again for ``boot_s`` seconds."""
    deadline = time.monotonic() + boot_s
    while True:
        try:
            return session.device.get_info() if config.protocol == "native" else dict(session.device.info)
        except DriverError:
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.5)  # the unit is booting: its first answer comes when it is up


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
