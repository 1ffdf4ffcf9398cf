"""The live view of a 1 kHz unit: read through the paced port, the values at most UI_RATE_HZ times a second
and the traces at most PLOT_RATE_HZ, every sample still taken."""

from __future__ import annotations

import asyncio
import time

from tui_helpers import wait_for

import station.tui.screens.live as live
from drivers.paced_port import PacedPort
from station.tui import messages
from station.tui.app import StationApp
from station.tui.config import TuiConfig


def test_the_live_view_reads_the_paced_port_and_draws_at_its_rates(monkeypatch) -> None:
    counts = {"snapshots": 0, "plots": 0}

    class Snapshot(messages.Snapshot):  # the same name: handled by on_snapshot
        def __init__(self, data):
            super().__init__(data)
            counts["snapshots"] += 1

    real_draw = live.draw_traces

    def draw(*args, **kwargs):
        counts["plots"] += 1
        return real_draw(*args, **kwargs)

    monkeypatch.setattr(live, "Snapshot", Snapshot)
    monkeypatch.setattr(live, "draw_traces", draw)
    app = StationApp(TuiConfig(simulate=True, seed=3, rate_hz=1000))

    async def run() -> None:
        async with app.run_test(size=(120, 40)) as pilot:
            await wait_for(pilot, lambda: app.session is not None, 30, "the simulated unit")
            assert isinstance(app.session.device, PacedPort)
            await pilot.press("enter")
            await wait_for(pilot, lambda: counts["plots"] > 0, 10, "the live view's first traces")
            before = dict(counts)
            samples = app.session.device.stats.samples
            start = time.monotonic()
            await pilot.pause(2.0)
            elapsed = time.monotonic() - start
            snapshots = counts["snapshots"] - before["snapshots"]
            plots = counts["plots"] - before["plots"]
            assert 3 <= snapshots <= elapsed * live.UI_RATE_HZ + 1
            assert 1 <= plots <= elapsed * live.PLOT_RATE_HZ + 1
            stats = app.session.device.stats
            assert stats.samples - samples >= 0.8 * 1000 * elapsed and stats.lost == 0
            app.exit(0)

    asyncio.run(run())
