"""Lab instruments (issue 26): commands per second each driver sustains against its emulator, and the
time from a stop (as Ctrl-C or an abort sends it) to a table at rest.

Each driver reads its instrument's main value in a loop (a chamber's temperature, a table's
position, a supply's measured voltage) over a real TCP socket or pty to the emulator of its
protocol, for ``--seconds`` each, ``--repeats`` times; the median is printed. The emulators answer
at once, so these are the station's own costs (link, description, retries, transcript), not real
instruments': a real ACUTROL takes about 2 ms a command over Ethernet (500/s), a Korad needs 50 ms
between commands and ends a reply by silence.

The stop time: the ACUTROL emulator's table turning at 90 deg/s with a 500 deg/s^2 limit, stopped
through the station's driver; the time until the emulator reports rate 0, median of the repeats
(the deceleration alone is 180 ms).

    .venv/bin/python benchmarks/instruments.py [--seconds 1] [--repeats 3]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from collections.abc import Callable, Iterator
from typing import Any

from drivers.instruments import Chamber, Instrument, Supply, Table
from mocks.instruments.acutrol import AcutrolEmulator
from mocks.instruments.aerosmith import AerosmithEmulator
from mocks.instruments.chamber_plant import ChamberPlant
from mocks.instruments.espec import EspecChamber
from mocks.instruments.korad import KoradSupply
from mocks.instruments.modbus_chambers import binder_mb1, watlow_f4
from mocks.instruments.scpi_supply import ScpiSupply, SupplyOutputs
from mocks.instruments.serving import ByteServer
from mocks.instruments.simserv import SimservChamber
from station.instruments.open import open_instrument


@contextlib.contextmanager
def _served(name: str) -> Iterator[tuple[str, Any]]:
    """(URL, emulator) of the driver ``name``, served for the block."""
    plant = ChamberPlant()
    makers: dict[str, Callable[[], tuple[str, Any, Any]]] = {
        "votsch (TCP)": lambda: ("votsch", ByteServer(SimservChamber(plant), "tcp"), None),
        "espec (pty)": lambda: ("espec", ByteServer(EspecChamber(plant), "pty"), None),
        "watlow-f4 (Modbus RTU, pty)": lambda: ("watlow-f4", watlow_f4(plant), None),
        "binder (Modbus TCP)": lambda: ("binder", binder_mb1(plant), None),
        "acutrol (TCP)": lambda: ("acutrol", *_table(AcutrolEmulator(), "tcp")),
        "acutrol (pty)": lambda: ("acutrol", *_table(AcutrolEmulator(), "pty")),
        "aerosmith (pty)": lambda: ("aerosmith", *_table(AerosmithEmulator(), "pty")),
        "scpi (TCP)": lambda: ("scpi", ByteServer(ScpiSupply(SupplyOutputs()), "tcp"), None),
        "scpi (pty)": lambda: ("scpi", ByteServer(ScpiSupply(SupplyOutputs()), "pty"), None),
        "korad (pty)": lambda: ("korad", ByteServer(KoradSupply(SupplyOutputs()), "pty"), None),
    }
    scheme, server, emulator = makers[name]()
    with server:
        yield f"{scheme}://{server.address}", emulator


def _table(emulator: Any, transport: str) -> tuple[ByteServer, Any]:
    return ByteServer(emulator, transport), emulator


def _read(instrument: Instrument) -> Callable[[], float]:
    if isinstance(instrument, Chamber):
        return instrument.temperature_c
    if isinstance(instrument, Table):
        return instrument.position_deg
    assert isinstance(instrument, Supply)
    return instrument.voltage_v


def commands_per_second(name: str, seconds: float) -> float:
    """Reads of the driver's main value per second against its emulator."""
    with _served(name) as (url, _):
        instrument = open_instrument(url)
        try:
            read = _read(instrument)
            read()
            count, start = 0, time.perf_counter()
            while time.perf_counter() - start < seconds:
                read()
                count += 1
            return count / (time.perf_counter() - start)
        finally:
            instrument.close()


def stop_time(transport: str) -> float:
    """Seconds from the station's stop to the ACUTROL emulator's rate 0 (from 90 deg/s)."""
    with _served(f"acutrol ({transport.upper() if transport == 'tcp' else transport})") as (url, emulator):
        table = open_instrument(url)
        assert isinstance(table, Table)
        try:
            table.set_acceleration(500.0)
            table.turn(90.0)
            deadline = time.monotonic() + 10.0
            while abs(emulator.axes[0].state()[1]) < 90.0 - 1e-6 and time.monotonic() < deadline:
                time.sleep(0.002)
            start = time.perf_counter()
            table.stop()
            while abs(emulator.axes[0].state()[1]) > 1e-9 and time.monotonic() < deadline + 10.0:
                time.sleep(0.0005)
            return time.perf_counter() - start
        finally:
            table.close()


def main() -> None:
    """Print the figures, medians of the repeats."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=1.0, help="seconds of reads per driver and repeat")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"commands per second against each emulator (median of {args.repeats} x {args.seconds:g} s):")
    names = ["votsch (TCP)", "espec (pty)", "watlow-f4 (Modbus RTU, pty)", "binder (Modbus TCP)",
             "acutrol (TCP)", "acutrol (pty)", "aerosmith (pty)", "scpi (TCP)", "scpi (pty)", "korad (pty)"]
    for name in names:
        runs = [commands_per_second(name, args.seconds) for _ in range(args.repeats)]
        print(f"  {name:30s} {statistics.median(runs):9.0f}/s   ({' '.join(f'{r:.0f}' for r in runs)})")
    for transport in ("tcp", "pty"):
        runs = [stop_time(transport) for _ in range(args.repeats)]
        print(f"stop to rest, acutrol ({transport}), 90 deg/s at 500 deg/s^2: "
              f"{statistics.median(runs) * 1e3:.0f} ms (deceleration alone 180 ms; runs "
              f"{' '.join(f'{r * 1e3:.0f}' for r in runs)})")


if __name__ == "__main__":
    main()
