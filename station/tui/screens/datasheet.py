"""The unit's datasheet on ``d``: every figure of ``--out`` in datasheet units, and across temperature
(a chamber campaign's or ``calibrate --across-temperature``'s file) the scale factor's change and the
turn-on repeatability at each soak, plotted.

It reads the file alone, so it opens with or without a unit connected.
"""

from __future__ import annotations

import numpy as np
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, VerticalScroll
from textual.events import Resize
from textual.widgets import Footer, Header, Static
from textual_plotext import PlotextPlot

from station.common.units import PEOPLE
from station.errors import StationError
from station.export.params.file import ParamsFile
from station.report.datasheet import Row, cell, datasheet_rows, format_table
from station.tui.plot import Series, draw
from station.tui.screens.station_screen import StationScreen

COLORS = ("red", "green", "blue")
SIDE_COLUMNS = 5  # the table's box: borders, padding and its scroll bar
TRIADS = {"gyro": ("gyroscope", "deg/s", PEOPLE["deg"]), "accel": ("accelerometer", "mg", PEOPLE["mg"])}


def _scale_series(params: ParamsFile, triad: str) -> list[Series]:
    """Per axis, k(t) of the triad's ``thermal.scale`` in ppm of K over its range."""
    model = params.thermal
    poly = model.scale.get(triad) if model is not None else None
    if model is None or poly is None:
        return []
    static = getattr(params, triad)
    k = static.scale if static is not None else np.ones(3)
    temp = np.linspace(poly.t_min, poly.t_max, 60)
    ppm = poly.evaluate(temp, model.reference_temp) / k * 1e6
    return [Series(axis, temp, ppm[:, j], COLORS[j]) for j, axis in enumerate("xyz")]


def _turn_on_series(params: ParamsFile, triad: str) -> list[Series]:
    """Per axis, the triad's turn-on repeatability at each soak of a campaign, in deg/s or mg."""
    block = (params.other.get("characterisation") or {}).get("across_temperature") or {}
    soaks = [s for s in block.get("turn_on") or [] if s.get(f"{triad}_bias_repeatability") is not None]
    if not soaks:
        return []
    temp = np.array([float(s["soak_c"]) for s in soaks])
    values = np.array([[np.nan if v is None else float(v) for v in s[f"{triad}_bias_repeatability"]]
                       for s in soaks]) * TRIADS[triad][2]
    return [Series(axis, temp, values[:, j], COLORS[j]) for j, axis in enumerate("xyz")]


def _stacked(rows: list[Row]) -> str:
    """The figures for a narrow terminal: each figure and unit on a line, its x, y, z values under it."""
    lines = []
    for row in rows:
        lines.append(f"{row.figure} ({row.unit})")
        lines.append("  " + "   ".join(f"{axis} {cell(value, unc)}" for axis, value, unc
                                       in zip("xyz", row.values, row.uncertainty, strict=True)))
    return "\n".join(lines)


class DatasheetScreen(StationScreen):
    """The datasheet table of ``--out`` under two plots: the scale factor against temperature and the
    turn-on repeatability at each soak (each plot says what it waits for where the file lacks it)."""

    BINDINGS = [Binding("escape", "back", "back"), Binding("s", "switch", "gyro/accel"),
                Binding("r", "reload", "read again")]
    DEFAULT_CSS = """
    DatasheetScreen #plots { height: 1fr; min-height: 8; }
    DatasheetScreen PlotextPlot { width: 1fr; height: 1fr; }
    DatasheetScreen #table-box { height: 1fr; min-height: 6; border: round $secondary; padding: 0 1; }
    """

    def compose(self) -> ComposeResult:
        """The two plots, the table under them, the keys."""
        yield Header()
        with Horizontal(id="plots"):
            yield PlotextPlot(id="scale-plot")
            yield PlotextPlot(id="turn-on-plot")
        with VerticalScroll(id="table-box"):
            yield Static("", id="table")
        yield Footer()

    def on_mount(self) -> None:
        """Read ``--out`` and show it, the gyroscope's plots first."""
        self.title = "imu-station · datasheet"
        self.triad = "gyro"
        self.action_reload()

    def action_switch(self) -> None:
        """Plot the other triad."""
        self.triad = "accel" if self.triad == "gyro" else "gyro"
        self.action_reload()

    def action_reload(self) -> None:
        """Read ``--out`` again (a campaign may have written it meanwhile) and redraw."""
        out = self.station.config.out
        table = self.query_one("#table", Static)
        scale_plot = self.query_one("#scale-plot", PlotextPlot)
        turn_on_plot = self.query_one("#turn-on-plot", PlotextPlot)
        params: ParamsFile | None = None
        text = Text()
        if out is None:
            text.append("No parameter file: start the TUI with --out FILE to see its datasheet.\n")
        elif not out.exists():
            text.append(f"{out} does not exist yet: calibrate the unit, or give --out the file of a campaign "
                        "(RUN_DIR/files/params.yaml).\n")
        else:
            try:
                params = ParamsFile.load(out)
            except StationError as exc:
                text.append(f"{exc}\n")
        name, unit, _ = TRIADS[self.triad]
        # An empty plot draws no title: what it lacks is said above the table.
        for plot, series, title, xlabel, ylabel, missing in (
                (scale_plot, _scale_series(params, self.triad) if params is not None else [],
                 "scale factor change", "temperature (degC)", "ppm", "no calibration across temperature"),
                (turn_on_plot, _turn_on_series(params, self.triad) if params is not None else [],
                 "turn-on repeatability", "soak (degC)", unit, "no campaign turn-ons")):
            if not draw(plot, series, title=f"{name}: {title}", xlabel=xlabel, ylabel=ylabel):
                text.append(f"{name}: {missing} to plot\n", style="italic")
        if params is not None:
            rows = datasheet_rows(params.to_dict())
            text.append(f"{out}\n", style="bold")
            if not rows:
                text.append("the file holds no figure a datasheet gives")
            else:
                # The sources ("measured by") are in the CLI's table; here the table if it fits, else each
                # figure over its values.
                tabled = format_table(rows, sources=False)
                fits = max(len(line) for line in tabled.splitlines()) <= self.size.width - SIDE_COLUMNS
                text.append(tabled if fits else _stacked(rows))
        table.update(text)

    def on_resize(self, event: Resize) -> None:
        """The table follows the width (a table where it fits)."""
        super().on_resize(event)
        self.call_after_refresh(self.action_reload)

    def action_back(self) -> None:
        """Escape: the live view with a unit connected, else the connect screen."""
        if self.station.session is not None:
            self.station.show("live")
        else:
            from station.tui.screens.connect import ConnectScreen

            self.app.switch_screen(ConnectScreen())

