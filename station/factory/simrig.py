"""``--simulate``: a simulated unit and a simulated turntable, each on its own pseudo-terminal, and
the simulated lab instruments a plan names.

The unit (``mocks.device.SimDevice`` served by ``mocks.pty_server.PtyServer``) is mounted on the
table (``mocks.turntable_sim.TurntableSim``): the station opens both ports like real ones, so a
simulated run goes through the same drivers, runner and records as a run on the line. With a
frame description as the plan's protocol, the unit streams that description's frames instead of
native ones (``mocks.frame_unit``). The instruments (``mocks.instruments.bench``: a simserv chamber,
an ACUTROL table, a SCPI supply, coupled to the unit, on loopback TCP) are reached by their URLs,
and by ``sim://KIND`` in this process while the block runs.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from station.errors import StationError

if TYPE_CHECKING:
    from mocks.pty_server import PtyServer


@dataclass(frozen=True)
class SimulatedUnit:
    """What to simulate: the unit's intrinsics come from ``UnitTruth.random(seed, grade)``.

    ``unplug_after_s``: the unit's link ends after this many seconds (a cable pulled mid-run).
    ``table_turn_error``: the simulated table turns (1 + this) times the asked angle (a wrong gear).
    ``speed``: the unit's clock (and so the table's motion) runs this many times faster than the
    wall clock (rehearsals and tests; the plan's times stay in device seconds, its timeouts in
    wall seconds); a campaign changes it while it runs (``SimulatedPorts.pace``).
    ``initial_c``: the simulated chamber's air and the unit start at this temperature (a resumed
    campaign: where the journal left the unit), else at the room's.
    ``thermal_intrinsics``: the unit's scale factor and misalignment move with temperature too
    (``UnitTruth.random(thermal_intrinsics=True)``; a chamber campaign's unit).
    """

    seed: int = 0
    grade: str = "mems"
    unplug_after_s: float | None = None
    table_turn_error: float = 0.0
    speed: float = 1.0
    initial_c: float | None = None
    thermal_intrinsics: bool = False


@dataclass(frozen=True)
class SimulatedPorts:
    """The two ports, the simulated unit itself (a simulated hand for a manual fixture), and the
    simulated instruments' URLs by kind (``chamber``: ``votsch://127.0.0.1:P``, ``table``:
    ``acutrol://...``, ``supply``: ``scpi://...``; empty when none was asked for)."""

    port: str
    table_port: str
    rig: Any
    instruments: dict[str, str] = field(default_factory=dict)
    pace: Callable[[float], None] | None = None
    """Sets the unit's clock to run this many times the wall clock from now on (continuous)."""


@contextlib.contextmanager
def simulated_rig(unit: SimulatedUnit, serial: str, rate_hz: float, protocol: str = "native",
                  instruments: Iterable[str] = ()) -> Iterator[SimulatedPorts]:
    """Serve the unit (reporting ``serial``) and its table on ptys, and the instruments asked for on
    loopback TCP, for the duration of the block.

    Parameters
    ----------
    unit : SimulatedUnit
        What to simulate.
    serial : str
        The serial number the unit reports.
    rate_hz : float
        Its sample rate.
    protocol : str
        ``native``, or ``frame:FILE`` (a plan's protocol): the unit streams that description's frames.
    instruments : iterable of str
        The instrument kinds to simulate (``chamber``, ``table``, ``supply``; a plan's
        ``instruments:`` keys), coupled to the unit and on its device clock (``speed``). Each is
        registered as ``sim://KIND`` (``station.instruments.open.register_simulated``) for the
        block, and unregistered after.

    Yields
    ------
    SimulatedPorts
        The unit's and the table's ports, and the instruments' URLs.

    Raises
    ------
    StationError
        An instrument kind the simulation does not have.
    """
    from mocks.device import SimDevice
    from mocks.faults import FaultSpec
    from mocks.instruments.warp import WarpPtyServer
    from mocks.truth import UnitTruth
    from mocks.turntable_sim import TurntableSim

    kinds = _kinds(instruments)
    truth = dataclasses.replace(UnitTruth.random(unit.seed, unit.grade, unit.thermal_intrinsics),
                                serial=serial)
    faults = FaultSpec(disconnect_after_s=unit.unplug_after_s) if unit.unplug_after_s is not None else None
    # 50 ms blocks (the server default is 20 ms): each block is one batch the runner checks, and the
    # station runs several simulated units at once.
    device = SimDevice(truth, seed=unit.seed, rate_hz=rate_hz, scenario="still")
    if protocol != "native":
        from mocks.frame_unit import speak_frames
        from station.frames.reader import load_description

        speak_frames(device, load_description(protocol.partition(":")[2]))
    server = WarpPtyServer(device, faults=faults, block_s=0.05, speed=unit.speed)
    with server, TurntableSim(server.device, turn_error=unit.table_turn_error) as table, \
            _instruments(server, kinds, unit.initial_c) as urls:
        yield SimulatedPorts(server.port_path, table.port_path, server.device, urls, server.set_speed)


def _kinds(instruments: Iterable[str]) -> tuple[str, ...]:
    from mocks.instruments.bench import parse_kinds

    names = [str(k) for k in instruments]
    if not names:
        return ()
    try:
        return parse_kinds(names)
    except ValueError as exc:
        raise StationError(f"--simulate: {exc}") from None


@contextlib.contextmanager
def _instruments(server: PtyServer, kinds: tuple[str, ...], initial_c: float | None = None
                 ) -> Iterator[dict[str, str]]:
    """The simulated bench of ``kinds`` around the served unit, registered as ``sim://KIND``; the
    chamber's air and unit start at ``initial_c`` when given."""
    if not kinds:
        yield {}
        return
    from mocks.instruments.bench import simulated_bench
    from mocks.instruments.chamber_plant import ChamberPlant
    from station.instruments.open import register_simulated

    plant = None if initial_c is None else ChamberPlant(server.device_time_s, initial_c=initial_c)
    with simulated_bench(server.device, server.device_time_s, kinds, plant=plant) as bench:
        try:
            for kind, url in bench.urls.items():
                register_simulated(kind, url)
            yield dict(bench.urls)
        finally:
            for kind in bench.urls:
                register_simulated(kind, None)
