"""The live view's traces (station.tui.traces): each axis on its own scale, so an accelerometer's x and y
near 0 are not drawn flat on z's 9.8 axis (issue 31); the braille line itself; drawn only while shown."""

from __future__ import annotations

import asyncio
import re

import numpy as np
import pytest
from textual.screen import Screen
from tui_helpers import screen_text, stop_reader, wait_for

from station.tui.app import StationApp
from station.tui.config import TuiConfig
from station.tui.messages import Snapshot
from station.tui.traces import TracePlot, band_extent, braille_rows, scale_labels

pytestmark = pytest.mark.timeout(120)
# A band's top or bottom row in the left plot: an optional axis name, the label, the tick.
_LABEL = re.compile(r"^\s*([xyz]?)\s*([+-]\d+\.\d+)┤")


def _tail() -> np.ndarray:
    t = np.arange(400) / 200.0
    return np.column_stack([t, 0.1 * np.sin(t), 0.2 * np.cos(t), 9.8 + 0.05 * np.sin(3 * t),
                            0.01 * np.sin(2 * t), -0.01 * np.cos(t), 0.002 * t, np.full_like(t, 25.0)])


async def _live_without_reader(pilot, app):
    await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
    await pilot.press("enter")
    screen = await wait_for(pilot, lambda: type(app.screen).__name__ == "LiveScreen" and app.screen, 10,
                            "the live view")
    await pilot.pause(0.3)
    await stop_reader(pilot, screen)
    return screen


def _accelerometer_scales(text: str) -> list[tuple[float, float]]:
    """(top, bottom) of each band of the accelerometer's plot (the screen's left half)."""
    labels = [float(m.group(2)) for row in text.splitlines() if (m := _LABEL.match(row))]
    return list(zip(labels[::2], labels[1::2], strict=False))


def _own_scales(scales: list[tuple[float, float]]) -> bool:
    """Each band spans its axis' own range (a twentieth either side), not z's 9.8 down to x's 0."""
    if len(scales) != 3:
        return False
    (x_top, x_bottom), (y_top, y_bottom), (z_top, z_bottom) = scales
    return (-0.02 < x_bottom < 0.0 and 0.09 < x_top < 0.12 and -0.11 < y_bottom < -0.09
            and 0.19 < y_top < 0.22 and 9.7 < z_bottom < 9.76 and 9.84 < z_top < 9.9)


def test_each_accelerometer_axis_is_drawn_on_its_own_scale():
    app = StationApp(TuiConfig(simulate=True, seed=1))
    seen: dict[str, object] = {}

    async def run() -> None:
        async with app.run_test(size=(100, 36)) as pilot:
            screen = await _live_without_reader(pilot, app)
            screen.post_message(Snapshot({"tail": _tail(), "stats": app.session.device.stats}))

            def scales_fit() -> bool:
                seen["text"] = screen_text(app)
                seen["scales"] = _accelerometer_scales(str(seen["text"]))
                return _own_scales(seen["scales"])  # type: ignore[arg-type]

            try:
                await wait_for(pilot, scales_fit, 10, "a scale of its own for each accelerometer axis")
            except AssertionError as exc:
                raise AssertionError(f"{exc}: scales {seen['scales']} on\n{seen['text']}") from None
            app.exit(0)

    asyncio.run(run())


def test_the_traces_are_drawn_only_while_the_live_view_is_shown():
    app = StationApp(TuiConfig(simulate=True, seed=1))

    async def run() -> None:
        async with app.run_test(size=(100, 36)) as pilot:
            screen = await _live_without_reader(pilot, app)
            plot = screen.query_one("#plot-acc", TracePlot)
            stats = app.session.device.stats
            screen.post_message(Snapshot({"tail": _tail(), "stats": stats}))
            await wait_for(pilot, lambda: plot.drawings, 10, "the traces")
            # Every line fills the plot's width exactly (a line a cell short shifted the next plot's first
            # character into its last column on a real terminal).
            for panel in (plot, screen.query_one("#values")):
                widths = {sum(seg.cell_length for seg in panel.render_line(y))
                          for y in range(panel.size.height)}
                assert widths == {panel.size.width}, (panel, widths)
            app.push_screen(Screen())  # a whole screen over the live view (the help is a modal: seen through)
            await wait_for(pilot, lambda: not screen.shown, 10, "a screen over the live view")
            drawn = plot.drawings
            later = _tail()
            later[:, 0] += 2.0
            screen.post_message(Snapshot({"tail": later, "stats": stats}))
            await pilot.pause(1.5)
            assert plot.drawings == drawn, "drawn while under another screen"
            app.pop_screen()
            # New samples came while hidden: drawn at once when shown again.
            await wait_for(pilot, lambda: screen.shown and plot.drawings > drawn, 10, "the traces again")
            app.exit(0)

    asyncio.run(run())


def test_braille_line_goes_from_corner_to_corner_and_a_constant_is_a_flat_line():
    t = np.linspace(0.0, 1.0, 50)
    rows = braille_rows(t, t, (0.0, 1.0), (0.0, 1.0), 10, 3)
    assert len(rows) == 3 and all(len(r) == 10 for r in rows)
    assert rows[2][0] != " " and rows[0][-1] != " "  # bottom left, top right
    assert rows[0][0] == " " and rows[2][-1] == " "
    flat = braille_rows(t, np.full(50, 9.81), (0.0, 1.0), band_extent(np.full(50, 9.81)), 10, 3)
    assert all(c != " " for c in flat[1]) and flat[0].strip() == "" and flat[2].strip() == ""
    # Fewer samples than dot columns: still one unbroken line.
    few = t[::10]
    sparse = braille_rows(few, few, (0.0, few[-1]), (0.0, few[-1]), 20, 4)
    assert all(any(row[c] != " " for row in sparse) for c in range(20))
    assert braille_rows(t, np.full(50, np.nan), (0.0, 1.0), (0.0, 1.0), 5, 2) == [" " * 5] * 2


def test_scale_labels_tell_top_and_bottom_apart():
    assert scale_labels(9.745, 9.855) == ("+9.855", "+9.745")
    top, bottom = scale_labels(-0.0107, 0.0048)
    assert top != bottom and len(top) == len(bottom)
