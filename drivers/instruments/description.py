"""Instrument descriptions (schema ``imu-station/instrument/1``): a protocol as data.

A chamber's, a rate table's or a supply's command set is a mapping the station checks here and a
generic driver speaks (``drivers.instruments.ascii``, ``drivers.instruments.modbus``): command
strings and reply patterns for a line protocol, registers, types, scales and word order for
Modbus. The shipped protocols are such files (``station/instruments/descriptions/``); a user whose
controller differs copies one and edits it (``votsch://HOST?description=mine.yaml``).

This module checks a plain mapping, as a YAML file gives it; reading the file (bounded, with lines
for every refusal) is the station's (``station.instruments.reader``). A refusal is a
:class:`DescriptionError` that names the key path (``commands.set_setpoint.send``), which the
reader turns into ``FILE:LINE: key: what is wrong``.

The document::

    schema: imu-station/instrument/1
    name: votsch-simserv             # shown in messages and the run record
    kind: chamber                    # chamber | table | supply
    protocol: ascii                  # ascii | modbus
    link:
      transport: tcp                 # tcp | serial | auto (tcp for HOST[:PORT], else serial) |
                                     # modbus-rtu | modbus-tcp
      tcp_port: 2049                 # default port of HOST
      baud: 9600                     # serial
      write_end: "\\r"               # appended to every command
      read_end: "\\r\\n"             # ends a reply; "" = a reply ends when the line is quiet
      quiet_s: 0.05                  # with read_end "": silence that ends a reply
      delay_s: 0.0                   # at least this long between two commands (slow controllers)
      timeout_s: 1.0                 # a reply must come within this
      retries: 2                     # further tries of an idempotent command
      unit: 1                        # Modbus unit (slave) id
    error_reply: "^NA:(?P<reason>.*)$"   # ascii: a reply matching this is a refusal
    word_order: big                  # modbus: big = high word first (32-bit values)
    axes: 1                          # tables: how many axes
    commands:                        # ascii: operation -> command
      temperature: {send: "11004\\xb61\\xb61", reply: "^1\\xb6(?P<value>\\\\S+)$"}
      set_setpoint: {send: "11001\\xb61\\xb61\\xb6{value:.1f}", reply: "^1$", idempotent: true}
    registers:                       # modbus: operation -> register
      temperature: {address: 100, type: int16, scale: 0.1}
      set_setpoint: {address: 300, type: int16, scale: 0.1, write: true}

A command's ``send`` is one string or a list sent in order (each with its own reply, where
``reply`` is a list of as many patterns, or one for all); ``reply: null`` expects none. Its
fields are ``{value}``, ``{axis}`` and ``{channel}``, with a format spec (``{value:.2f}``) and
nothing else (no attribute or index access). A reply pattern's group ``value`` is read as a
number, ``identity`` as text, ``state`` as on/off. Text is encoded as Latin-1, so ``\\xb6`` in
a YAML double-quoted string is the byte 0xB6.
"""

from __future__ import annotations

import re
import string
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from protocols.errors import StationError

SCHEMA = "imu-station/instrument/1"
KINDS = ("chamber", "table", "supply")
PROTOCOLS = ("ascii", "modbus")
TRANSPORTS = ("tcp", "serial", "auto", "modbus-rtu", "modbus-tcp")
REGISTER_TYPES = {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2}
FIELDS = ("value", "axis", "channel")

OPERATIONS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # kind: (required operations, optional operations)
    "chamber": (("temperature", "setpoint", "set_setpoint"),
                ("identify", "gradient", "set_gradient", "start", "stop", "running", "alarms", "reset")),
    "table": (("position", "move", "stop"),
              ("identify", "rate", "turn", "set_acceleration", "home", "settled", "servo_on", "servo_off")),
    "supply": (("set_voltage", "set_current", "output_on", "output_off", "voltage", "current"),
               ("identify", "output", "voltage_setpoint", "current_setpoint", "select_channel", "reset")),
}
"""Per kind, the operations a description must give and those it may give."""

MAX_SEND_CHARS = 256
MAX_COMMANDS = 64


class DescriptionError(StationError, ValueError):
    """A description the station cannot use; ``path`` is the key path of the offending value.

    Parameters
    ----------
    path : tuple
        Keys (and list indices) from the document's root to the value.
    message : str
        What is wrong and what it should be.
    """

    def __init__(self, path: tuple[str | int, ...], message: str):
        super().__init__(f"{'.'.join(map(str, path)) or '(document)'}: {message}")
        self.path = path
        self.message = message


@dataclass(frozen=True)
class LinkSettings:
    """How the instrument is reached and how its replies end."""

    transport: str = "serial"
    tcp_port: int | None = None
    baud: int = 9600
    write_end: str = "\n"
    read_end: str = "\n"
    quiet_s: float = 0.05
    delay_s: float = 0.0
    timeout_s: float = 1.0
    retries: int = 2
    unit: int = 1


@dataclass(frozen=True)
class Command:
    """One operation of a line protocol: what to send, what to expect back."""

    send: tuple[str, ...]
    reply: tuple[re.Pattern[str] | None, ...]
    idempotent: bool


@dataclass(frozen=True)
class Register:
    """One operation of a Modbus instrument: a holding register (or two, for 32-bit types)."""

    address: int
    type: str
    scale: float = 1.0
    write: bool = False
    value: float | None = None  # written as is (a start or stop register), instead of a value given

    @property
    def words(self) -> int:
        """Registers the value takes."""
        return REGISTER_TYPES[self.type]


@dataclass(frozen=True)
class InstrumentDescription:
    """A checked description: everything a generic driver needs to speak the instrument."""

    name: str
    kind: str
    protocol: str
    link: LinkSettings
    commands: Mapping[str, Command] = field(default_factory=dict)
    registers: Mapping[str, Register] = field(default_factory=dict)
    error_reply: re.Pattern[str] | None = None
    word_order: str = "big"
    axes: int = 1
    notes: str = ""

    def has(self, operation: str) -> bool:
        """True when the description gives ``operation``."""
        return operation in self.commands or operation in self.registers


def _expect(ok: bool, path: tuple[str | int, ...], message: str) -> None:
    if not ok:
        raise DescriptionError(path, message)


def _text(doc: Mapping[str, Any], key: str, path: tuple[str | int, ...], default: str | None = None,
          max_chars: int = MAX_SEND_CHARS) -> str:
    value = doc.get(key, default)
    _expect(isinstance(value, str), path + (key,), f"must be text, not {type(value).__name__}")
    _expect(len(value) <= max_chars, path + (key,), f"longer than {max_chars} characters")
    _expect(all(ord(ch) < 256 for ch in value), path + (key,),
            "only Latin-1 characters (the link sends one byte per character; \\xNN for a byte)")
    return value


def _number(doc: Mapping[str, Any], key: str, path: tuple[str | int, ...], default: float,
            low: float, high: float, integer: bool = False) -> float:
    value = doc.get(key, default)
    kind = "a whole number" if integer else "a number"
    _expect(isinstance(value, int | float) and not isinstance(value, bool), path + (key,),
            f"must be {kind}, not {value!r}")
    _expect(low <= value <= high and (not integer or float(value).is_integer()), path + (key,),
            f"must be {kind} in {low:g}..{high:g}, not {value!r}")
    return value


def _template(text: str, path: tuple[str | int, ...]) -> str:
    try:
        parts = list(string.Formatter().parse(text))
    except ValueError as exc:
        raise DescriptionError(path, f"not a valid template ({exc}); write a literal brace as {{{{ or "
                                     "}}}}") from None
    for _, name, spec, conversion in parts:
        if name is None:
            continue
        allowed = ", ".join("{" + f + "}" for f in FIELDS)
        _expect(name in FIELDS, path, f"field {{{name}}} is not one of {allowed}")
        _expect(conversion is None and "{" not in (spec or ""), path, f"field {{{name}}}: a format spec only "
                "(e.g. {value:.2f}), no conversion or nested field")
        try:
            format(1.5 if name == "value" else 1, spec or "")
        except ValueError as exc:
            raise DescriptionError(path, f"field {{{name}:{spec}}}: {exc}") from None
    return text


def _pattern(text: str, path: tuple[str | int, ...]) -> re.Pattern[str]:
    try:
        return re.compile(text)
    except re.error as exc:
        raise DescriptionError(path, f"not a regular expression: {exc}") from None


def _command(doc: Any, path: tuple[str | int, ...]) -> Command:
    _expect(isinstance(doc, Mapping), path, "must be a mapping with send (and reply)")
    unknown = set(doc) - {"send", "reply", "idempotent"}
    _expect(not unknown, path + (sorted(unknown)[0] if unknown else "",), "unknown key; a command has "
            "send, reply and idempotent")
    send = doc.get("send")
    sends = [send] if isinstance(send, str) else send
    _expect(isinstance(sends, list) and 0 < len(sends) <= 8, path + ("send",),
            "must be a command (text) or a list of up to 8")
    where = [path + ("send", i) if isinstance(send, list) else path + ("send",) for i in range(len(sends))]
    sent = tuple(_template(_text({"s": s}, "s", w[:-1] if not isinstance(send, list) else w), w)
                 for s, w in zip(sends, where, strict=True))
    reply = doc.get("reply")
    if reply is None or isinstance(reply, str):
        replies = [reply] * len(sent)
    else:
        _expect(isinstance(reply, list) and len(reply) == len(sent), path + ("reply",),
                f"must be a pattern, null, or a list of {len(sent)} (one per command sent)")
        replies = reply
    patterns = []
    for i, r in enumerate(replies):
        at = path + ("reply",) + ((i,) if isinstance(reply, list) else ())
        _expect(r is None or isinstance(r, str), at, "must be a regular expression (text) or null")
        patterns.append(None if r is None else _pattern(r, at))
    idempotent = doc.get("idempotent", True)
    _expect(isinstance(idempotent, bool), path + ("idempotent",), "must be true or false")
    return Command(sent, tuple(patterns), idempotent)


def _register(doc: Any, path: tuple[str | int, ...]) -> Register:
    _expect(isinstance(doc, Mapping), path, "must be a mapping with address and type")
    unknown = set(doc) - {"address", "type", "scale", "write", "value"}
    _expect(not unknown, path + (sorted(unknown)[0] if unknown else "",), "unknown key; a register has "
            "address, type, scale, write and value")
    address = int(_number(doc, "address", path, -1, 0, 65535, integer=True))
    kind = doc.get("type", "int16")
    _expect(kind in REGISTER_TYPES, path + ("type",), f"must be one of {', '.join(REGISTER_TYPES)}")
    scale = _number(doc, "scale", path, 1.0, -1e9, 1e9)
    _expect(scale != 0, path + ("scale",), "must not be 0")
    write = doc.get("write", False)
    _expect(isinstance(write, bool), path + ("write",), "must be true or false")
    value = doc.get("value")
    number = isinstance(value, int | float) and not isinstance(value, bool)
    _expect(value is None or number, path + ("value",), "must be a number (written as is) or absent")
    return Register(address, kind, float(scale), write, None if value is None else float(value))


def _link(doc: Any, protocol: str) -> LinkSettings:
    path: tuple[str | int, ...] = ("link",)
    doc = {} if doc is None else doc
    _expect(isinstance(doc, Mapping), path, "must be a mapping")
    known = {f for f in LinkSettings.__dataclass_fields__}
    unknown = set(doc) - known
    _expect(not unknown, path + (sorted(unknown)[0] if unknown else "",),
            f"unknown key; known: {', '.join(sorted(known))}")
    transport = doc.get("transport", "modbus-rtu" if protocol == "modbus" else "serial")
    _expect(transport in TRANSPORTS, path + ("transport",), f"must be one of {', '.join(TRANSPORTS)}")
    _expect(transport.startswith("modbus") == (protocol == "modbus"), path + ("transport",),
            f"a {protocol} description takes " + ("modbus-rtu or modbus-tcp" if protocol == "modbus" else
                                                   "tcp, serial or auto"))
    tcp_port = doc.get("tcp_port")
    if tcp_port is not None:
        tcp_port = int(_number(doc, "tcp_port", path, 0, 1, 65535, integer=True))
    return LinkSettings(
        transport=transport, tcp_port=tcp_port,
        baud=int(_number(doc, "baud", path, 9600, 50, 12_000_000, integer=True)),
        write_end=_text(doc, "write_end", path, "\n", 4), read_end=_text(doc, "read_end", path, "\n", 4),
        quiet_s=_number(doc, "quiet_s", path, 0.05, 0.001, 5.0),
        delay_s=_number(doc, "delay_s", path, 0.0, 0.0, 5.0),
        timeout_s=_number(doc, "timeout_s", path, 1.0, 0.01, 60.0),
        retries=int(_number(doc, "retries", path, 2, 0, 10, integer=True)),
        unit=int(_number(doc, "unit", path, 1, 0, 247, integer=True)))


def describe(doc: Any) -> InstrumentDescription:
    """Check a description document and build it.

    Parameters
    ----------
    doc : mapping
        The document, as read from YAML.

    Returns
    -------
    InstrumentDescription

    Raises
    ------
    DescriptionError
        The first problem found, with the key path of the value.
    """
    _expect(isinstance(doc, Mapping), (), "must be a mapping (schema, name, kind, protocol, link, commands)")
    known = {"schema", "name", "kind", "protocol", "link", "commands", "registers", "error_reply",
             "word_order", "axes", "notes"}
    unknown = set(doc) - known
    _expect(not unknown, (sorted(map(str, unknown))[0] if unknown else "",),
            f"unknown key; known: {', '.join(sorted(known))}")
    _expect(doc.get("schema") == SCHEMA, ("schema",), f"must be {SCHEMA}")
    name = _text(doc, "name", (), "", 80)
    _expect(bool(re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name)), ("name",),
            "must be letters, digits, '.', '_' or '-' (it is shown in messages and the run record)")
    kind = doc.get("kind")
    _expect(kind in KINDS, ("kind",), f"must be one of {', '.join(KINDS)}")
    protocol = doc.get("protocol", "ascii")
    _expect(protocol in PROTOCOLS, ("protocol",), f"must be one of {', '.join(PROTOCOLS)}")
    link = _link(doc.get("link"), protocol)
    required, optional = OPERATIONS[kind]
    section = "commands" if protocol == "ascii" else "registers"
    other = "registers" if protocol == "ascii" else "commands"
    _expect(other not in doc, (other,), f"a {protocol} description gives {section}, not {other}")
    ops = doc.get(section)
    _expect(isinstance(ops, Mapping) and 0 < len(ops) <= MAX_COMMANDS, (section,),
            f"must be a mapping of operation to {section[:-1]}")
    for op in ops:
        _expect(op in required or op in optional, (section, str(op)),
                f"not an operation of a {kind}; known: {', '.join(required + optional)}")
    missing = [op for op in required if op not in ops]
    _expect(not missing, (section,), f"a {kind} needs {', '.join(missing)}")
    commands = {op: _command(ops[op], (section, op)) for op in ops} if protocol == "ascii" else {}
    registers = {op: _register(ops[op], (section, op)) for op in ops} if protocol == "modbus" else {}
    error_reply = doc.get("error_reply")
    if error_reply is not None:
        error_reply = _pattern(_text(doc, "error_reply", ()), ("error_reply",))
    word_order = doc.get("word_order", "big")
    _expect(word_order in ("big", "little"), ("word_order",), "must be big (high word first) or little")
    axes = int(_number(doc, "axes", (), 1, 1, 3, integer=True))
    notes = doc.get("notes", "")
    _expect(isinstance(notes, str), ("notes",), "must be text")
    return InstrumentDescription(name, kind, protocol, link, commands, registers, error_reply, word_order,
                                 axes, notes)
