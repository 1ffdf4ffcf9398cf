"""A simulated bench around one simulated unit: a chamber, a rate table and a bench supply, each on a
loopback TCP port and each coupled to the unit, as the real ones are to a unit on the bench.

- The chamber is the simserv emulator (``votsch://``) over a
  :class:`~mocks.instruments.chamber_plant.ChamberPlant` whose clock is the unit's device clock, and
  the unit reads its temperature from that plant (:meth:`~mocks.device.SimDevice.follow_temperature`):
  a setpoint sent by the station's driver warms the unit, and a unit served at ``--speed X`` warms
  X times faster, as everything else of it runs.
- The rate table is the ACUTROL emulator (``acutrol://...?axes=3``), three axes: the outer vertical,
  the middle and the inner carrying the unit (``mount`` along it, up at rest), so the station's
  poses and turns about every axis are reachable; a turn of the table is a turn the unit's gyroscope
  sees. Mounting holds the unit still with the mount axis up, which replaces the motion of a moving
  scenario.
- The supply is the SCPI emulator (``scpi://``) with the unit on its channel 1. It starts with that
  output on at 5 V (0.5 A limit) and the unit running as it was (no boot), so the unit streams as
  without a bench; switching the output off silences the unit, on boots it anew (seq from 0).

``simulated_bench(device, clock)`` starts the ones asked for and yields a :class:`SimulatedBench`
(their URLs and the emulators, for tests); leaving the block stops them all.

``clock`` is the device clock of whoever serves the unit, ``PtyServer.device_time_s`` (server
seconds times the speed). It must not take the unit's lock: the plant holds its own lock while it
reads its clock, and the unit's sampler holds the unit's lock while it reads the plant, so a
clock that locked the unit (``SimDevice.next_due_s``) could deadlock the two threads.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from mocks.device import SimDevice
from mocks.instruments.acutrol import AcutrolEmulator
from mocks.instruments.chamber_plant import ChamberPlant
from mocks.instruments.scpi_supply import ScpiSupply, SupplyOutputs
from mocks.instruments.serving import ByteServer
from mocks.instruments.simserv import SimservChamber

KINDS = ("chamber", "table", "supply")
"""The instruments a simulated bench has, in the order they are started and printed."""
SCHEMES = {"chamber": "votsch", "table": "acutrol", "supply": "scpi"}
"""The URL scheme each simulated instrument is reached by."""
SUPPLY_V = 5.0  # the unit's supply at start: on, in its range
SUPPLY_A = 0.5  # above the unit's 0.12 A at 5 V: no current limiting
KEEP_S = 600.0  # device seconds of the plant's history kept behind the unit's samples


def parse_kinds(spec: str | Iterable[str]) -> tuple[str, ...]:
    """The instrument kinds of ``chamber,table,supply`` (a comma-separated text or a list), in bench
    order, each once.

    Parameters
    ----------
    spec : str or iterable of str
        Names among :data:`KINDS`; ``all`` for every one.

    Returns
    -------
    tuple of str

    Raises
    ------
    ValueError
        An unknown name, or none at all.
    """
    names = [n.strip() for n in (spec.split(",") if isinstance(spec, str) else spec) if n.strip()]
    if "all" in names:
        names = [n for n in names if n != "all"] + list(KINDS)
    unknown = [n for n in names if n not in KINDS]
    if unknown:
        raise ValueError(f"unknown instrument {unknown[0]!r}; known: {', '.join(KINDS)} (or all)")
    if not names:
        raise ValueError(f"name at least one instrument: {', '.join(KINDS)} (or all)")
    return tuple(k for k in KINDS if k in names)


class _Follower:
    """The unit's temperature from the plant, dropping the plant's history the unit has passed
    (a long, sped-up run keeps its memory and each evaluation's cost bounded)."""

    def __init__(self, plant: ChamberPlant):
        self.plant = plant

    def __call__(self, t: np.ndarray) -> np.ndarray:
        times = np.asarray(t, float)
        values = self.plant.unit_c(times)
        if times.size:
            self.plant.forget_before(float(np.min(times)) - KEEP_S)
        return values


@dataclass
class SimulatedBench:
    """The instruments of a running simulated bench.

    Attributes
    ----------
    urls : dict
        Kind -> the URL the station opens it by (``votsch://127.0.0.1:P`` ...), in :data:`KINDS` order.
    servers : dict
        Kind -> its :class:`ByteServer` (faults: ``silent``, ``garbage``, ``drop_link()``).
    plant, chamber : the chamber's air and unit, and its simserv protocol (None without a chamber).
    table : the ACUTROL emulator (None without a table).
    outputs, supply : the supply's channels, and its SCPI protocol (None without a supply).
    """

    urls: dict[str, str] = field(default_factory=dict)
    servers: dict[str, ByteServer] = field(default_factory=dict)
    plant: ChamberPlant | None = None
    chamber: SimservChamber | None = None
    table: AcutrolEmulator | None = None
    outputs: SupplyOutputs | None = None
    supply: ScpiSupply | None = None

    def describe(self) -> str:
        """One line of what the instruments heard (for a summary)."""
        parts = []
        if self.chamber is not None:
            parts.append(f"chamber {len(self.chamber.requests)} request(s)")
        if self.table is not None:
            parts.append(f"table {len(self.table.lines)} command(s)")
        if self.supply is not None:
            parts.append(f"supply {len(self.supply.commands)} command(s)")
        return ", ".join(parts) or "none"


def _serve(bench: SimulatedBench, kind: str, emulator: object) -> None:
    server = ByteServer(emulator, "tcp").start()  # type: ignore[arg-type]  # every emulator has feed()
    bench.servers[kind] = server
    bench.urls[kind] = f"{SCHEMES[kind]}://{server.address}"


@contextlib.contextmanager
def simulated_bench(device: SimDevice, clock: Callable[[], float], kinds: Iterable[str] = KINDS, *,
                    mount: str = "+z", plant: ChamberPlant | None = None) -> Iterator[SimulatedBench]:
    """Serve the instruments ``kinds`` on loopback TCP, coupled to ``device``, for the block.

    Parameters
    ----------
    device : SimDevice
        The unit on the bench (already served, or about to be: its server's clock is ``clock``).
    clock : callable
        The unit's device time now, s, without taking the unit's lock (``PtyServer.device_time_s``;
        see the module docstring).
    kinds : iterable of str
        Which of ``chamber``, ``table``, ``supply`` (default all three).
    mount : str
        The unit's signed axis along the table's axis 1.
    plant : ChamberPlant, optional
        The chamber's plant (default: one at 23 degC on ``clock``); it must run on ``clock``.

    Yields
    ------
    SimulatedBench
        The URLs and the emulators. Leaving the block stops every server (and raises what a
        serving thread failed with, once all are stopped).
    """
    wanted = parse_kinds(kinds)
    bench = SimulatedBench()
    try:
        if "chamber" in wanted:
            bench.plant = plant if plant is not None else ChamberPlant(clock)
            device.follow_temperature(_Follower(bench.plant))
            bench.chamber = SimservChamber(bench.plant)
            _serve(bench, "chamber", bench.chamber)
        if "table" in wanted:
            # Three axes: the station's poses and turns about every axis (a single axis turns the mount's).
            bench.table = AcutrolEmulator(axes=3, device=device, mount=mount)
            _serve(bench, "table", bench.table)
            bench.urls["table"] += "?axes=3"
        if "supply" in wanted:
            # The output is switched on before the unit is wired to it: the unit, already running,
            # is not booted again (its scenario, turn-on and seq go on as without a bench).
            bench.outputs = SupplyOutputs(None)
            bench.outputs.set(bench.outputs.unit_channel, volts=SUPPLY_V, amps=SUPPLY_A, on=True)
            bench.outputs.device = device
            bench.outputs.set(bench.outputs.unit_channel)  # powers a unit that was off
            bench.supply = ScpiSupply(bench.outputs)
            _serve(bench, "supply", bench.supply)
        yield bench
    finally:
        failure: BaseException | None = None
        for server in bench.servers.values():
            try:
                server.stop()
            except RuntimeError as exc:
                failure = failure or exc
        if failure is not None:
            raise failure
