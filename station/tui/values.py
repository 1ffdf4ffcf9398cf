"""The live view's values panel: the latest values under the header "x y z unit" and the link's line,
drawn straight into textual strips.

The panel is redrawn ten times a second. As a ``Static`` holding a rich renderable, each frame went
through textual's visual pipeline (measuring, rendering to segments, splitting and cropping lines): a
third of the live view's CPU on the event loop. Here a frame is a few strips made from the cells.
"""

from __future__ import annotations

from rich.segment import Segment
from rich.style import Style
from rich.text import Text
from textual.geometry import Size
from textual.strip import Strip
from textual.widget import Widget

HEADER = ("", "x", "y", "z", "unit")
BOLD = Style(bold=True)


class ValuesPanel(Widget):
    """Rows of cells under :data:`HEADER` (each column right-justified, two spaces either side, the header
    bold, as a rich Table without a box would show them), then the link's line, wrapped to the width; or
    a message in their place (:meth:`say`)."""

    DEFAULT_CSS = "ValuesPanel { height: auto; }"

    def __init__(self, message: str, *, id: str | None = None) -> None:  # noqa: A002 (textual's)
        super().__init__(id=id)
        self._rows: list[tuple[str, ...]] = []
        self._widths = [len(cell) for cell in HEADER]
        self._link = Text()
        self._message: Text | None = Text(message)
        self._lines: list[Strip] | None = None
        self._drawn_width = -1
        self._shape: tuple[int, int, int] | None = None

    def show(self, rows: list[tuple[str, ...]], link: Text) -> None:
        """Show ``rows`` (cells as :data:`HEADER`) and the link's line ``link``; the screen is laid out again
        only when the number of lines may change."""
        widths = [max(len(cells[j]) for cells in (HEADER, *rows)) for j in range(len(HEADER))]
        shape = (len(rows), sum(widths), link.cell_len)
        layout = shape != self._shape or self._message is not None
        self._rows, self._link, self._message, self._shape = rows, link, None, shape
        self._widths = widths
        self._lines = None
        self.refresh(layout=layout)

    def say(self, message: Text) -> None:
        """Show ``message`` in place of the values (the link failed)."""
        self._message, self._shape, self._lines = message, None, None
        self.refresh(layout=True)

    def get_content_height(self, container: Size, viewport: Size, width: int) -> int:
        """As many lines as the drawing at ``width`` has."""
        return len(self._draw(width))

    def render_line(self, y: int) -> Strip:
        """Line ``y`` of the drawing (drawn when the values or the width changed)."""
        width = self.size.width
        if self._lines is None or self._drawn_width != width:
            self._lines, self._drawn_width = self._draw(width), width
        return self._lines[y] if 0 <= y < len(self._lines) else Strip.blank(width)

    def _wrapped(self, text: Text, width: int) -> list[Strip]:
        console = self.app.console
        if text.cell_len <= width:
            return [Strip(list(text.render(console)))]
        return [Strip(list(line.render(console))) for line in text.wrap(console, max(1, width))]

    def _draw(self, width: int) -> list[Strip]:
        if self._message is not None:
            return [line.crop_extend(0, width, None) for line in self._wrapped(self._message, width)]
        lines = []
        for i, cells in enumerate((HEADER, *self._rows)):
            style = BOLD if i == 0 else None
            segments = []
            for cell, w in zip(cells, self._widths, strict=True):
                segments.append(Segment("  " + cell.rjust(w) + "  ", style))
            lines.append(Strip(segments))
        lines += self._wrapped(self._link, width)
        return [line.crop_extend(0, width, None) for line in lines]
