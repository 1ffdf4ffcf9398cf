"""Modbus chamber controllers served by pymodbus's own servers: a Watlow F4 over Modbus RTU on a raw
pty, and a Binder MB1 over Modbus TCP on loopback.

``shared/specs/instruments.md``, "Chambers". The register maps are the spec's, written here and
not read from the shipped descriptions (``station/instruments/descriptions/``), so a test of the
driver against this emulator checks the descriptions too:

- Watlow F4: holding registers, signed 16-bit, value x 10: 100 = process value (degC), 300 =
  setpoint 1 (read and write), 103 / 107 = heat / cool power (%). Unit 1.
- Binder MB1: 32-bit floats in two registers, low word first by default (``word_order``):
  0x11A9 = actual temperature, 0x1077 = setpoint in use, 0x1581 = manual setpoint (write), 0x1A22 =
  mode (16-bit, not interpreted).

Every value read is the :class:`~mocks.instruments.chamber_plant.ChamberPlant`'s at that moment (a
pymodbus device ``action`` fills the registers before they are answered); a write to the setpoint
register changes the plant. A controller with a setpoint always controls, so the plant runs.

Between the driver and pymodbus's server sits a byte relay (a second pty, or a loopback TCP
proxy) that injects the faults every emulator offers (``silent``, ``garbage``, ``drop_link()``,
as :class:`mocks.instruments.serving.ByteServer`), which a library's server cannot.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import select
import socket
import struct
import threading
from collections.abc import Callable
from typing import Any, Self

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from mocks.instruments.chamber_plant import ChamberPlant
from mocks.raw_pty import open_serving_pty

WRITE_CODES = (6, 16)  # write single register, write multiple registers


class _Value:
    """One value of the controller: where it lives, how it is coded, where it comes from."""

    def __init__(self, address: int, kind: str, read: Callable[[], float],
                 write: Callable[[float], bool] | None = None, scale: float = 1.0):
        self.address = address
        self.kind = kind  # int16 | uint16 | float32
        self.read = read
        self.write = write  # returns False when the controller refuses the value
        self.scale = scale

    @property
    def words(self) -> int:
        return 2 if self.kind == "float32" else 1

    def encode(self, word_order: str) -> list[int]:
        value = self.read() / self.scale
        if self.kind == "float32":
            high, low = struct.unpack(">HH", struct.pack(">f", value))
            return [high, low] if word_order == "big" else [low, high]
        raw = max(-32768, min(32767, round(value)))
        return [raw & 0xFFFF]

    def decode(self, words: list[int], word_order: str) -> float:
        if self.kind == "float32":
            high, low = (words[0], words[1]) if word_order == "big" else (words[1], words[0])
            return float(struct.unpack(">f", struct.pack(">HH", high, low))[0]) * self.scale
        raw = words[0] - 0x10000 if self.kind == "int16" and words[0] >= 0x8000 else words[0]
        return raw * self.scale


class ModbusChamber:
    """A Modbus chamber controller on pymodbus's server behind a fault-injecting relay.

    Parameters
    ----------
    plant : ChamberPlant
        The chamber it reports and commands.
    values : list of _Value
        Its register map (use :func:`watlow_f4` or :func:`binder_mb1`).
    transport : str
        ``rtu`` (a raw pty; ``address`` is its path) or ``tcp`` (``address`` is ``127.0.0.1:PORT``).
    unit : int
        Its Modbus unit id.
    word_order : str
        ``big`` (high word first) or ``little``, for 32-bit values.

    Attributes
    ----------
    address : str
        Where the driver connects.
    silent, garbage : bool
        Faults: answer nothing, or scramble every answer.
    received : int
        Bytes the driver sent so far.
    """

    def __init__(self, plant: ChamberPlant, values: list[_Value], transport: str, unit: int = 1,
                 word_order: str = "big"):
        if transport not in ("rtu", "tcp"):
            raise ValueError(f"transport is rtu or tcp, not {transport!r}")
        self.plant = plant
        self.values = values
        self.transport = transport
        self.unit = unit
        self.word_order = word_order
        self.address = ""
        self.silent = False
        self.garbage = False
        self.received = 0
        self.writes: list[tuple[int, list[int]]] = []
        self.error: BaseException | None = None
        self._random = random.Random(0)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._backend_master = -1  # rtu: the server's pty
        self._front_master = -1  # rtu: the driver's pty
        self._backend_port = 0  # tcp: the server's port
        self._listener: socket.socket | None = None
        self._pairs: list[tuple[socket.socket, socket.socket]] = []
        plant.set_running(True)

    # --- pymodbus's side -----------------------------------------------------------------------

    async def _action(self, function_code: int, start_address: int, address: int, count: int,
                      registers: list[int], set_values: list[int] | list[bool] | None) -> ExcCodes | None:
        if set_values is not None and function_code in WRITE_CODES:
            words = [int(v) for v in set_values]
            self.writes.append((address, words))
            for value in self.values:
                if value.address == address and value.write is not None and len(words) == value.words:
                    if not value.write(value.decode(words, self.word_order)):
                        return ExcCodes.ILLEGAL_VALUE
                    return None
            return ExcCodes.ILLEGAL_ADDRESS
        for value in self.values:
            if value.address < address + count and address < value.address + value.words:
                at = value.address - start_address
                registers[at:at + value.words] = value.encode(self.word_order)
        return None

    def _device(self) -> SimDevice:
        data = [SimData(v.address, values=[0] * v.words, datatype=DataType.REGISTERS) for v in self.values]
        return SimDevice(id=self.unit, simdata=data, action=self._action)

    def _serve(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
        except BaseException as exc:  # noqa: BLE001 - kept for stop() to raise in the test's thread
            self.error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _main(self) -> None:
        if self.transport == "tcp":
            self._server = ModbusTcpServer(self._device(), address=("127.0.0.1", 0))
        else:
            self._server = ModbusSerialServer(self._device(), port=self._backend_path, baudrate=19200,
                                              reconnect_delay=0.1)
        await self._server.serve_forever(background=True)
        if self.transport == "tcp":
            self._backend_port = self._server.transport.sockets[0].getsockname()[1]
        self._ready.set()
        await self._server.serving

    # --- the relay (faults) ----------------------------------------------------------------------

    def start(self) -> Self:
        """Start pymodbus's server and the relay in front of it; returns self."""
        if self.transport == "rtu":
            self._backend_master, self._backend_path = open_serving_pty()
            self._front_master, self.address = open_serving_pty()
        self._threads = [threading.Thread(target=self._serve, name="modbus-chamber", daemon=True)]
        self._threads[0].start()
        if not self._ready.wait(10.0) or self.error is not None:
            raise RuntimeError("the Modbus chamber's server did not start") from self.error
        if self.transport == "tcp":
            self._listener = socket.create_server(("127.0.0.1", 0))
            self.address = f"127.0.0.1:{self._listener.getsockname()[1]}"
        relay = threading.Thread(target=self._relay, name="modbus-chamber-relay", daemon=True)
        relay.start()
        self._threads.append(relay)
        return self

    def _reply(self, data: bytes) -> bytes:
        if self.silent:
            return b""
        if self.garbage:
            return bytes(self._random.randrange(256) for _ in data)
        return data

    def _relay(self) -> None:
        try:
            while not self._stop.is_set():
                if self.transport == "rtu":
                    self._relay_pty()
                else:
                    self._relay_tcp()
        except BaseException as exc:  # noqa: BLE001
            self.error = exc

    def _relay_pty(self) -> None:
        front, back = self._front_master, self._backend_master
        if front < 0:
            self._stop.wait(0.02)
            return
        ready, _, _ = select.select([front, back], [], [], 0.05)
        for fd in ready:
            try:
                data = os.read(fd, 4096)
            except BlockingIOError:
                continue
            except OSError:  # EIO: nobody has that end open now
                self._stop.wait(0.02)
                continue
            if fd == front:
                self.received += len(data)
                with contextlib.suppress(OSError):
                    os.write(back, data)
            else:
                reply = self._reply(data)
                if reply:
                    with contextlib.suppress(OSError):
                        os.write(front, reply)

    def _relay_tcp(self) -> None:
        listener = self._listener
        if listener is None:
            self._stop.wait(0.02)
            return
        socks = [listener] + [s for pair in self._pairs for s in pair]
        ready, _, _ = select.select(socks, [], [], 0.05)
        for sock in ready:
            if sock is listener:
                conn, _ = listener.accept()
                backend = socket.create_connection(("127.0.0.1", self._backend_port), timeout=5)
                self._pairs.append((conn, backend))
                continue
            pair = next(p for p in self._pairs if sock in p)
            try:
                data = sock.recv(4096)
            except OSError:
                data = b""
            if not data:
                self._pairs.remove(pair)
                for s in pair:
                    s.close()
                continue
            if sock is pair[0]:
                self.received += len(data)
                pair[1].sendall(data)
            else:
                reply = self._reply(data)
                if reply:
                    with contextlib.suppress(OSError):
                        pair[0].sendall(reply)

    def drop_link(self) -> None:
        """A link lost mid-run: close the driver's pty or connections, and stop serving."""
        self._stop.set()
        for thread in self._threads[1:]:
            thread.join(timeout=5)
        if self._front_master >= 0:
            with contextlib.suppress(OSError):
                os.close(self._front_master)
            self._front_master = -1
        for pair in self._pairs:
            for s in pair:
                with contextlib.suppress(OSError):
                    s.close()
        self._pairs.clear()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
            self._listener = None

    def stop(self) -> None:
        """Stop the relay and pymodbus's server; raises what a serving thread failed with."""
        self.drop_link()
        loop, server = self._loop, self._server
        if loop is not None and server is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError, TimeoutError):
                asyncio.run_coroutine_threadsafe(server.shutdown(), loop).result(timeout=5)
        self._threads[0].join(timeout=5)
        if self._backend_master >= 0:
            with contextlib.suppress(OSError):
                os.close(self._backend_master)
            self._backend_master = -1
        if self.error is not None:
            raise RuntimeError("the Modbus chamber emulator failed") from self.error

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _setter(plant: ChamberPlant) -> Callable[[float], bool]:
    def write(celsius: float) -> bool:
        if not plant.min_c <= celsius <= plant.max_c:
            return False
        plant.set_setpoint(celsius)
        return True
    return write


def watlow_f4(plant: ChamberPlant, unit: int = 1) -> ModbusChamber:
    """A Watlow F4 controller over Modbus RTU on a raw pty (not started).

    Parameters
    ----------
    plant : ChamberPlant
    unit : int
        Its Modbus address.

    Returns
    -------
    ModbusChamber
    """
    def power(sign: float) -> Callable[[], float]:
        # Heat (cool) power in %, as a proportional band of 5 K would give it.
        return lambda: max(0.0, min(100.0, sign * (plant.setpoint_c - plant.now_air_c()) * 20.0))
    values = [_Value(100, "int16", plant.now_air_c, scale=0.1),
              _Value(103, "int16", power(1.0), scale=0.1),
              _Value(107, "int16", power(-1.0), scale=0.1),
              _Value(300, "int16", lambda: plant.setpoint_c, _setter(plant), scale=0.1)]
    return ModbusChamber(plant, values, "rtu", unit)


def binder_mb1(plant: ChamberPlant, unit: int = 1, word_order: str = "little") -> ModbusChamber:
    """A Binder MB1 controller over Modbus TCP on loopback (not started).

    Parameters
    ----------
    plant : ChamberPlant
    unit : int
        Its Modbus unit id.
    word_order : str
        Of its 32-bit floats: ``little`` (low word first, as SiLab-Bonn/basil reads it) or ``big``.

    Returns
    -------
    ModbusChamber
    """
    values = [_Value(0x1077, "float32", lambda: plant.setpoint_c),
              _Value(0x11A9, "float32", plant.now_air_c),
              _Value(0x1581, "float32", lambda: plant.setpoint_c, _setter(plant)),
              _Value(0x1A22, "uint16", lambda: 1.0 if plant.running else 0.0)]
    return ModbusChamber(plant, values, "tcp", unit, word_order)
