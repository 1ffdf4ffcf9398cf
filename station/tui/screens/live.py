"""Live view: the latest values (the magnetic field too, for a unit that reports one), the measured
rate, the accelerometer and gyroscope traces, errors and lost samples."""

from __future__ import annotations

import threading
import time

import numpy as np
from rich.console import Console, ConsoleOptions, RenderResult
from rich.measure import Measurement
from rich.segment import Segment
from rich.style import Style
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.timer import Timer
from textual.widgets import Footer, Header, Static
from textual_plotext import PlotextPlot

from drivers.paced_port import PacedPort
from protocols.base import has_mag
from station.tui.messages import LinkFailed, Snapshot
from station.tui.plot import FastPlot, Series, draw
from station.tui.pump import Tail, pump
from station.tui.screens.station_screen import StationScreen

AXIS_COLORS = ("red", "green", "blue")
TAIL_SAMPLES = 400
# The screen's frame rate: at most UI_RATE_HZ snapshots a second (the values, the link), whatever the
# unit's rate, each drawn without a layout pass while its number of lines stays; the traces at most
# PLOT_RATE_HZ, and only when new samples came. A trace costs plotext (pure Python) 20-30 ms of CPU
# (its canvas built whatever the points; station.tui.plot vectorises its lines), the most of what
# this screen costs: 4 drawings a second took 0.35 of a core with a 1 kHz unit.
UI_RATE_HZ = 10.0
PLOT_RATE_HZ = 1.0
# Tail columns: device time (s), acc x y z, gyro x y z, temperature, field x y z (NaN without).
T, ACC, GYRO, TEMP, MAG = 0, slice(1, 4), slice(4, 7), 7, slice(8, 11)
HEADER = ("", "x", "y", "z", "unit")
NULL_STYLE, BOLD = Style.null(), Style(bold=True)


class Values:
    """The values under the header "x y z unit" and the link's line below: the segments a rich Table (no
    box, padding 2, right-justified columns, a bold header) in a grid with the link yields, without its
    measuring: a tenth of its CPU, ten times a second. A cell wider than the screen is not shortened."""

    def __init__(self, rows: list[tuple[str, ...]], link: str) -> None:
        self.rows = rows
        self.link = Text.from_markup(link)
        self.widths = [max(len(cells[j]) for cells in (HEADER, *rows)) for j in range(len(HEADER))]
        self.width = sum(self.widths) + 4 * len(HEADER)

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        """As wide as the table, or the link's line when it is wider (it wraps)."""
        return Measurement(self.width, max(self.width, self.link.cell_len))

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        """Each row: per cell, its padding and its text right-justified (the header bold), then the
        link, wrapped to the width."""
        pad, null, bold = Segment("  ", NULL_STYLE), NULL_STYLE, BOLD
        fill = Segment(" " * max(0, options.max_width - self.width), null)
        for i, cells in enumerate((HEADER, *self.rows)):
            if i == 0:
                head = Segment("  ", bold)
                for cell, width in zip(cells, self.widths, strict=True):
                    yield from (head, Segment(cell.rjust(width), bold), head)
            else:
                for cell, width in zip(cells, self.widths, strict=True):
                    yield from (pad, Segment(cell.rjust(width)), pad)
            if fill.text:
                yield fill
            yield Segment.line()
        yield from console.render(self.link, options)


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
            yield FastPlot(id="plot-acc")
            yield FastPlot(id="plot-gyro")
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
        self._plotted_rows: tuple[int, float] | None = None  # (count, newest time) of the rows drawn
        self._values_shape: tuple[int, int, int] | None = None  # rows, widths drawn last
        # The paced port read once a frame, not every 20 ms: the same samples in fewer, larger batches
        # (a pty holds 0.4 s of a 1 kHz unit); the wizard's runner gets the port's own pacing back.
        device = self.session.device
        self._period: float | None = None
        if isinstance(device, PacedPort):
            self._period = device.period_s
            device.period_s = max(device.period_s, 1.0 / UI_RATE_HZ)
        self._read()

    def on_unmount(self) -> None:
        """Give the port its own pacing back."""
        device = self.station.session.device if self.station.session is not None else None
        if self._period is not None and isinstance(device, PacedPort):
            device.period_s = self._period

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
        cells = [("accel", *(f"{v:+9.4f}" for v in last[0:3]), "m/s^2"),
                 ("gyro", *(f"{v:+9.5f}" for v in last[3:6]), "rad/s"),
                 ("|a|", f"{np.linalg.norm(last[0:3]):9.4f}", "", "", "m/s^2"),
                 ("temp", f"{last[6]:9.2f}", "", "", "degC")]
        field = rows[-1, MAG]
        if field.size == 3 and np.isfinite(field).all():  # a unit that reports a magnetometer
            cells.append(("mag", *(f"{v:+9.2f}" for v in field), "uT"))
        values = Values(cells, f"rate [b]{stats.rate_hz:.1f} Hz[/b]   samples {stats.samples}   errors "
                        f"{stats.errors} (CRC {stats.crc_errors})   lost {stats.lost}   dropped "
                        f"{stats.overflow_drops}")
        # The same rows and a link line as long as last time (it may wrap on a narrow screen): the
        # values' box keeps its size, so no layout pass over the screen.
        shape = (len(cells), values.width, values.link.cell_len)
        self.query_one("#values", Static).update(values, layout=shape != self._values_shape)
        self._values_shape = shape
        self._rows = rows
        if self._plotted_rows == (len(rows), float(rows[-1, T])):
            return  # no new samples: the traces stand
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
        self._plotted_rows = (len(rows), float(rows[-1, T]))
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
        self._values_shape = None

    def action_wizard(self) -> None:
        """Enter: the sequence wizard."""
        self.station.show("wizard")
