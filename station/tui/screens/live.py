"""Live view: the latest values (the magnetic field too, for a unit that reports one), the measured
rate, the accelerometer and gyroscope traces, errors and lost samples."""

from __future__ import annotations

import threading
import time

import numpy as np
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.timer import Timer
from textual.widgets import Footer, Header, Static

from drivers.link_stats import LinkStats
from drivers.paced_port import PacedPort
from protocols.base import has_mag
from station.tui.messages import LinkFailed, Snapshot
from station.tui.pump import Tail, pump
from station.tui.screens.station_screen import StationScreen
from station.tui.traces import TracePlot
from station.tui.values import ValuesPanel

AXIS_COLORS = ("red", "green", "blue")
TAIL_SAMPLES = 400
# The screen's frame rate: at most UI_RATE_HZ snapshots a second (the values, the link), whatever the
# unit's rate, each drawn without a layout pass while its number of lines stays; the traces at most
# PLOT_RATE_HZ, only when new samples came and the screen is the one shown, at once when samples follow
# a quiet spell. A trace is drawn with numpy (station.tui.traces, about 1 ms); what remains is textual
# compositing its lines, so the traces keep a lower rate than the values.
UI_RATE_HZ = 10.0
PLOT_RATE_HZ = 2.0
# Tail columns: device time (s), acc x y z, gyro x y z, temperature, field x y z (NaN without).
T, ACC, GYRO, TEMP, MAG = 0, slice(1, 4), slice(4, 7), 7, slice(8, 11)


class LiveScreen(StationScreen):
    """The unit's latest values and link health, and the last seconds of each triad as traces."""

    BINDINGS = [Binding("enter", "wizard", "sequence wizard", show=True)]
    DEFAULT_CSS = """
    LiveScreen #values { border: round $accent; padding: 0 1; }
    LiveScreen #plots { height: 1fr; min-height: 8; }
    LiveScreen TracePlot { width: 1fr; height: 1fr; }
    LiveScreen #hint { height: 1; padding: 0 1; color: $text-muted; }
    """

    def compose(self) -> ComposeResult:
        """The values, the two trace plots side by side, the keys."""
        yield Header()
        yield ValuesPanel("waiting for samples ...", id="values")
        with Horizontal(id="plots"):
            yield TracePlot("accelerometer", "m/s^2", id="plot-acc")
            yield TracePlot("gyroscope", "rad/s", id="plot-gyro")
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
        self._stats: LinkStats | None = None  # the link's, with the newest rows
        self._plot_timer: Timer | None = None
        self._plotted = 0.0  # time.monotonic() of the last traces drawn
        self._plotted_rows: tuple[int, float] | None = None  # (count, newest time) of the rows drawn
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
        self._rows, self._stats = rows, stats
        if not self.shown:
            return  # under another screen: drawn when shown again
        self._draw_values(rows, stats)
        self._plot_when_due()

    @property
    def shown(self) -> bool:
        """Whether the screen can be seen: on top, or under screens that all let it show through (a
        modal such as the help). textual's ``is_current`` counts the screen under any top screen."""
        stack = self.app.screen_stack
        if self not in stack:
            return False
        return all(above.styles.background.a < 1 for above in stack[stack.index(self) + 1:])

    def on_screen_resume(self) -> None:
        """On top again: the newest values and traces at once."""
        if len(self._rows) and self._stats is not None:
            self._draw_values(self._rows, self._stats)
            self._plot_when_due()

    def _draw_values(self, rows: np.ndarray, stats: LinkStats) -> None:
        """The latest values and the link's line."""
        last = rows[-1, 1:]
        cells = [("accel", *(f"{v:+9.4f}" for v in last[0:3]), "m/s^2"),
                 ("gyro", *(f"{v:+9.5f}" for v in last[3:6]), "rad/s"),
                 ("|a|", f"{np.linalg.norm(last[0:3]):9.4f}", "", "", "m/s^2"),
                 ("temp", f"{last[6]:9.2f}", "", "", "degC")]
        field = rows[-1, MAG]
        if field.size == 3 and np.isfinite(field).all():  # a unit that reports a magnetometer
            cells.append(("mag", *(f"{v:+9.2f}" for v in field), "uT"))
        link = Text.assemble("rate ", (f"{stats.rate_hz:.1f} Hz", "bold"),
                             f"   samples {stats.samples}   errors {stats.errors} (CRC {stats.crc_errors})   "
                             f"lost {stats.lost}   dropped {stats.overflow_drops}")
        self.query_one("#values", ValuesPanel).show(cells, link)

    def _plot_when_due(self) -> None:
        """Draw the traces now if new samples came and their turn is due (at once after a quiet spell),
        else once it is."""
        rows = self._rows
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
        if not self.shown:
            return  # drawn when the screen is shown again
        self._plotted = time.monotonic()
        rows = self._rows
        self._plotted_rows = (len(rows), float(rows[-1, T]))
        draw_traces(self.query_one("#plot-acc", TracePlot), self.query_one("#plot-gyro", TracePlot), rows)

    def on_link_failed(self, message: LinkFailed) -> None:
        """The link failed: say so where the values were."""
        self.query_one("#values", ValuesPanel).say(Text(f"link lost: {message.error}", style="red"))

    def action_wizard(self) -> None:
        """Enter: the sequence wizard."""
        self.station.show("wizard")


def draw_traces(acc: TracePlot, gyro: TracePlot, rows: np.ndarray) -> None:
    """Give the two plots the traces of ``rows`` (tail columns), time in seconds before the newest."""
    t = rows[:, T] - rows[-1, T]
    acc.show(t, rows[:, ACC], "xyz", AXIS_COLORS)
    gyro.show(t, rows[:, GYRO], "xyz", AXIS_COLORS)
