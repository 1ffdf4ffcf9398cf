"""The fleet report's chart per measurement, written as SVG directly: a histogram against the limits
beside the individuals control chart.

Matplotlib takes about 0.2 s a figure, so thirty measurements over 10,000 records would take more
than the report's whole budget (5 s); these two panels are simple enough to write as SVG elements,
in matplotlib's default look (its colours, DejaVu Sans, light grid, ticks at its steps) so they
sit beside the station's other plots without a seam. A long series is
drawn through per-pixel minimum and maximum, which looks the same as every point.
"""

from __future__ import annotations

import math
from html import escape

import numpy as np

BLUE, RED, GREY, DARK = "#1f77b4", "#d62728", "#a6a6a6", "#333333"
WIDTH, HEIGHT = 1000, 250
TOP, BOTTOM = 28, 212
HIST = (70, 470)
CHART = (560, 985)
COLUMNS = 425  # the chart's width in SVG units: one minimum-maximum pair per column
MAX_DOTS = 400  # up to this many runs each point is drawn as a dot too


def _ticks(lo: float, hi: float, most: int = 6) -> np.ndarray:
    """Tick positions inside [lo, hi] at a 1, 2, 2.5 or 5 times a power of ten step, at most ``most``
    of them (the steps matplotlib's ``MaxNLocator`` picks; importing matplotlib would cost more than
    drawing every chart)."""
    raw = (hi - lo) / (most - 1)
    scale = 10.0 ** math.floor(math.log10(raw))
    step = next(m * scale for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * scale >= raw)
    first = math.ceil(lo / step) * step
    ticks = np.arange(first, hi + 1e-9 * step, step)
    return np.where(np.abs(ticks) < 1e-12 * step, 0.0, ticks)  # a clean zero, not -1e-17


def _fmt(v: float) -> str:
    return f"{v:.6g}"


class _Panel:
    """A panel's scales: data to SVG coordinates, y down."""

    def __init__(self, x: tuple[int, int], xlim: tuple[float, float], ylim: tuple[float, float]):
        self.x0, self.x1 = x
        self.xlim, self.ylim = xlim, ylim

    def sx(self, v: np.ndarray | float) -> np.ndarray | float:
        lo, hi = self.xlim
        return self.x0 + (np.asarray(v) - lo) / (hi - lo) * (self.x1 - self.x0)

    def sy(self, v: np.ndarray | float) -> np.ndarray | float:
        lo, hi = self.ylim
        return BOTTOM - (np.asarray(v) - lo) / (hi - lo) * (BOTTOM - TOP)

    def frame(self, title: str, xlabel: str) -> list[str]:
        """Grid, ticks with labels, the box and the title."""
        out = []
        for t in _ticks(*self.xlim):
            x = float(self.sx(t))
            out.append(f'<line x1="{x:.1f}" y1="{TOP}" x2="{x:.1f}" y2="{BOTTOM}" stroke="#b0b0b0" '
                       'stroke-opacity="0.3" stroke-width="0.8"/>')
            out.append(f'<text x="{x:.1f}" y="{BOTTOM + 14}" text-anchor="middle">{_fmt(t)}</text>')
        for t in _ticks(*self.ylim):
            y = float(self.sy(t))
            out.append(f'<line x1="{self.x0}" y1="{y:.1f}" x2="{self.x1}" y2="{y:.1f}" stroke="#b0b0b0" '
                       'stroke-opacity="0.3" stroke-width="0.8"/>')
            out.append(f'<text x="{self.x0 - 4}" y="{y + 3.5:.1f}" text-anchor="end">{_fmt(t)}</text>')
        out.append(f'<rect x="{self.x0}" y="{TOP}" width="{self.x1 - self.x0}" height="{BOTTOM - TOP}" '
                   'fill="none" stroke="black" stroke-width="0.8"/>')
        out.append(f'<text x="{(self.x0 + self.x1) / 2:.1f}" y="{TOP - 8}" text-anchor="middle" '
                   f'font-size="12">{escape(title)}</text>')
        out.append(f'<text x="{(self.x0 + self.x1) / 2:.1f}" y="{BOTTOM + 30}" text-anchor="middle">'
                   f'{escape(xlabel)}</text>')
        return out

    def hline(self, y: float, colour: str, dash: str, width: float = 1.0) -> str:
        """A horizontal line across the panel at data ``y``."""
        sy = float(self.sy(y))
        return (f'<line x1="{self.x0}" y1="{sy:.1f}" x2="{self.x1}" y2="{sy:.1f}" stroke="{colour}" '
                f'stroke-width="{width}" stroke-dasharray="{dash}"/>')

    def vline(self, x: float, colour: str, dash: str, width: float = 1.2) -> str:
        """A vertical line across the panel at data ``x``."""
        sx = float(self.sx(x))
        return (f'<line x1="{sx:.1f}" y1="{TOP}" x2="{sx:.1f}" y2="{BOTTOM}" stroke="{colour}" '
                f'stroke-width="{width}" stroke-dasharray="{dash}"/>')


def _span(values: np.ndarray, extra: list[float]) -> tuple[float, float]:
    """The data range with the limits in view and matplotlib's 5 % margin."""
    pool = [float(v) for v in extra if math.isfinite(v)]
    if values.size:
        pool += [float(values.min()), float(values.max())]
    lo, hi = (min(pool), max(pool)) if pool else (0.0, 1.0)
    if hi <= lo:
        lo, hi = lo - 0.5 * (abs(lo) or 1.0), hi + 0.5 * (abs(hi) or 1.0)
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad


def _decimated(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices and values of a per-column minimum-maximum envelope of ``y`` (all points when short)."""
    n = len(y)
    if n <= 2 * COLUMNS:
        return np.arange(n, dtype=float), y
    edges = np.linspace(0, n, COLUMNS + 1).astype(int)
    xs, ys = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        part = y[a:b]
        i, j = a + int(np.argmin(part)), a + int(np.argmax(part))
        for k in sorted((i, j)):
            xs.append(k)
            ys.append(y[k])
    return np.array(xs, dtype=float), np.array(ys)


def chart_svg(values: np.ndarray, beyond: np.ndarray, low: float | None, high: float | None,
              control: tuple[float, float, float], unit: str) -> str:
    """Histogram (limits dashed red) and individuals chart (centre solid, control limits dotted, beyond x).

    Parameters
    ----------
    values : ndarray, (N,)
        The measurement in time order, in ``unit``.
    beyond : ndarray of bool, (N,)
        The points beyond the control limits.
    low, high : float or None
        The plan's limits.
    control : (float, float, float)
        Centre line, lower and upper control limits (NaN when undefined).
    unit : str
        The values' unit, for the labels.

    Returns
    -------
    str
        An ``<svg>`` element sized by the page (viewBox).
    """
    values = np.asarray(values, dtype=float)
    finite = values[np.isfinite(values)]
    limits = [v for v in (low, high) if v is not None]
    out = [f'<svg class="plot" viewBox="0 0 {WIDTH} {HEIGHT}" '
           'preserveAspectRatio="xMidYMid meet" font-family="DejaVu Sans, Arial, sans-serif" font-size="10">',
           f'<rect width="{WIDTH}" height="{HEIGHT}" fill="white"/>']
    xlim = _span(finite, limits)
    counts, edges = np.histogram(finite, bins=min(40, max(5, int(np.sqrt(max(len(finite), 1))))), range=xlim)
    hist = _Panel(HIST, xlim, (0.0, max(1.0, float(counts.max()) * 1.05) if counts.size else 1.0))
    out += hist.frame(f"distribution ({unit or 'ratio'}); limits dashed", unit or "ratio")
    for c, a, b in zip(counts, edges[:-1], edges[1:], strict=True):
        if c:
            x0, x1, y = float(hist.sx(a)), float(hist.sx(b)), float(hist.sy(c))
            out.append(f'<rect x="{x0:.1f}" y="{y:.1f}" width="{max(x1 - x0, 0.5):.1f}" '
                       f'height="{BOTTOM - y:.1f}" fill="{BLUE}" fill-opacity="0.8"/>')
    out += [hist.vline(v, RED, "5 3") for v in limits]
    center, lcl, ucl = control
    ylim = _span(finite, [*limits, lcl, ucl])
    n = len(values)
    chart = _Panel(CHART, (-0.5, max(n - 0.5, 0.5)), ylim)
    out += chart.frame(f"individuals chart, time order; control limits dotted; {int(beyond.sum())} "
                       "beyond (x)", "run")
    xs, ys = _decimated(values)
    keep = np.isfinite(ys)
    points = " ".join(f"{x:.1f},{y:.1f}" for x, y in zip(chart.sx(xs[keep]), chart.sy(ys[keep]), strict=True))
    out.append(f'<polyline points="{points}" fill="none" stroke="{BLUE}" stroke-width="0.8" '
               'stroke-linejoin="round"/>')
    if n <= MAX_DOTS:
        out += [f'<circle cx="{x:.1f}" cy="{y:.1f}" r="1.8" fill="{BLUE}"/>'
                for x, y in zip(chart.sx(xs[keep]), chart.sy(ys[keep]), strict=True)]
    out += [chart.hline(v, RED, "5 3") for v in limits]
    if math.isfinite(ucl):
        out += [chart.hline(center, DARK, "none"), chart.hline(lcl, DARK, "2 2"),
                chart.hline(ucl, DARK, "2 2")]
    for k in np.flatnonzero(beyond):
        x, y = float(chart.sx(k)), float(chart.sy(values[k]))
        out.append(f'<path d="M{x - 3:.1f},{y - 3:.1f}L{x + 3:.1f},{y + 3:.1f}M{x - 3:.1f},{y + 3:.1f}'
                   f'L{x + 3:.1f},{y - 3:.1f}" stroke="{RED}" stroke-width="1.5"/>')
    out.append("</svg>")
    return "\n".join(out)
