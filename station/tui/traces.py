"""The live view's traces: the last samples of a triad drawn in braille, each axis in a band of its own
with its own scale, on a shared time axis.

A trace is drawn with numpy straight into textual strips (:class:`TracePlot`): no plotext canvas, no ANSI
text decoded and restyled. A 1 kHz unit's trace costs about a millisecond this way against 25-40 ms
through plotext (issue 30), and an axis never shares a scale with another: an accelerometer's x and y near
0 are not flattened against z's 9.8 (issue 31).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from rich.segment import Segment
from rich.style import Style
from textual.events import Resize
from textual.geometry import Size
from textual.strip import Strip
from textual.widget import Widget

# Braille dots: bit of the dot at (column, row) of a 2x4 cell, rows from the top.
_DOT_BITS = np.array([[0x01, 0x02, 0x04, 0x40], [0x08, 0x10, 0x20, 0x80]], dtype=np.int64)
_BRAILLE = 0x2800
GUTTER_MIN = 9  # the widest tick label and the axis' name


def scale_labels(low: float, high: float) -> tuple[str, str]:
    """The labels of a band's top (``high``) and bottom (``low``), with as many decimals as tell them
    apart (at least three significant digits of their difference), the same width.

    Parameters
    ----------
    low, high : float
        The band's extent.

    Returns
    -------
    tuple of str
        The labels of ``high`` and ``low``.
    """
    span = abs(high - low)
    decimals = 2 if span <= 0 or not math.isfinite(span) else min(6, max(0, 2 - math.floor(math.log10(span))))
    top, bottom = f"{high:+.{decimals}f}", f"{low:+.{decimals}f}"
    width = max(len(top), len(bottom))
    return top.rjust(width), bottom.rjust(width)


def band_extent(values: np.ndarray) -> tuple[float, float]:
    """The extent of a band showing ``values``: their range with a twentieth of it either side, or a
    small fixed span around a constant value (so a still axis is a flat line in the middle)."""
    finite = values[np.isfinite(values)]
    if not len(finite):
        return -1.0, 1.0
    low, high = float(finite.min()), float(finite.max())
    span = high - low
    if span <= 1e-12 * max(1.0, abs(high)):
        pad = max(1e-6, 1e-3 * abs(high))
        return low - pad, high + pad
    return low - span / 20, high + span / 20


def braille_rows(t: np.ndarray, y: np.ndarray, t_range: tuple[float, float], y_range: tuple[float, float],
                 width: int, height: int) -> list[str]:
    """The line through (t, y) in braille, ``width`` x ``height`` cells, one string per row (top first).

    Each dot column shows the samples that fall in it, joined to the column before, so a noisy trace
    with many samples per column is a continuous band and a sparse one a continuous line.

    Parameters
    ----------
    t, y : ndarray
        The samples, in time order; samples that are not finite are left out.
    t_range, y_range : tuple of float
        The extents mapped to the left and right edges, and the bottom and top edges.
    width, height : int
        Cells.

    Returns
    -------
    list of str
    """
    keep = np.isfinite(t) & np.isfinite(y)
    t, y = t[keep], y[keep]
    cols, rows = 2 * width, 4 * height
    blank = " " * width
    if width <= 0 or height <= 0:
        return [""] * max(0, height)
    if not len(t):
        return [blank] * height
    (t0, t1), (y0, y1) = t_range, y_range
    px = np.clip(((t - t0) / ((t1 - t0) or 1.0) * (cols - 1)).round(), 0, cols - 1).astype(np.int64)
    py = np.clip(((y - y0) / ((y1 - y0) or 1.0) * (rows - 1)).round(), 0, rows - 1).astype(np.int64)
    # Per dot column: the lowest and highest dot of its samples, reached from the last dot before it.
    starts = np.flatnonzero(np.r_[True, px[1:] != px[:-1]])
    lo = np.minimum.reduceat(py, starts)
    hi = np.maximum.reduceat(py, starts)
    previous = py[starts[1:] - 1]
    lo[1:] = np.minimum(lo[1:], previous)
    hi[1:] = np.maximum(hi[1:], previous)
    column = px[starts]
    dots = np.zeros((rows, cols), dtype=bool)  # row 0 at the bottom
    level = np.arange(rows)[:, None]
    dots[:, column] = (level >= lo) & (level <= hi)
    # Columns skipped between samples (fewer samples than columns): the line across them.
    if len(column) > 1 and np.any(np.diff(column) > 1):
        gaps = np.flatnonzero(np.diff(column) > 1)
        for g in gaps.tolist():
            c0, c1 = int(column[g]), int(column[g + 1])
            v0, v1 = int(py[starts[g + 1] - 1]), int(py[starts[g + 1]])
            between = np.arange(c0 + 1, c1)
            at = np.round(v0 + (v1 - v0) * (between - c0) / (c1 - c0)).astype(np.int64)
            dots[at, between] = True
    cells = dots[::-1].reshape(height, 4, width, 2)  # (cell row, dot row, cell column, dot column)
    codes = _BRAILLE + np.einsum("rjcd,dj->rc", cells.astype(np.int64), _DOT_BITS)
    codes[codes == _BRAILLE] = ord(" ")  # a cell without dots is blank, as in the other plots
    return ["".join(map(chr, row)) for row in codes.tolist()]


class TracePlot(Widget):
    """A triad's last samples: a title, one band per axis (its name, its scale, its trace in its colour),
    the time axis. :meth:`show` gives it data; it is drawn when textual asks for its lines."""

    DEFAULT_CSS = "TracePlot { width: 1fr; height: 1fr; }"

    def __init__(self, title: str, unit: str, *, id: str | None = None) -> None:  # noqa: A002 (textual's)
        super().__init__(id=id)
        self.title = title
        self.unit = unit
        self._t = np.empty(0)
        self._values = np.empty((0, 0))
        self._names: Sequence[str] = ()
        self._colors: Sequence[str] = ()
        self._lines: list[Strip] | None = None
        self._drawn_size: Size | None = None
        self.drawings = 0  # how many times the traces were drawn (the tests count frames)

    def show(self, t: np.ndarray, values: np.ndarray, names: Sequence[str], colors: Sequence[str]) -> None:
        """Draw ``values`` (n, axes) against ``t`` (seconds), the axes named ``names`` in ``colors``."""
        self._t, self._values = np.asarray(t, float), np.asarray(values, float)
        self._names, self._colors = tuple(names), tuple(colors)
        self._lines = None
        self.refresh()

    def on_resize(self, event: Resize) -> None:
        """Drawn again at the new size."""
        self._lines = None

    def render_line(self, y: int) -> Strip:
        """Line ``y`` of the drawing (drawn when the data or the size changed)."""
        size = self.size
        if self._lines is None or self._drawn_size != size:
            self._lines = self._draw(size.width, size.height)
            self._drawn_size = size
            self.drawings += 1
        if 0 <= y < len(self._lines):
            return self._lines[y]
        return Strip.blank(size.width)

    def _draw(self, width: int, height: int) -> list[Strip]:
        bold, dim = Style(bold=True), Style(dim=True)
        title = f"{self.title} ({self.unit})"
        axes = self._values.shape[1] if self._values.ndim == 2 else 0
        if not len(self._t) or axes == 0:
            title += " (waiting for data)"
        lines = [Strip([Segment(title.center(width)[:width], bold)])]
        body = height - 2  # the title above, the time axis below
        if axes == 0 or body < axes or not len(self._t):
            return lines + [Strip.blank(width)] * max(0, height - 1)
        t = self._t
        t_range = (float(np.nanmin(t)), float(np.nanmax(t)))
        extents = [band_extent(self._values[:, j]) for j in range(axes)]
        labels = [scale_labels(*extent) for extent in extents]
        names = [self._names[j] if j < len(self._names) else "" for j in range(axes)]
        gutter = max(GUTTER_MIN, *(len(n) + 1 + len(top) for n, (top, _) in zip(names, labels, strict=True)))
        plot_width = max(1, width - gutter - 2)  # the tick, and a blank column before the next plot
        heights = [body // axes + (1 if j < body % axes else 0) for j in range(axes)]
        for j in range(axes):
            color = Style(color=self._colors[j % len(self._colors)])
            rows = braille_rows(t, self._values[:, j], t_range, extents[j], plot_width, heights[j])
            top, bottom = labels[j]
            for r, row in enumerate(rows):
                if r == 0:
                    name, label, tick = names[j], top, "┤"
                elif r == len(rows) - 1:
                    name, label, tick = "", bottom, "┤"
                else:
                    name, label, tick = "", "", "│"
                pad = gutter - len(name) - len(label)
                lines.append(Strip([Segment(name, color + bold), Segment(" " * pad + label, dim),
                                    Segment(tick, dim), Segment(row, color)]))
        left, right = f"{t_range[0]:.2f}", f"{t_range[1]:.2f}"
        middle = "time (s)"
        space = plot_width - len(left) - len(right)
        if space >= len(middle) + 2:
            axis = left + middle.center(space) + right
        else:
            axis = (left + " " * max(1, plot_width - len(left) - len(right)) + right)[:plot_width]
        lines.append(Strip([Segment(" " * (gutter + 1) + axis, dim)]))
        return [line.crop_extend(0, width, None) for line in lines]
