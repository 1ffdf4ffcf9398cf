"""Matplotlib figures as inline SVG for the HTML reports, drawn in the style of the station's PNGs.

The figure is rendered by matplotlib's SVG backend without pyplot (no global state, no GUI
backend), text kept as text (``svg.fonttype none``: small, searchable, printable), and the SVG's
fixed size replaced by a ``viewBox`` so the page's CSS sets its width on screen and on paper.
"""

from __future__ import annotations

import io
import re
from typing import Any

_SIZE = re.compile(r'<svg([^>]*?) width="[^"]*" height="[^"]*"')


def new_figure(width_in: float, height_in: float, rows: int = 1, cols: int = 1) -> tuple[Any, Any]:
    """A figure of ``rows`` x ``cols`` panels (an ndarray of Axes, always 2-D) on the SVG canvas.

    Parameters
    ----------
    width_in, height_in : float
        Size in inches (the SVG's aspect ratio; the page scales it).
    rows, cols : int
        Panels.

    Returns
    -------
    (Figure, ndarray of Axes)
    """
    from matplotlib.backends.backend_svg import FigureCanvasSVG
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    FigureCanvasSVG(fig)
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def to_svg(fig: Any) -> str:
    """The figure as an ``<svg>`` element for inline use: no XML prologue, scalable (viewBox kept).

    Parameters
    ----------
    fig : matplotlib.figure.Figure

    Returns
    -------
    str
        The ``<svg ...>...</svg>`` text.
    """
    import matplotlib

    buf = io.StringIO()
    # ids stay random (no svg.hashsalt): several SVGs share one page and their clip paths must not clash
    with matplotlib.rc_context({"svg.fonttype": "none"}):
        # no <metadata>: its RDF names web addresses, and a page that prints offline wants none of them
        fig.savefig(buf, format="svg", metadata={"Creator": None, "Date": None, "Format": None, "Type": None})
    text = buf.getvalue()
    text = text[text.index("<svg"):]
    # The page sets the width; a fixed size in points would overflow a phone or an A4 margin.
    return _SIZE.sub(r'<svg\1 class="plot" preserveAspectRatio="xMidYMid meet"', text, count=1)
