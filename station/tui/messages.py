"""Messages that thread workers post to the screens (``post_message`` is thread-safe)."""

from __future__ import annotations

from typing import Any

from textual.message import Message


class Snapshot(Message):
    """A coalesced snapshot for a screen: ``data`` is whatever that screen draws."""

    def __init__(self, data: dict[str, Any]) -> None:
        super().__init__()
        self.data = data


class LinkFailed(Message):
    """Posted from a worker thread when the link or a fit fails: ``error`` says why."""

    def __init__(self, error: Exception) -> None:
        super().__init__()
        self.error = error
