"""The messages a unit sent besides its samples: the last ones, numbered, and what it said it is.

A device keeps one :class:`MessageLog`; a command notes :attr:`MessageLog.count` before it is
sent and finds its answer among the messages after that mark (:meth:`MessageLog.answer_since`).
"""

from __future__ import annotations

import json
from collections import deque
from typing import Any

from drivers.errors import CommandRejected, CommandTimeout, CommandUnsupported
from protocols import native
from protocols.base import Message

MESSAGE_BACKLOG = 64
COMMAND_NAMES = {native.GET_INFO: "GET_INFO", native.SET_RATE: "SET_RATE",
                 native.START_STREAM: "START_STREAM", native.STOP_STREAM: "STOP_STREAM",
                 native.RESTART: "RESTART"}


def command_name(command_id: int) -> str:
    """A native command's name, for messages (``command 0x2a`` when it has none)."""
    return COMMAND_NAMES.get(command_id, f"command 0x{command_id:02x}")


class MessageLog:
    """The last :data:`MESSAGE_BACKLOG` messages, numbered from 1, and the unit's last DEVICE_INFO.

    Not thread-safe by itself: a device with a reader thread calls it under its own lock.
    """

    def __init__(self) -> None:
        self.count = 0
        self.info: dict[str, Any] = {}
        self._messages: deque[tuple[int, Message]] = deque(maxlen=MESSAGE_BACKLOG)

    def add(self, message: Message) -> None:
        """Keep ``message``; a DEVICE_INFO updates :attr:`info` (one that is not a JSON object is dropped)."""
        if message.msg_id == native.DEVICE_INFO:
            try:
                self.info = native.parse_device_info(message.payload)
            except (ValueError, UnicodeDecodeError):
                return
        self.count += 1
        self._messages.append((self.count, message))

    def answer_since(self, command_id: int, mark: int, port: str) -> Message | None:
        """The answer to ``command_id`` among the messages after ``mark``, or None: DEVICE_INFO for
        GET_INFO, else the ACK naming it; an ACK with an error status raises ``CommandRejected``."""
        for index, message in self._messages:
            if index > mark and _answers(message, command_id):
                if message.msg_id == native.ACK:
                    ack = native.parse_ack(message.payload)
                    if not ack.ok:
                        status = native.ACK_STATUS_NAMES.get(ack.status, f"status {ack.status}")
                        name = command_name(command_id)
                        raise CommandRejected(f"{port}: the unit refused {name}: {status}", port, ack.status)
                return message
        return None


def _answers(message: Message, command_id: int) -> bool:
    if command_id == native.GET_INFO:
        if message.msg_id != native.DEVICE_INFO:
            return False
        try:
            json.loads(message.payload.decode("utf-8"))
        except (ValueError, UnicodeDecodeError):
            return False
        return True
    return message.msg_id == native.ACK and len(message.payload) == 2 and message.payload[0] == command_id


def unsupported(port: str, protocol: str, command_id: int) -> CommandUnsupported:
    """The error of a command sent to a unit whose protocol has no commands."""
    return CommandUnsupported(f"{port}: the {protocol} protocol has no {command_name(command_id)} command; "
                              f"configure the unit with its vendor's tool", port)


def no_answer(port: str, protocol: str, command_id: int, tries: int, timeout: float) -> CommandTimeout:
    """The error of a command that ``tries`` sendings of ``timeout`` seconds each left unanswered."""
    return CommandTimeout(f"{port}: no answer to {command_name(command_id)} in {tries} tries of "
                          f"{timeout:g} s; check that the unit is powered, speaks the {protocol} protocol "
                          f"and that the baud rate is right", port)
