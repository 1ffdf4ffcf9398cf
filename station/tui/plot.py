"""The TUI's plots: curves drawn in a textual-plotext widget, with axes, ticks, labels and a legend.

Every plot of the TUI (the live traces, the Allan deviation with its fitted lines, the temperature
sweep) is a :class:`~textual_plotext.PlotextPlot` redrawn with :func:`draw`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from textual_plotext import PlotextPlot

# Plotext's markers: measured points in braille dots (fine), fitted lines in small dots.
DATA_MARKER = "braille"
FIT_MARKER = "dot"
MANTISSAS = (1.0, 2.0, 5.0)


@dataclass(frozen=True)
class Series:
    """One curve: its name (the legend), x and y values, colour, and whether it is a fitted line."""

    name: str
    x: np.ndarray
    y: np.ndarray
    color: str = "white"
    fitted: bool = False


def _finite(series: Series, logx: bool, logy: bool) -> tuple[np.ndarray, np.ndarray]:
    x, y = np.asarray(series.x, float), np.asarray(series.y, float)
    keep = np.isfinite(x) & np.isfinite(y)
    if logx:
        keep &= x > 0
    if logy:
        keep &= y > 0
    return x[keep], y[keep]


def log_ticks(low: float, high: float) -> tuple[list[float], list[str]]:
    """Tick positions (log10) and labels (values) for a log axis from ``low`` to ``high`` (log10).

    Decades; 1, 2, 5 of each decade where the axis spans less than two.

    Parameters
    ----------
    low, high : float
        The axis' extent, log10 of the values.

    Returns
    -------
    tuple of (list of float, list of str)
    """
    decades = range(int(np.floor(low)), int(np.ceil(high)) + 1)
    mantissas = MANTISSAS if high - low < 2 else (1.0,)
    values = [m * 10.0**k for k in decades for m in mantissas]
    inside = [v for v in values if low - 1e-9 <= np.log10(v) <= high + 1e-9]
    return [float(np.log10(v)) for v in inside], [f"{v:g}" for v in inside]


def draw(widget: PlotextPlot, series: Sequence[Series], *, title: str, xlabel: str, ylabel: str,
         logx: bool = False, logy: bool = False) -> int:
    """Redraw ``widget`` with ``series``; points that are not finite (or not positive on a log axis)
    are left out.

    Parameters
    ----------
    widget : PlotextPlot
        The plot to redraw.
    series : sequence of Series
        The curves, drawn in order (a fitted line over its data, when given after it).
    title, xlabel, ylabel : str
        The plot's title and axis labels (with units).
    logx, logy : bool
        Logarithmic axes.

    Returns
    -------
    int
        The number of curves drawn (0: the plot says it waits for data).
    """
    plt = widget.plt
    plt.clear_figure()
    plt.title(title)
    plt.xlabel(xlabel)
    plt.ylabel(ylabel)
    # Log axes are drawn as log10 on linear ones with value labels: plotext's own log scale
    # transforms the data in place, so a second render (any resize) takes the log of a log.
    extents: list[tuple[np.ndarray, np.ndarray]] = []
    drawn = 0
    for s in series:
        x, y = _finite(s, logx, logy)
        if len(x) < 2:
            continue
        x, y = (np.log10(x) if logx else x), (np.log10(y) if logy else y)
        extents.append((x, y))
        plt.plot(x.tolist(), y.tolist(), label=s.name, color=s.color,
                 marker=FIT_MARKER if s.fitted else DATA_MARKER)
        drawn += 1
    if not drawn:
        plt.title(f"{title} (waiting for data)")
    else:
        xs = np.concatenate([x for x, _ in extents])
        ys = np.concatenate([y for _, y in extents])
        if logx:
            plt.xticks(*log_ticks(float(xs.min()), float(xs.max())))
        if logy:
            plt.yticks(*log_ticks(float(ys.min()), float(ys.max())))
    widget.refresh()
    return drawn
