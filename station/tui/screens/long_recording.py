"""The frame shared by the long-recording screens: record the stream until Enter, then fit it."""

from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.widgets import Footer, Header, Static

from station.tui.messages import LinkFailed, Snapshot
from station.tui.recording import open_recording
from station.tui.screens.station_screen import StationScreen


class LongRecordingScreen(StationScreen):
    """A ``#plots`` panel and a ``#side`` panel over a recording named ``KIND``.

    A subclass supplies the texts below, a ``_read`` worker that fills ``self.recording`` and posts
    progress snapshots for ``show_progress``, and a ``_fit`` worker, run once the reader is stopped,
    that posts ``{"fit": ..., "saved": path or None}`` for ``show_fit``.
    """

    BINDINGS = [Binding("enter", "stop", "stop and fit", show=True), Binding("escape", "back", "back")]
    HEADING = ""
    KIND = ""
    INTRO = ""
    FITTING = ""

    def compose(self) -> ComposeResult:
        yield Header()
        with Horizontal():
            yield Static("", id="plots")
            yield Static(self.INTRO, id="side")
        yield Footer()

    def on_mount(self) -> None:
        self.title = f"imu-station · {self.HEADING}"
        self.recording = open_recording(self.session, self.station.config.out, self.KIND)
        self.stopped = False
        self._read()

    def on_unmount(self) -> None:
        self.recording.close()

    def on_snapshot(self, message: Snapshot) -> None:
        d = message.data
        if "fit" in d:
            self.show_fit(d["fit"], d["saved"])
        elif not self.stopped:
            self.show_progress(d)

    def on_link_failed(self, message: LinkFailed) -> None:
        self.query_one("#side", Static).update(Text(f"{message.error}", style="red"))

    def action_stop(self) -> None:
        if self.stopped:
            return
        self.stopped = True
        self.workers.cancel_group(self, "reader")
        self.recording.close()
        self.query_one("#side", Static).update(self.FITTING)
        self._fit()

    def action_back(self) -> None:
        self.station.show("live")

    # ---- what a subclass supplies -----------------------------------------------------------------

    def _read(self) -> object:
        """Thread worker: fill ``self.recording`` and post progress snapshots."""
        raise NotImplementedError

    def _fit(self) -> object:
        """Thread worker: fit the stopped recording and post ``{"fit": ..., "saved": ...}``."""
        raise NotImplementedError

    def show_progress(self, data: dict[str, Any]) -> None:
        raise NotImplementedError

    def show_fit(self, fit: Any, saved: str | None) -> None:
        raise NotImplementedError
