"""Live view: the latest values, the measured rate, a sparkline per axis, errors and lost samples."""

from __future__ import annotations

import threading

import numpy as np
from rich.table import Table
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Grid, Horizontal
from textual.widgets import Footer, Header, Label, Sparkline, Static

from station.tui.messages import LinkFailed, Snapshot
from station.tui.pump import Tail, pump
from station.tui.screens.station_screen import StationScreen

CHANNELS = ("ax", "ay", "az", "gx", "gy", "gz")
TAIL_SAMPLES = 400


class LiveScreen(StationScreen):
    BINDINGS = [Binding("enter", "wizard", "sequence wizard", show=True)]
    DEFAULT_CSS = """
    LiveScreen #values { height: auto; border: round $accent; padding: 0 1; }
    LiveScreen Grid { grid-size: 2; grid-columns: 8 1fr; height: auto; grid-rows: 2; }
    LiveScreen Sparkline { height: 2; }
    """

    def compose(self) -> ComposeResult:
        yield Header()
        yield Static("waiting for samples ...", id="values")
        with Grid():
            for name in CHANNELS:
                yield Label(name)
                yield Sparkline([], id=f"spark-{name}", summary_function=np.mean)
        with Horizontal():
            yield Static("Enter: sequence wizard · a: Allan recording · t: temperature sweep · ?: help",
                         id="hint")
        yield Footer()

    def on_mount(self) -> None:
        self.title = "imu-station · live"
        self._lock = threading.Lock()
        self._tail = Tail(TAIL_SAMPLES, 7)
        self._read()

    @work(thread=True, exclusive=True, group="reader")
    def _read(self) -> None:
        device = self.session.device

        def on_batch(batch: np.ndarray) -> None:
            rows = np.column_stack([batch["acc"], batch["gyro"], batch["temp"]])
            with self._lock:
                self._tail.add(rows)

        def on_tick() -> None:
            with self._lock:
                data = self._tail.data.copy()
            stats = device.stats
            self.post_message(Snapshot({"tail": data, "stats": stats}))

        pump(device, on_batch, on_tick, lambda exc: self.post_message(LinkFailed(exc)))

    def on_snapshot(self, message: Snapshot) -> None:
        tail = message.data["tail"]
        stats = message.data["stats"]
        rows = tail[np.isfinite(tail[:, 0])]
        if not len(rows):
            return
        last = rows[-1]
        table = Table(box=None, padding=(0, 2), show_header=True, header_style="bold")
        for col in ("", "x", "y", "z", "unit"):
            table.add_column(col, justify="right")
        table.add_row("accel", *(f"{v:+9.4f}" for v in last[0:3]), "m/s^2")
        table.add_row("gyro", *(f"{v:+9.5f}" for v in last[3:6]), "rad/s")
        table.add_row("|a|", f"{np.linalg.norm(last[0:3]):9.4f}", "", "", "m/s^2")
        table.add_row("temp", f"{last[6]:9.2f}", "", "", "degC")
        link = (f"rate [b]{stats.rate_hz:.1f} Hz[/b]   samples {stats.samples}   errors {stats.errors} "
                f"(CRC {stats.crc_errors})   lost {stats.lost}   dropped {stats.overflow_drops}")
        grid = Table.grid()
        grid.add_row(table)
        grid.add_row(link)
        self.query_one("#values", Static).update(grid)
        for j, name in enumerate(CHANNELS):
            series = rows[:, j]
            self.query_one(f"#spark-{name}", Sparkline).data = (series - series.mean()).tolist()

    def on_link_failed(self, message: LinkFailed) -> None:
        self.query_one("#values", Static).update(f"[red]link lost: {message.error}[/red]")

    def action_wizard(self) -> None:
        self.station.show("wizard")
