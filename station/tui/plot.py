"""A small braille plot for the terminal: several series, linear or logarithmic axes.

Each character cell holds 2 x 4 dots (Unicode braille, U+2800 + dot bits), so a plot of
W x H cells has 2W x 4H points. Textual has no plot widget; this is the ADEV and the
temperature plot of the TUI.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from rich.text import Text

# Dot bit of (column 0..1, row 0..3) in a braille cell.
_DOT_BITS = ((0x01, 0x08), (0x02, 0x10), (0x04, 0x20), (0x40, 0x80))


@dataclass(frozen=True)
class Series:
    """One curve of a braille plot: its name, x and y values and colour style."""

    name: str
    x: np.ndarray
    y: np.ndarray
    style: str = "white"


def _scale(v: np.ndarray, log: bool) -> np.ndarray:
    v = np.asarray(v, float)
    if log:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(v > 0, np.log10(v), np.nan)
    return v


def _fmt(v: float, log: bool) -> str:
    value = 10**v if log else v
    if value == 0 or not math.isfinite(value):
        return "0"
    return f"{value:.0e}" if log or abs(value) >= 1e4 or abs(value) < 1e-2 else f"{value:.3g}"


def braille_plot(series: Sequence[Series], width: int = 60, height: int = 14, logx: bool = False,
                 logy: bool = False, xlabel: str = "", ylabel: str = "") -> Text:
    """The series drawn as dots in a ``width`` x ``height`` cell canvas, with axis extents and a legend.

    Points that are not finite (or not positive on a log axis) are left out.
    """
    xs = [_scale(s.x, logx) for s in series]
    ys = [_scale(s.y, logy) for s in series]
    finite = [np.isfinite(x) & np.isfinite(y) for x, y in zip(xs, ys, strict=True)]
    all_x = np.concatenate([x[f] for x, f in zip(xs, finite, strict=True)] or [np.zeros(0)])
    all_y = np.concatenate([y[f] for y, f in zip(ys, finite, strict=True)] or [np.zeros(0)])
    out = Text()
    if ylabel:
        out.append(ylabel + "\n", style="bold")
    if not len(all_x):
        out.append("(no data yet)\n".rjust(width // 2 + 8), style="dim")
        return out
    x0, x1 = float(all_x.min()), float(all_x.max())
    y0, y1 = float(all_y.min()), float(all_y.max())
    if x1 == x0:
        x0, x1 = x0 - 0.5, x1 + 0.5
    if y1 == y0:
        y0, y1 = y0 - 0.5, y1 + 0.5
    bits = np.zeros((height, width), dtype=np.int32)
    owner = np.full((height, width), -1, dtype=np.int32)
    for k, (x, y, f) in enumerate(zip(xs, ys, finite, strict=True)):
        px = np.clip(((x[f] - x0) / (x1 - x0) * (2 * width - 1)).round().astype(int), 0, 2 * width - 1)
        py = np.clip(((y1 - y[f]) / (y1 - y0) * (4 * height - 1)).round().astype(int), 0, 4 * height - 1)
        for cx, cy in zip(px, py, strict=True):
            row, col = cy // 4, cx // 2
            bits[row, col] |= _DOT_BITS[cy % 4][cx % 2]
            owner[row, col] = k
    label_w = 8
    for row in range(height):
        if row == 0:
            label = _fmt(y1, logy)
        elif row == height - 1:
            label = _fmt(y0, logy)
        else:
            label = ""
        out.append(f"{label:>{label_w}} ┤" if label else " " * label_w + " │", style="dim")
        for col in range(width):
            b = int(bits[row, col])
            out.append(chr(0x2800 + b) if b else " ", style=series[owner[row, col]].style if b else "")
        out.append("\n")
    out.append(" " * label_w + " └" + "─" * width + "\n", style="dim")
    left, right = _fmt(x0, logx), _fmt(x1, logx)
    out.append(" " * (label_w + 2) + left + " " * max(1, width - len(left) - len(right)) + right + "\n",
               style="dim")
    if xlabel:
        out.append(" " * (label_w + 2) + xlabel.center(width) + "\n", style="dim")
    for s in series:
        out.append(" " * (label_w + 2) + "⣿ ", style=s.style)
        out.append(s.name + "\n")
    return out
