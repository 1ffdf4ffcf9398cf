"""Live view: the latest values (the magnetic field too, for a unit that reports one), the measured
rate, the accelerometer and gyroscope traces, errors and lost samples."""

from __future__ import annotations

import threading
import time

import numpy as np
from rich.table import Table
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.timer import Timer
from textual.widgets import Footer, Header, Static
from textual_plotext import PlotextPlot

from protocols.base import has_mag
from station.tui.messages import LinkFailed, Snapshot
from station.tui.plot import Series, draw
from station.tui.pump import Tail, pump
from station.tui.screens.station_screen import StationScreen

AXIS_COLORS = ("red", "green", "blue")
TAIL_SAMPLES = 400
# At most UI_RATE_HZ snapshots a second (the values, the link) and PLOT_RATE_HZ drawings of the traces:
# a trace costs plotext (pure Python) 20-50 ms of CPU whatever its points, its whole canvas built and
# transposed; it was the most of what the TUI cost on this screen (20 drawings a second wanted 2 cores).
UI_RATE_HZ = 10.0
PLOT_RATE_HZ = 4.0
# Tail columns: device time (s), acc x y z, gyro x y z, temperature, field x y z (NaN without).
T, ACC, GYRO, TEMP, MAG = 0, slice(1, 4), slice(4, 7), 7, slice(8, 11)


class LiveScreen(StationScreen):
    """The unit's latest values and link health, and the last seconds of each triad as traces."""

    BINDINGS = [Binding("enter", "wizard", "sequence wizard", show=True)]
    DEFAULT_CSS = """
    LiveScreen #values { height: auto; border: round $accent; padding: 0 1; }
    LiveScreen #plots { height: 1fr; min-height: 8; }
    LiveScreen PlotextPlot { width: 1fr; height: 1fr; }
    LiveScreen #hint { height: 1; padding: 0 1; color: $text-muted; }
    """

    def compose(self) -> ComposeResult:
        """The values, the two trace plots side by side, the keys."""
        yield Header()
        yield Static("waiting for samples ...", id="values")
        with Horizontal(id="plots"):
            yield PlotextPlot(id="plot-acc")
            yield PlotextPlot(id="plot-gyro")
        yield Static("Enter: sequence wizard · a: Allan · t: temperature sweep · ?: help", id="hint")
        yield Footer()

    def on_mount(self) -> None:
        """Start reading the unit."""
        self.title = "imu-station · live"
        self._lock = threading.Lock()
        self._tail = Tail(TAIL_SAMPLES, 11)
        # Set while no snapshot waits for the UI: a UI slower than the snapshots (a busy machine) is
        # sent the newest when it is ready, never a queue of stale ones to draw in turn.
        self._taken = threading.Event()
        self._taken.set()
        self._rows = np.empty((0, 11))
        self._plot_timer: Timer | None = None
        self._plotted = 0.0  # time.monotonic() of the last traces drawn
        self._read()

    @work(thread=True, exclusive=True, group="reader")
    def _read(self) -> None:
        device = self.session.device

        def on_batch(batch: np.ndarray) -> None:
            field = batch["mag"] if has_mag(batch) else np.full((len(batch), 3), np.nan)
            rows = np.column_stack([batch["t_us"] * 1e-6, batch["acc"], batch["gyro"], batch["temp"], field])
            with self._lock:
                self._tail.add(rows)

        def on_tick() -> None:
            if not self._taken.is_set():
                return
            self._taken.clear()
            with self._lock:
                data = self._tail.data.copy()
            stats = device.stats
            self.post_message(Snapshot({"tail": data, "stats": stats}))

        pump(device, on_batch, on_tick, lambda exc: self.post_message(LinkFailed(exc)), UI_RATE_HZ)

    def on_snapshot(self, message: Snapshot) -> None:
        """Show the latest values, the link, and the traces of the last samples."""
        self._taken.set()
        tail = message.data["tail"]
        stats = message.data["stats"]
        rows = tail[np.isfinite(tail[:, 0])]
        if not len(rows):
            return
        last = rows[-1, 1:]
        table = Table(box=None, padding=(0, 2), show_header=True, header_style="bold")
        for col in ("", "x", "y", "z", "unit"):
            table.add_column(col, justify="right")
        table.add_row("accel", *(f"{v:+9.4f}" for v in last[0:3]), "m/s^2")
        table.add_row("gyro", *(f"{v:+9.5f}" for v in last[3:6]), "rad/s")
        table.add_row("|a|", f"{np.linalg.norm(last[0:3]):9.4f}", "", "", "m/s^2")
        table.add_row("temp", f"{last[6]:9.2f}", "", "", "degC")
        field = rows[-1, MAG]
        if field.size == 3 and np.isfinite(field).all():  # a unit that reports a magnetometer
            table.add_row("mag", *(f"{v:+9.2f}" for v in field), "uT")
        link = (f"rate [b]{stats.rate_hz:.1f} Hz[/b]   samples {stats.samples}   errors {stats.errors} "
                f"(CRC {stats.crc_errors})   lost {stats.lost}   dropped {stats.overflow_drops}")
        grid = Table.grid()
        grid.add_row(table)
        grid.add_row(link)
        self.query_one("#values", Static).update(grid)
        self._rows = rows
        wait = self._plotted + 1.0 / PLOT_RATE_HZ - time.monotonic()
        if wait <= 0:
            self._plot()
        elif self._plot_timer is None:  # the traces of the newest rows, when their turn comes
            self._plot_timer = self.set_timer(wait, self._plot)

    def _plot(self) -> None:
        """Draw the traces of the newest rows."""
        if self._plot_timer is not None:
            self._plot_timer.stop()
            self._plot_timer = None
        self._plotted = time.monotonic()
        rows = self._rows
        t = rows[:, T] - rows[-1, T]  # seconds before the latest sample
        for name, columns, title, unit in (("acc", ACC, "accelerometer", "m/s^2"),
                                            ("gyro", GYRO, "gyroscope", "rad/s")):
            values = rows[:, columns]
            draw(self.query_one(f"#plot-{name}", PlotextPlot),
                 [Series(axis, t, values[:, j], AXIS_COLORS[j]) for j, axis in enumerate("xyz")],
                 title=title, xlabel="time (s)", ylabel=unit)

    def on_link_failed(self, message: LinkFailed) -> None:
        """The link failed: say so where the values were."""
        self.query_one("#values", Static).update(f"[red]link lost: {message.error}[/red]")

    def action_wizard(self) -> None:
        """Enter: the sequence wizard."""
        self.station.show("wizard")
