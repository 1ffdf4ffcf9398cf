"""The TUI's plots: curves drawn in a textual-plotext widget, with axes, ticks, labels and a legend.

Every plot of the TUI (the live traces, the Allan deviation with its fitted lines, the temperature
sweep) is a :class:`~textual_plotext.PlotextPlot` redrawn with :func:`draw`.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import plotext
import plotext._utility as _plotext_utility
from rich.style import Style
from rich.text import Span, Text
from textual.app import RenderResult
from textual_plotext import PlotextPlot

# Plotext's markers: measured points in braille dots (fine), fitted lines in small dots.
DATA_MARKER = "braille"
FIT_MARKER = "dot"
MANTISSAS = (1.0, 2.0, 5.0)


_PLOTEXT_GET_LINES = _plotext_utility.get_lines


def _get_lines(x: list, y: list, *other: list) -> list:
    """plotext's ``get_lines`` (the canvas points of the segments joining a curve's points), vectorised.

    plotext 5.3.2 joins every pair of points in Python, a list of points per segment: on a trace of
    400 noisy samples, tens of thousands of points, most of a drawing's 50-80 ms of CPU. The same points
    are made here with numpy (the same float operations: ``x0 + k * (x1 - x0) / (a - 1)`` truncated), each
    kept once; plotext keeps each point once anyway (``brush``, a set) before it draws, so the drawing is
    the same. Curves whose points are not all integers, or whose points differ in marker or colour, go
    to plotext's own.
    """
    n = len(x)
    if n < 2 or len(y) != n or any(len(o) != n for o in other) or \
            any(o.count(o[0]) != n for o in other if isinstance(o, list)) or \
            not all(type(v) is int for v in x) or not all(type(v) is int for v in y):
        return _PLOTEXT_GET_LINES(x, y, *other)
    xs, ys = np.asarray(x, np.int64), np.asarray(y, np.int64)
    dx, dy = np.diff(xs), np.diff(ys)
    steps = np.maximum(np.abs(dx), np.abs(dy))  # a - 1: points per segment, its last one left out
    seg = np.repeat(np.arange(n - 1), steps)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(steps) - steps, steps)
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = dx[seg] / steps[seg]
        sy = dy[seg] / steps[seg]
    px = np.trunc(xs[:-1][seg] + k * sx).astype(np.int64)
    py = np.trunc(ys[:-1][seg] + k * sy).astype(np.int64)
    px, py = np.append(px, xs[-1]), np.append(py, ys[-1])
    px, py = _once(px, py)
    xl = px.tolist()
    _UNIQUE.append(xl)  # plotext's brush, next, need not look for repeated points in these
    del _UNIQUE[:-8]
    return [xl, py.tolist(), *([o[0]] * len(px) for o in other)]


_PLOTEXT_BRUSH = _plotext_utility.brush
_UNIQUE: list[list] = []  # the x lists of the last curves of _get_lines: points each once


def _brush(*lists: list) -> list:
    """plotext's ``brush`` (the points each kept once, in a set's order), which has nothing to do on
    the points of :func:`_get_lines`: they are each once already."""
    first = lists[0] if lists else None
    if first is not None and any(first is seen for seen in _UNIQUE) and \
            all(len(other) == len(first) for other in lists):
        return list(lists)
    return _PLOTEXT_BRUSH(*lists)


def _once(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points (x, y) each kept once (in no particular order)."""
    x0, y0 = x.min(initial=0), y.min(initial=0)
    span = int(y.max(initial=0) - y0) + 1
    keys = np.unique((x - x0) * span + (y - y0))
    return keys // span + x0, keys % span + y0


_PLOTEXT_HD_GROUP = _plotext_utility.hd_group
_HD_BITS: dict[int, list[tuple[int, ...]]] = {}


def _hd_group(x: list, y: list, xf: list, yf: list) -> tuple:
    """plotext's ``hd_group`` (the canvas points gathered into characters of 2x2, 2x3 or 2x4 dots, each
    with the dots it shows), vectorised: the same characters, each once (plotext's order is a set's).
    Points that are not all integers, or with markers of different sizes, go to plotext's own."""
    n = len(x)
    if n == 0 or len(y) != n or len(xf) != n or len(yf) != n or xf.count(xf[0]) != n or \
            yf.count(yf[0]) != n or not all(type(v) is int for v in x) or not all(type(v) is int for v in y):
        return _PLOTEXT_HD_GROUP(x, y, xf, yf)
    fx, fy = int(xf[0]), int(yf[0])
    xs, ys = np.asarray(x, np.int64), np.asarray(y, np.int64)
    cx, cy = xs // fx, ys // fy
    bit = (fy - 1 - ys % fy) * fx + xs % fx  # plotext's dots matrix, rows reversed, flattened
    x0, y0 = cx.min(), cy.min()
    span = int(cy.max() - y0) + 1
    keys, where = np.unique((cx - x0) * span + (cy - y0), return_inverse=True)
    masks = np.zeros(len(keys), np.int64)
    np.bitwise_or.at(masks, where.ravel(), np.left_shift(1, bit))
    size = fx * fy
    table = _HD_BITS.get(size)
    if table is None:
        table = _HD_BITS[size] = [tuple((m >> b) & 1 for b in range(size)) for m in range(1 << size)]
    return ((keys // span + x0).tolist(), (keys % span + y0).tolist(), [table[m] for m in masks.tolist()])


if plotext.__version__ == "5.3.2":  # the version whose get_lines this one reproduces (pinned)
    _plotext_utility.get_lines = _get_lines
    _plotext_utility.hd_group = _hd_group
    _plotext_utility.brush = _brush


_SGR = re.compile(r"(\x1b\[[0-9;]*m)")
_RESET = "\x1b[0m"
_STYLES: dict[str, Style | None] = {}


def _style(codes: str) -> Style | None:
    """The style rich's ANSI decoder gives text after the escape sequences ``codes`` (cached)."""
    if codes not in _STYLES:
        spans = Text.from_ansi(codes + "x").spans
        _STYLES[codes] = spans[0].style if spans else None  # type: ignore[assignment]
    return _STYLES[codes]


def ansi_text(ansi: str) -> Text:
    """``Text.from_ansi(ansi)`` for plotext's output (256-colour SGR codes, each run closed by a reset):
    the same text and styles, made with a cache of the styles instead of decoding every code."""
    plain: list[str] = []
    spans: list[Span] = []
    at = 0
    codes = ""
    for token in _SGR.split(ansi):
        if not token:
            continue
        if token[0] == "\x1b":
            codes = "" if token == _RESET else codes + token
            continue
        style = _style(codes) if codes else None
        plain.append(token)
        end = at + len(token)
        if style is not None:
            if spans and spans[-1].end == at and spans[-1].style is style:  # one span for a run
                spans[-1] = Span(spans[-1].start, end, style)
            else:
                spans.append(Span(at, end, style))
        at = end
    return Text("".join(plain), spans=spans)


class FastPlot(PlotextPlot):
    """A :class:`~textual_plotext.PlotextPlot` whose drawing is turned into text with :func:`ansi_text`
    (rich's decoder was a fifth of a trace's CPU)."""

    def render(self) -> RenderResult:
        """What ``PlotextPlot.render`` draws, with :func:`ansi_text` for ``Text.from_ansi``."""
        self._plot.plotsize(self.size.width, self.size.height)
        self._plot._set_size(self.size.width, self.size.height)  # as PlotextPlot does (its issue 5)
        self._plot.theme(self._get_plotext_theme_name(self.app.theme))
        return ansi_text(self._plot.build())


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
