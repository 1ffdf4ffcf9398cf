"""Allan recording: a long still recording with its Allan deviation redrawn as it grows, then the fit."""

from __future__ import annotations

import time

import numpy as np
from rich.console import Group
from rich.text import Text
from textual import work
from textual.widgets import Static

from station.acquisition.allan_source import AXES
from station.engines.allan import allan_curve, cluster_sizes, integrate_rates, overlapping_adev
from station.engines.allan_fit import identify_noise
from station.errors import StationError
from station.export import allan_report
from station.export.params_file import ParamsFile, to_plain
from station.tui.messages import LinkFailed, Snapshot
from station.tui.plot import Series, braille_plot
from station.tui.pump import pump
from station.tui.recording import Recording
from station.tui.screens.long_recording import LongRecordingScreen

COLORS = ("red", "green", "dodger_blue1")
MIN_SAMPLES = 64


def adev_plots(tau: np.ndarray, adev: np.ndarray, width: int = 50, height: int = 10) -> Group:
    """The gyro and accel ADEV (columns in ``AXES`` order) as two log-log braille plots."""
    gyro = [Series(AXES[j], tau, adev[:, j], COLORS[j]) for j in range(3)]
    acc = [Series(AXES[3 + j], tau, adev[:, 3 + j], COLORS[j]) for j in range(3)]
    return Group(braille_plot(gyro, width, height, True, True, "tau (s)", "gyro ADEV (rad/s)"),
                 braille_plot(acc, width, height, True, True, "tau (s)", "accel ADEV (m/s^2)"))


class AllanScreen(LongRecordingScreen):
    HEADING = "Allan recording"
    KIND = "allan"
    INTRO = "Keep the unit still. The recording runs until Enter."
    FITTING = "fitting the noise terms ..."
    DEFAULT_CSS = """
    AllanScreen #plots { width: 1fr; border: round $accent; }
    AllanScreen #side { width: 60; border: round $secondary; padding: 0 1; }
    """

    @work(thread=True, exclusive=True, group="reader")
    def _read(self) -> None:
        device = self.session.device
        next_adev = [0.0]

        def on_tick() -> None:
            # The ADEV is heavier than a redraw: recompute it at most once a second, and never
            # more than a fifth of the time, so the reader keeps up however long the record.
            now = time.monotonic()
            data: dict = {"count": self.recording.count, "stats": device.stats}
            if now >= next_adev[0]:
                samples = self.recording.snapshot()
                if len(samples) >= MIN_SAMPLES:
                    rates = np.column_stack([samples["gyro"], samples["acc"]]).astype(np.float64)
                    rate = Recording.rate_hz(samples)
                    m = cluster_sizes(len(rates), per_decade=5)
                    adev = overlapping_adev(rates, rate, m, workers=1)
                    data.update(tau=m / rate, adev=adev, rate_hz=rate)
                spent = time.monotonic() - now
                next_adev[0] = now + max(1.0, 5 * spent)
            self.post_message(Snapshot(data))

        pump(device, self.recording.add, on_tick, lambda exc: self.post_message(LinkFailed(exc)))

    def show_progress(self, d: dict) -> None:
        stats = d["stats"]
        # The device clock, not the wall clock: the record's length is what the Allan deviation sees.
        elapsed = d["count"] / stats.rate_hz if stats.rate_hz > 0 else 0.0
        side = Text()
        side.append("Allan recording\n", style="bold")
        side.append(f"recorded  {elapsed / 60:6.1f} min of {self.station.config.allan_minutes:g} min asked\n")
        side.append(f"samples   {d['count']}\n")
        side.append(f"rate      {stats.rate_hz:.1f} Hz\n")
        side.append(f"lost      {stats.lost}   errors {stats.errors}\n\n")
        side.append("Keep the unit still and the temperature steady.\n"
                    "Hours of data show bias instability and random walk;\n"
                    "minutes show white noise only.\n\nEnter: stop and fit · Escape: back")
        self.query_one("#side", Static).update(side)
        if "adev" in d:
            self.query_one("#plots", Static).update(adev_plots(d["tau"], d["adev"], self.plot_width()))
        if elapsed >= 60 * self.station.config.allan_minutes:
            self.action_stop()

    @work(thread=True, exclusive=True, group="fit")
    def _fit(self) -> None:
        samples = self.recording.snapshot()
        try:
            if len(samples) < 1000:
                raise StationError(f"{len(samples)} samples are too few for an Allan fit; record longer")
            rates = np.column_stack([samples["gyro"], samples["acc"]]).astype(np.float64)
            rate = Recording.rate_hz(samples)
            phase = integrate_rates(rates, rate)
            curve, noise = identify_noise(allan_curve(phase, rate, AXES), phase)  # as the allan command
            section = to_plain(allan_report.noise_section(noise, curve, {"source": self.session.name}))
        except StationError as exc:
            self.post_message(LinkFailed(exc))
            return
        saved = None
        out = self.station.config.out
        if out is not None:
            params = ParamsFile.load_or_new(out)
            params.update_device(self.session.info)
            params.noise = section
            params.save(out)
            saved = str(out)
        self.post_message(Snapshot({"fit": (curve, section), "saved": saved}))

    def show_fit(self, fit: tuple, saved: str | None) -> None:
        curve, section = fit
        self.query_one("#plots", Static).update(adev_plots(curve.tau, curve.adev, self.plot_width()))
        text = Text("\n".join(allan_report.summary_lines(section)) + "\n\n")
        text.append(f"noise section saved to {saved}" if saved else "no --out: nothing saved", style="bold")
        if self.recording.path is not None:
            text.append(f"\nrecording in {self.recording.path}")
        text.append("\nEscape: back · q: quit")
        self.query_one("#side", Static).update(text)

    def plot_width(self) -> int:
        """Plot cells that fit the panel beside the axis labels."""
        return max(20, self.query_one("#plots", Static).size.width - 14)
