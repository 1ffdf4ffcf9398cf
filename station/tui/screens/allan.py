"""Allan recording: a long still recording with its Allan deviation redrawn as it grows, then the fit."""

from __future__ import annotations

import time

import numpy as np
from rich.text import Text
from textual import work
from textual.widgets import Static

from station.acquisition.allan_source import AXES
from station.engines.allan.deviation import (
    AllanCurve,
    allan_curve,
    cluster_sizes,
    integrate_rates,
    overlapping_adev,
)
from station.engines.allan.fit import AxisNoise, identify_noise
from station.errors import StationError
from station.export.params import noise as noise_file
from station.export.params.file import to_plain
from station.tui.messages import LinkFailed, Snapshot
from station.tui.plot import Series, draw
from station.tui.pump import pump
from station.tui.recording import Recording
from station.tui.screens.long_recording import LongRecordingScreen

COLORS = ("red", "green", "blue")
DIM = ("orange", "cyan", "magenta")  # the band, the terms and the valid range of each axis
MIN_SAMPLES = 64


def adev_series(tau: np.ndarray, adev: np.ndarray, noise: list[AxisNoise] | None,
                first: int, curve: AllanCurve | None = None) -> list[Series]:
    """The ADEV of the three axes from column ``first`` (``AXES`` order), each followed, when ``noise``
    is given, by its fitted model (the sum), every term of the model as its own line, the curve's 68 %
    band (from ``curve``) and the bounds of the model's valid range as vertical lines.

    Parameters
    ----------
    tau : numpy.ndarray
        Averaging times, s.
    adev : numpy.ndarray
        Allan deviation, one column per axis of ``AXES``.
    noise : list of AxisNoise or None
        The fit of every axis (None while recording).
    first : int
        0 for the gyroscope, 3 for the accelerometer.
    curve : AllanCurve, optional
        The fitted curve, for its 68 % interval.

    Returns
    -------
    list of Series
    """
    out = []
    for j in range(3):
        k = first + j
        out.append(Series(AXES[k], tau, adev[:, k], COLORS[j]))
        if noise is None:
            continue
        fit = noise[k]
        out.append(Series(f"{AXES[k]} fit", tau, fit.model(tau), COLORS[j], fitted=True))
        if curve is not None:
            out.append(Series(f"{AXES[k]} 68%", tau, curve.ci_low[:, k], DIM[j], fitted=True))
            out.append(Series("", tau, curve.ci_high[:, k], DIM[j], fitted=True))
        model = fit.noise_model
        if model is None:
            continue
        for label, part in model.parts(tau).items():
            out.append(Series(f"{AXES[k]} {label}", tau, np.sqrt(part), DIM[j], fitted=True))
        span = [float(np.min(adev[:, k])) / 2.0, float(np.max(adev[:, k])) * 2.0]
        for name, edge in zip((f"{AXES[k]} valid", ""), model.valid_tau, strict=True):
            out.append(Series(name, np.array([edge, edge]), np.array(span), DIM[j], fitted=True))
    return out


def draw_adev(screen: LongRecordingScreen, tau: np.ndarray, adev: np.ndarray,
              noise: list[AxisNoise] | None = None, curve: AllanCurve | None = None) -> None:
    """The gyro and accel ADEV on log-log axes, with the model, its terms, band and valid range once
    fitted."""
    gyro_plot, acc_plot = screen.plots()
    draw(gyro_plot, adev_series(tau, adev, noise, 0, curve), title="gyro ADEV", xlabel="tau (s)",
         ylabel="rad/s", logx=True, logy=True)
    draw(acc_plot, adev_series(tau, adev, noise, 3, curve), title="accel ADEV", xlabel="tau (s)",
         ylabel="m/s^2", logx=True, logy=True)


class AllanScreen(LongRecordingScreen):
    """A long still recording with its Allan deviation redrawn as it grows; Enter fits the noise
    terms and saves the ``noise`` section (asking before replacing one)."""

    HEADING = "Allan recording"
    KIND = "allan"
    SECTION = "noise"
    INTRO = "Keep the unit still. The recording runs until Enter."
    FITTING = "fitting the noise terms ..."

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
        """The recording's length and link, and the ADEV so far."""
        stats = d["stats"]
        # The device clock, not the wall clock: the record's length is what the Allan deviation sees.
        elapsed = d["count"] / stats.rate_hz if stats.rate_hz > 0 else 0.0
        side = Text()
        side.append("Allan recording  ", style="bold")
        side.append(f"{elapsed / 60:.1f} min of {self.station.config.allan_minutes:g} min asked, "
                    f"{d['count']} samples\n")
        side.append(f"rate {stats.rate_hz:.1f} Hz · lost {stats.lost} · errors {stats.errors}\n")
        side.append("Keep the unit still and the temperature steady: hours of data show bias instability "
                    "and random walk, minutes white noise only.\n")
        side.append("Enter: stop and fit · Escape: back", style="bold")
        self.query_one("#side", Static).update(side)
        if "adev" in d:
            draw_adev(self, d["tau"], d["adev"])
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
            section = to_plain(noise_file.noise_section(noise, curve, {"source": self.session.name}))
        except StationError as exc:
            self.post_message(LinkFailed(exc))
            return
        self.post_message(Snapshot({"fit": (curve, noise, section), "section": section}))

    def show_fit(self, fit: tuple) -> None:
        """The fitted lines over the curves, and the noise terms of every axis."""
        curve, noise, section = fit
        draw_adev(self, curve.tau, curve.adev, noise, curve)
        text = Text("\n".join(noise_file.summary_lines(section)))
        if self.recording.path is not None:
            text.append(f"\nrecording in {self.recording.path}")
        self.query_one("#side", Static).update(text)
