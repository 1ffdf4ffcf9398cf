"""Temperature-sweep monitor: temperature and its rate, the bias against temperature, then the fit."""

from __future__ import annotations

import time

import numpy as np
from rich.text import Text
from textual import work
from textual.widgets import Static

from station.acquisition.runner import samples_to_capture
from station.console.thermal_report import format_report
from station.engines.thermal.fit import ThermalSettings, ThermalSweep, fit_thermal
from station.errors import StationError
from station.export.params.file import ParamsFile
from station.tui.messages import LinkFailed, Snapshot
from station.tui.plot import Series, draw
from station.tui.pump import pump
from station.tui.screens.long_recording import LongRecordingScreen

COLORS = ("red", "green", "blue")
BLOCK_S = 1.0
DTEMP_WINDOW_S = 30.0


def block_means(samples: np.ndarray, block_s: float = BLOCK_S) -> dict[str, np.ndarray]:
    """Means over blocks of ``block_s`` of device time: t (s), temp, gyro (B, 3), acc (B, 3).

    Parameters
    ----------
    samples : numpy structured array
        Samples as decoded (``t_us``, ``acc``, ``gyro``, ``temp``).
    block_s : float
        Length of a block, s of device time.

    Returns
    -------
    dict of str to numpy.ndarray
        ``t``, ``temp``, ``gyro``, ``acc``: one row per block holding samples.
    """
    t = (samples["t_us"] - samples["t_us"][0]).astype(np.float64) * 1e-6
    ids = (t // block_s).astype(np.int64)
    counts = np.bincount(ids)
    keep = counts > 0

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(ids, weights=values)[keep] / counts[keep]

    gyro = samples["gyro"].astype(np.float64)
    acc = samples["acc"].astype(np.float64)
    return {"t": mean(t), "temp": mean(samples["temp"].astype(np.float64)),
            "gyro": np.column_stack([mean(gyro[:, j]) for j in range(3)]),
            "acc": np.column_stack([mean(acc[:, j]) for j in range(3)])}


def temperature_rate(t: np.ndarray, temp: np.ndarray, window_s: float = DTEMP_WINDOW_S) -> float:
    """dT/dt (degC/s): slope of a line through the last ``window_s`` of block temperatures.

    Parameters
    ----------
    t, temp : numpy.ndarray
        Block times (s) and temperatures (degC).
    window_s : float
        How far back the line is fitted.

    Returns
    -------
    float
        The rate, NaN with fewer than three blocks in the window.
    """
    recent = t >= t[-1] - window_s
    if np.count_nonzero(recent) < 3:
        return float("nan")
    return float(np.polyfit(t[recent], temp[recent], 1)[0])


def draw_sweep(screen: LongRecordingScreen, blocks: dict[str, np.ndarray]) -> None:
    """Temperature against time, and the gyro bias change against temperature.

    Parameters
    ----------
    screen : LongRecordingScreen
        The screen whose two plots are redrawn.
    blocks : dict of str to numpy.ndarray
        The block means (:func:`block_means`).
    """
    t, temp = blocks["t"], blocks["temp"]
    gyro = blocks["gyro"] - blocks["gyro"].mean(axis=0)
    left, right = screen.plots()
    draw(left, [Series("temperature", t / 60, temp, "yellow")], title="temperature", xlabel="time (min)",
         ylabel="degC")
    draw(right, [Series(f"g{a}", temp, gyro[:, j], COLORS[j]) for j, a in enumerate("xyz")],
         title="gyro bias change", xlabel="temperature (degC)", ylabel="rad/s")


class ThermalScreen(LongRecordingScreen):
    """The temperature-sweep recording: live temperature, rate and bias plots; Enter fits the model."""

    HEADING = "temperature sweep"
    KIND = "thermal"
    SECTION = "thermal"
    INTRO = "Keep the unit still in the chamber. The sweep is recorded until Enter."
    FITTING = "fitting the thermal model ..."
    @work(thread=True, exclusive=True, group="reader")
    def _read(self) -> None:
        device = self.session.device
        next_draw = [0.0]

        def on_tick() -> None:
            now = time.monotonic()
            if now < next_draw[0]:
                return
            next_draw[0] = now + 0.5
            samples = self.recording.snapshot()
            if len(samples) < 2:
                return
            self.post_message(Snapshot({"blocks": block_means(samples), "stats": device.stats}))

        pump(device, self.recording.add, on_tick, lambda exc: self.post_message(LinkFailed(exc)))

    def show_progress(self, d: dict) -> None:
        """Update the side panel and the plots from a snapshot of the block means."""
        blocks, stats = d["blocks"], d["stats"]
        temp = blocks["temp"]
        rate = temperature_rate(blocks["t"], temp)
        side = Text()
        side.append("Temperature sweep  ", style="bold")
        side.append(f"{blocks['t'][-1] / 60:.1f} min, {self.recording.count} samples\n")
        side.append(f"temperature {temp[-1]:.2f} degC · rate {rate * 60:+.2f} degC/min · "
                    f"range {np.nanmin(temp):.1f} .. {np.nanmax(temp):.1f} degC\n")
        side.append(f"link {stats.rate_hz:.0f} Hz · lost {stats.lost} · errors {stats.errors}\n")
        side.append("Sweep the chamber over the whole operating range, slowly (about 1 degC/min), "
                    "up and down.\n")
        side.append("Enter: stop and fit · Escape: back", style="bold")
        self.query_one("#side", Static).update(side)
        draw_sweep(self, blocks)

    @work(thread=True, exclusive=True, group="fit")
    def _fit(self) -> None:
        samples = self.recording.snapshot()
        out = self.station.config.out
        try:
            # the file's accel and gyro sections, when there, make the fit of calibrated readings
            params = ParamsFile.load_or_new(out) if out is not None else ParamsFile()
            capture = samples_to_capture(samples)
            if capture.temp is None:
                raise StationError("the recording has no temperature readings; the unit must send its "
                                   "temperature for a thermal model")
            held = params.thermal
            # A file calibrated across temperature keeps its polynomials: the bias is fitted about its T_ref.
            across = held is not None and bool(held.scale or held.misalignment)
            settings = ThermalSettings(reference_temp=held.reference_temp if across and held else None)
            fit = fit_thermal(ThermalSweep(capture.t, capture.temp, capture.acc, capture.gyro,
                                           accel_cal=params.accel, gyro_cal=params.gyro), settings)
            section = fit.model.keeping_intrinsics(held)
        except (StationError, ValueError) as exc:
            self.post_message(LinkFailed(StationError(f"the thermal fit failed: {exc}")))
            return
        calibrated = {"accel": params.accel is not None, "gyro": params.gyro is not None}
        self.post_message(Snapshot({"fit": format_report(fit, calibrated), "section": section}))

    def show_fit(self, report: str) -> None:
        """Show the fit's report."""
        self.query_one("#side", Static).update(Text(report))
