"""The frame shared by the long-recording screens: record the stream until Enter, then fit it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Footer, Header, Static
from textual_plotext import PlotextPlot

from station.errors import StationError
from station.export.params.file import UnitMismatchError
from station.tui.messages import LinkFailed, Snapshot
from station.tui.recording import open_recording
from station.tui.saving import REPLACE_KEY, existing_section, save_sections
from station.tui.screens.ask import AskScreen
from station.tui.screens.station_screen import StationScreen


class LongRecordingScreen(StationScreen):
    """Two plots side by side (``#plot-0``, ``#plot-1``) over a ``#side`` panel, for a recording
    named ``KIND``.

    A subclass supplies the texts below, a ``_read`` worker that fills ``self.recording`` and posts
    progress snapshots for ``show_progress``, and a ``_fit`` worker, run once the reader is stopped,
    that posts ``{"fit": ..., "section": ...}``: ``show_fit`` shows the fit, then the ``SECTION`` is
    saved to ``--out``, asking first when the file already holds one.
    """

    BINDINGS = [Binding("enter", "stop", "stop and fit", show=True), Binding("escape", "back", "back")]
    DEFAULT_CSS = """
    LongRecordingScreen #plots { height: 2fr; min-height: 10; }
    LongRecordingScreen PlotextPlot { width: 1fr; height: 1fr; }
    LongRecordingScreen #side-box { height: 1fr; min-height: 7; border: round $secondary; padding: 0 1; }
    LongRecordingScreen #saved { display: none; }
    """
    HEADING = ""
    KIND = ""
    INTRO = ""
    FITTING = ""
    SECTION = ""

    def compose(self) -> ComposeResult:
        """The two plots, the side panel under them, the keys."""
        yield Header()
        with Horizontal(id="plots"):
            yield PlotextPlot(id="plot-0")
            yield PlotextPlot(id="plot-1")
        with VerticalScroll(id="side-box"):
            yield Static("", id="saved")
            yield Static(self.INTRO, id="side")
        yield Footer()

    def on_mount(self) -> None:
        """Open the recording (beside --out) and start reading the unit."""
        self.title = f"imu-station · {self.HEADING}"
        self.recording = open_recording(self.session, self.station.config.out, self.KIND)
        self.stopped = False
        self._read()

    def plots(self) -> tuple[PlotextPlot, PlotextPlot]:
        """The two plots, left and right."""
        return self.query_one("#plot-0", PlotextPlot), self.query_one("#plot-1", PlotextPlot)

    def on_unmount(self) -> None:
        """Close the recording file."""
        self.recording.close()

    def on_snapshot(self, message: Snapshot) -> None:
        """A progress snapshot, or the fit (shown, then its section saved)."""
        d = message.data
        if "fit" in d:
            self.show_fit(d["fit"])
            self.save_section(d["section"])
        elif not self.stopped:
            self.show_progress(d)

    def say_saved(self, text: str) -> None:
        """What became of the fit, above it, with the keys."""
        saved = self.query_one("#saved", Static)
        saved.update(Text(f"{text}\nEscape: back · q: quit", style="bold"))
        saved.display = True

    def save_section(self, value: Any) -> None:
        """Merge the fitted ``SECTION`` into ``--out``; a section already there is replaced only if the
        operator says so."""
        out = self.station.config.out
        name = self.SECTION
        if out is None:
            self.say_saved("no --out: nothing saved")
            return
        try:
            exists = existing_section(out, name)
        except StationError as exc:
            self.say_saved(f"{name} section not saved: {exc}")
            return
        if not exists:
            self._write(out, value)
            return

        def answered(reply: tuple[str, str] | None) -> None:
            if reply is not None and reply[0] == "r":
                self._write(out, value)
            else:
                self.say_saved(f"{name} section not saved: {out} keeps the one it had")

        self.app.push_screen(AskScreen(f"{out} already holds a {name} section. Replace it with this fit?",
                                       [("k", "keep the file's"), ("r", "replace it")]), answered)

    def _write(self, out: Path, value: Any, replace: bool = False) -> None:
        try:
            save_sections(out, self.session.info, {self.SECTION: value}, capture=self.recording.path,
                          replace=replace)
        except UnitMismatchError as exc:
            self.ask_other_unit(str(exc), out, value)
            return
        except (StationError, OSError) as exc:  # OSError: a folder that cannot be made
            self.say_saved(f"{self.SECTION} section not saved: {exc}")
            return
        self.say_saved(f"{self.SECTION} section saved to {out}")

    def ask_other_unit(self, refusal: str, out: Path, value: Any) -> None:
        """``out`` holds another unit's results: save to another file, replace it, or keep the fit unsaved."""
        def answered(reply: tuple[str, str] | None) -> None:
            key, chosen = reply if reply is not None else ("back", "")
            if key == "s" and chosen:
                self._write(Path(chosen), value)
            elif key == REPLACE_KEY:
                self._write(Path(chosen or out), value, replace=True)
            else:
                self.say_saved(f"{self.SECTION} section not saved: {out} holds another unit")

        self.app.push_screen(AskScreen(refusal, [("s", "save to the file named here (e: edit)"),
                                                 (REPLACE_KEY, "replace that file: its sections are dropped"),
                                                 ("k", "do not save")], str(out)), answered)

    def on_link_failed(self, message: LinkFailed) -> None:
        """The link or the fit failed: say why."""
        self.query_one("#side", Static).update(Text(f"{message.error}", style="red"))

    def action_stop(self) -> None:
        """Enter: stop reading, close the recording and fit it."""
        if self.stopped:
            return
        self.stopped = True
        self.workers.cancel_group(self, "reader")
        self.recording.close()
        self.query_one("#side", Static).update(self.FITTING)
        self._fit()

    def action_back(self) -> None:
        """Escape: back to the live view."""
        self.station.show("live")

    # ---- what a subclass supplies -----------------------------------------------------------------

    def _read(self) -> object:
        """Thread worker: fill ``self.recording`` and post progress snapshots."""
        raise NotImplementedError

    def _fit(self) -> object:
        """Thread worker: fit the stopped recording and post ``{"fit": ..., "saved": ...}``."""
        raise NotImplementedError

    def show_progress(self, data: dict[str, Any]) -> None:
        """Show a progress snapshot of ``_read``."""
        raise NotImplementedError

    def show_fit(self, fit: Any) -> None:
        """Show what ``_fit`` posted."""
        raise NotImplementedError
