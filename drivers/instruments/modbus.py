"""Modbus instruments spoken from a description (Watlow F4 over RTU, Binder MB1 over TCP), through
pymodbus: its framing, CRC and transaction handling, none written here.

An operation is a holding register (two for 32-bit types, in the description's word order), read
and scaled (``value * scale``) or, for a ``write: true`` register, written as ``value / scale``
rounded to the register's type (or as the register's fixed ``value``: a start or stop code).
Reads are retried by pymodbus (``link.retries``); a write is sent once. Every exchange goes to the
transcript as ``read 100`` / ``write 300 = 350`` with the registers' raw values.
"""

from __future__ import annotations

import time
from typing import Any

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from drivers.instruments.description import InstrumentDescription, Register
from drivers.instruments.errors import InstrumentError, InstrumentLost, InstrumentRefused, InstrumentTimeout
from drivers.instruments.link import split_host
from drivers.instruments.speaker import Reply, Speaker
from drivers.instruments.transcript import Transcript

_TYPES = {"int16": "INT16", "uint16": "UINT16", "int32": "INT32", "uint32": "UINT32", "float32": "FLOAT32"}
_RANGES = {"int16": (-32768, 32767), "uint16": (0, 65535), "int32": (-2**31, 2**31 - 1),
           "uint32": (0, 2**32 - 1)}


def open_client(target: str, description: InstrumentDescription, url: str) -> Any:
    """A connected pymodbus client for ``target`` (``HOST[:PORT]`` for modbus-tcp, a port for RTU)."""
    link = description.link
    if link.transport == "modbus-tcp":
        host, port = split_host(target, link.tcp_port or 502, url)
        client: Any = ModbusTcpClient(host, port=port, timeout=link.timeout_s, retries=link.retries)
    else:
        client = ModbusSerialClient(target, baudrate=link.baud, timeout=link.timeout_s, retries=link.retries)
    if not client.connect():
        client.close()
        raise InstrumentLost(f"{url}: cannot open the Modbus link to {target}; check the address or port, "
                             "the baud rate and that the controller's Modbus interface is enabled", url)
    return client


class ModbusSpeaker(Speaker):
    """A description's registers on a pymodbus client."""

    def __init__(self, url: str, description: InstrumentDescription, client: Any,
                 transcript: Transcript | None = None):
        super().__init__(url, description, transcript)
        self.client = client

    def _datatype(self, register: Register) -> Any:
        return getattr(self.client.DATATYPE, _TYPES[register.type])

    def do(self, operation: str, value: float | None = None, axis: int = 1, channel: int = 1) -> Reply:
        """Read (or write) ``operation``'s register; ``{"value": ...}`` for a read."""
        register = self.description.registers.get(operation)
        if register is None:
            raise InstrumentError(f"{self.url}: the {self.description.name} description has no '{operation}' "
                                  "register; add it to the description (?description=FILE.yaml)", self.url,
                                  operation)
        if register.write:
            self._write(operation, register, register.value if register.value is not None else value)
            return {}
        return {"value": repr(self._read(operation, register))}

    def _call(self, text: str, call: Any) -> Any:
        started = time.time()
        try:
            response = call()
        except ModbusException as exc:
            self.transcript.add(self.url, text, "", started, "InstrumentTimeout")
            lost = "connection" in str(exc).lower() and "timeout" not in str(exc).lower()
            kind = InstrumentLost if lost else InstrumentTimeout
            raise kind(f"{self.url}: {self.description.name}: {text}: {exc}; check the link, the unit id "
                       f"({self.description.link.unit}) and the baud rate", self.url, text) from None
        if response.isError():
            self.transcript.add(self.url, text, str(response), started, "InstrumentRefused")
            raise InstrumentRefused(f"{self.url}: {self.description.name} refused {text}: {response}; check "
                                    "the register numbers in the description", self.url, text, str(response))
        return response, started

    def _read(self, operation: str, register: Register) -> float:
        text = f"read {operation} {register.address}"
        response, started = self._call(text, lambda: self.client.read_holding_registers(
            register.address, count=register.words, device_id=self.description.link.unit))
        raw = self.client.convert_from_registers(response.registers, self._datatype(register),
                                                 word_order=self.description.word_order)
        self.transcript.add(self.url, text, " ".join(map(str, response.registers)), started)
        return float(raw) * register.scale

    def _write(self, operation: str, register: Register, value: float | None) -> None:
        if value is None:
            raise InstrumentError(f"{self.url}: '{operation}' needs a value", self.url, operation)
        scaled = value / register.scale
        if register.type != "float32":
            low, high = _RANGES[register.type]
            scaled = round(scaled)
            if not low <= scaled <= high:
                raise InstrumentError(f"{self.url}: {operation} {value:g} is {scaled} in the register, "
                                      f"outside its {register.type} range {low}..{high}", self.url, operation)
        words = self.client.convert_to_registers(scaled, self._datatype(register),
                                                 word_order=self.description.word_order)
        text = f"write {operation} {register.address} = {' '.join(map(str, words))}"
        _, started = self._call(text, lambda: self.client.write_registers(
            register.address, words, device_id=self.description.link.unit))
        self.transcript.add(self.url, text, "ok", started)

    def close(self) -> None:
        """Close the client."""
        self.client.close()
