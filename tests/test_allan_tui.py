"""The TUI's Allan plot of a fitted model: each term its own line, the sum, the 68 % band and the valid range,
drawn in a headless app (Pilot); and the PNG plot of the same model."""

from __future__ import annotations

import asyncio

import numpy as np
from textual.app import App, ComposeResult
from textual_plotext import PlotextPlot
from tui_helpers import svg_rows

from mocks.truth import FLICKER_FLOOR, GM_ADEV_PEAK, NoiseGenerator, NoiseSpec
from station.engines.allan.deviation import allan_curve, integrate_rates
from station.engines.allan.fit import identify_noise
from station.plots.allan import render_png
from station.tui.plot import draw
from station.tui.screens.allan import AXES, adev_series


def _fitted():
    """3 h at 10 Hz of white noise and a 100 s Gauss-Markov bias on every axis of both sensors."""
    spec = NoiseSpec(N=[7e-4] * 3, B=[2e-4 * GM_ADEV_PEAK / FLICKER_FLOOR] * 3, b_corr_time_s=100.0)
    y = NoiseGenerator(spec, 10.0, np.random.SeedSequence(4)).next(int(3 * 3600 * 10.0))
    rates = np.column_stack([y, 10.0 * y])
    phase = integrate_rates(rates, 10.0)
    return identify_noise(allan_curve(phase, 10.0, AXES), phase)


class _PlotApp(App):
    def compose(self) -> ComposeResult:
        yield PlotextPlot(id="adev")


def test_tui_allan_plot_draws_terms_sum_band_and_valid_range():
    curve, noise = _fitted()
    series = adev_series(curve.tau, curve.adev, noise, 0, curve)
    names = [s.name for s in series]
    for axis in ("gx", "gy", "gz"):
        model = noise[AXES.index(axis)].noise_model
        assert model is not None
        wanted = {axis, f"{axis} fit", f"{axis} 68%", f"{axis} valid"}
        wanted |= {f"{axis} {label}" for label in model.parts(curve.tau)}
        assert wanted <= set(names) and f"{axis} N" in wanted
    fit = next(s for s in series if s.name == "gx fit")
    labels = noise[0].noise_model.parts(curve.tau)
    parts = [s for s in series if s.name in {f"gx {label}" for label in labels}]
    assert len(parts) == len(labels)
    np.testing.assert_allclose(fit.y**2, sum(s.y**2 for s in parts), rtol=1e-9)  # the sum of its terms
    app = _PlotApp()

    async def run() -> None:
        async with app.run_test(size=(150, 50)) as pilot:
            drawn = draw(app.query_one(PlotextPlot), series, title="gyro ADEV", xlabel="tau (s)",
                         ylabel="rad/s", logx=True, logy=True)
            assert drawn == len([s for s in series if len(s.x) >= 2])
            await pilot.pause(0.2)
            rows = svg_rows(app.export_screenshot())
            text = "\n".join(rows)
            assert "gyro ADEV" in text and "gx N" in text and "gx valid" in text and "gx 68%" in text

    asyncio.run(run())
    png = render_png(curve, noise, "model")
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
