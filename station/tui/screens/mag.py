"""The magnetometer step: turn the unit until the field has been seen from enough directions.

The screen draws the two halves of the sphere of field directions (in the sensor's axes) with the
cells already visited, marks where the field points now, and says which way to turn next (the
largest missing group of directions, :meth:`station.engines.magnetometer.coverage.MagCoverage.advice`).
Directions are taken from the hard-iron centre estimated so far (the least-squares sphere through
the readings, :func:`station.engines.magnetometer.fit.sphere_fit`, once they spread enough; raw before).
The step finishes by itself at :data:`TARGET_SHARE` of the sphere; Enter finishes it earlier once
the calibration can use the share (``MIN_COVERAGE``; below ``WARN_COVERAGE`` it warns, and says
so). Everything read is recorded to the magnetometer capture (``TuiConfig.mag_capture_path``), for
``imu-station calibrate FILE --method mag``. A unit without a magnetometer is told apart within
seconds and the screen says so.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.widgets import Footer, Header, ProgressBar, Static

from protocols.base import has_mag
from station.acquisition.recorder import Recorder
from station.engines.magnetometer.calibration import MIN_COVERAGE, WARN_COVERAGE
from station.engines.magnetometer.coverage import CELLS, MagCoverage, direction_label, field_coverage
from station.engines.magnetometer.fit import sphere_fit
from station.errors import StationError
from station.tui.art import bar
from station.tui.mag_art import hemispheres
from station.tui.messages import LinkFailed, Snapshot
from station.tui.pump import pump
from station.tui.screens.station_screen import StationScreen

# The share of the sphere at which the step finishes by itself: a hand-turned unit reaches it in a
# minute or two; a desk-bound session does not, and is finished with Enter.
TARGET_SHARE = 0.8
# Directions kept a second for the coverage (a hand turns slowly: more adds nothing but work).
KEEP_HZ = 25.0
# Seconds of samples without a field before the unit is taken for one without a magnetometer.
NO_MAG_AFTER_S = 2.0
# The hard-iron centre is trusted once the readings spread over this share of their magnitude.
CENTRE_SPREAD = 0.5
MIN_CENTRE_SAMPLES = 30


class MagProgress:
    """The field directions of a session so far, thinned to :data:`KEEP_HZ`, and their coverage."""

    def __init__(self) -> None:
        self.readings: list[np.ndarray] = []
        self.samples = 0  # samples read, with or without a field
        self.with_field = 0
        self.first_t_us: int | None = None
        self.last_t_us = 0
        self._last_bin = -1  # the last 1/KEEP_HZ s bin of device time a reading was kept from

    def add(self, batch: np.ndarray) -> None:
        """Take a batch of samples: those with a finite field, the first of each 1/KEEP_HZ s, are kept."""
        if not len(batch):
            return
        t = batch["t_us"].astype(np.int64)
        if self.first_t_us is None:
            self.first_t_us = int(t[0])
        self.last_t_us = int(t[-1])
        self.samples += len(batch)
        if not has_mag(batch):
            return
        mag = batch["mag"].astype(np.float64)
        ok = np.isfinite(mag).all(axis=1)
        self.with_field += int(ok.sum())
        index = np.flatnonzero(ok)
        if not len(index):
            return
        bins = t[index] // int(1e6 / KEEP_HZ)
        first = np.concatenate([[bins[0] != self._last_bin], bins[1:] != bins[:-1]])
        self._last_bin = int(bins[-1])
        if first.any():
            self.readings.append(mag[index[first]])

    @property
    def seconds(self) -> float:
        """Device time read so far."""
        return 0.0 if self.first_t_us is None else (self.last_t_us - self.first_t_us) * 1e-6

    @property
    def no_magnetometer(self) -> bool:
        """Samples came for :data:`NO_MAG_AFTER_S` and not one carried a field."""
        return self.with_field == 0 and self.seconds >= NO_MAG_AFTER_S

    def centre(self, m: np.ndarray) -> np.ndarray:
        """The hard iron as far as the readings tell: the sphere through them once they spread."""
        if len(m) < MIN_CENTRE_SAMPLES:
            return np.zeros(3)
        norm = float(np.median(np.linalg.norm(m - np.median(m, axis=0), axis=1)))
        spread = float(np.linalg.norm(m.max(axis=0) - m.min(axis=0)))
        if not norm or spread < CENTRE_SPREAD * norm:
            return np.zeros(3)
        start = sphere_fit(m)
        radius = 1.0 / float(start.correction[0, 0])
        # A sphere fit on a thin arc can run off; then the raw directions say more.
        return start.bias if np.linalg.norm(start.bias - m.mean(axis=0)) < 3.0 * radius else np.zeros(3)

    def coverage(self) -> tuple[MagCoverage, np.ndarray | None]:
        """The coverage of the directions so far, and the field's direction now (None before any)."""
        if not self.readings:
            return field_coverage(np.zeros((0, 3))), None
        m = np.concatenate(self.readings)
        self.readings = [m]
        centred = m - self.centre(m)
        return field_coverage(centred), centred[-1]


class MagScreen(StationScreen):
    """The sphere's two halves with the directions visited, what to do next, and the coverage."""

    BINDINGS = [Binding("enter", "finish", "finish", show=True), Binding("escape", "back", "back")]
    DEFAULT_CSS = """
    MagScreen #top { height: auto; }
    MagScreen #sphere { width: auto; border: round $accent; padding: 0 1; }
    MagScreen #guide-box { width: 1fr; height: auto; }
    MagScreen #guide { border: round $secondary; padding: 0 1; height: auto; }
    MagScreen.-short #guide { border: none; border-left: round $secondary; }
    MagScreen #coverage { padding: 0 1; height: 1; }
    MagScreen #status { height: auto; min-height: 2; border: heavy $warning; padding: 0 1; }
    MagScreen.-short #status { border: none; border-top: heavy $warning; }
    """

    def __init__(self) -> None:
        super().__init__()
        self.progress = MagProgress()
        self.finished = False
        self.share = 0.0
        self.recorder: Recorder | None = None
        self._lock = threading.Lock()

    def compose(self) -> ComposeResult:
        """The sphere, the guidance with the coverage bar, the status line, the keys."""
        yield Header()
        with Horizontal(id="top"):
            yield Static(hemispheres(np.zeros(CELLS, bool)), id="sphere")
            with Vertical(id="guide-box"):
                yield Static("waiting for samples ...", id="guide")
                yield ProgressBar(total=1.0, show_eta=False, id="coverage")
        yield Static("", id="status")
        yield Footer()

    def on_mount(self) -> None:
        """Open the capture, move a simulated unit, and start reading."""
        self.title = "imu-station · magnetometer"
        session = self.session
        path = self.station.config.mag_capture_path()
        try:
            if path is not None:
                self.recorder = Recorder(path, device=session.info, port=session.name,
                                         protocol=session.device.protocol)
        except (StationError, OSError) as exc:
            self.post_message(LinkFailed(exc))
        self._turn_simulated_unit()
        self.query_one("#status", Static).update(Text(
            "Turn the unit slowly in every direction, pausing now and then; keep it away from steel and "
            "magnets. Enter: finish · Escape: back", style="dim"))
        self._read()

    def _turn_simulated_unit(self) -> None:
        """The simulated unit turns itself through attitudes that cover the sphere (as a hand would)."""
        command = getattr(self.session.rig, "command", None)
        if command is not None:
            from mocks.mag_sessions import sphere_session

            command(sphere_session(n_poses=40, seed=self.station.config.seed, hold_s=0.5, move_s=1.0,
                                   initial_still_s=0.5))

    @work(thread=True, exclusive=True, group="reader")
    def _read(self) -> None:
        device = self.session.device

        def on_batch(batch: np.ndarray) -> None:
            with self._lock:
                if self.finished:
                    return
                self.progress.add(batch)
                if self.recorder is not None and has_mag(batch):
                    self.recorder.write(batch, device.stats.as_dict())

        def on_tick() -> None:
            with self._lock:
                if self.progress.no_magnetometer:
                    self.post_message(Snapshot({"no_mag": True}))
                    return
                coverage, now = self.progress.coverage()
                seconds, samples = self.progress.seconds, self.progress.with_field
            self.post_message(Snapshot({"coverage": coverage, "now": now, "seconds": seconds,
                                        "samples": samples}))

        pump(device, on_batch, on_tick, lambda exc: self.post_message(LinkFailed(exc)), ui_rate_hz=4.0)

    def on_snapshot(self, message: Snapshot) -> None:
        """Draw the directions visited and the advice; finish at the target share."""
        if self.finished:
            return
        if message.data.get("no_mag"):
            self.finished = True
            self.workers.cancel_group(self, "reader")
            self._close_capture(remove=True)
            self.query_one("#guide", Static).update(Text(
                "This unit reports no magnetometer: its samples carry no field (mx, my, mz), so there is "
                "nothing to calibrate here.", style="yellow"))
            self.query_one("#status", Static).update("l: live view · w: sequence wizard · q: quit")
            return
        coverage: MagCoverage = message.data["coverage"]
        now = message.data["now"]
        self.share = coverage.share
        self.query_one("#sphere", Static).update(hemispheres(coverage.hit, now))
        self.query_one("#coverage", ProgressBar).update(progress=min(1.0, coverage.share / TARGET_SHARE))
        guide = Text()
        guide.append(f"covered {coverage.share:4.0%} of the sphere", style="bold")
        guide.append(f" (target {TARGET_SHARE:.0%})\n")
        width = max(10, self.query_one("#guide", Static).content_size.width - 2)
        guide.append(bar(coverage.share, width) + "\n", style="green")
        if now is not None:
            guide.append(f"field now along {direction_label(now)}, {np.linalg.norm(now):.1f} uT\n")
        if coverage.missing:
            guide.append("turn next: ", style="bold cyan")
            guide.append(coverage.advice(1)[0] + "\n")
            guide.append(f"missing: {' '.join(coverage.missing[:6])}\n", style="dim")
        guide.append(f"{message.data['samples']} samples, {message.data['seconds']:.0f} s", style="dim")
        self.query_one("#guide", Static).update(guide)
        if coverage.share >= TARGET_SHARE:
            self._finish(f"Coverage reached {coverage.share:.0%}: the magnetometer step is done.")

    def on_link_failed(self, message: LinkFailed) -> None:
        """The link or the capture file failed: say so."""
        self.query_one("#status", Static).update(Text(f"stopped: {message.error}\nq: quit", style="red"))

    def action_finish(self) -> None:
        """Enter: finish now, once the calibration can use the coverage (a desk session's third of the
        sphere included: the dip constraint carries it, with a warning)."""
        if self.finished:
            self.station.show("live")
            return
        if self.share < MIN_COVERAGE:
            self.notify(f"only {self.share:.0%} covered: the calibration needs at least {MIN_COVERAGE:.0%}; "
                        f"turn on", severity="warning")
            return
        why = f"Finished at {self.share:.0%} of the sphere."
        if self.share < WARN_COVERAGE:
            why += (f" Under {WARN_COVERAGE:.0%} the calibration leans on the dip constraint and warns: "
                    f"fine for a desk-bound unit, with still poses in varied tilts.")
        self._finish(why)

    def action_back(self) -> None:
        """Escape: leave the step (what was recorded stays in its file)."""
        self.station.show("live")

    def _finish(self, why: str) -> None:
        self.finished = True
        self.workers.cancel_group(self, "reader")
        path = self._close_capture(remove=False)
        text = Text(why + "\n", style="bold green")
        if path is not None:
            text.append(f"Magnetometer capture saved to {path}; calibrate it with:\n"
                        f"  imu-station calibrate {path} --method mag -o PARAMS\n")
        else:
            text.append("Give --capture or --out to keep the session's capture.\n")
        text.append("Enter: live view · q: quit")
        self.query_one("#status", Static).update(text)

    def _close_capture(self, remove: bool) -> Path | None:
        """Close the capture file (removed when nothing was or should be kept); its path, or None."""
        with self._lock:
            recorder, self.recorder = self.recorder, None
        if recorder is None:
            return None
        try:
            recorder.close(self.session.device.stats.as_dict())
        except (StationError, OSError):
            pass
        if remove or recorder.rows == 0:
            recorder.path.unlink(missing_ok=True)
            return None
        return recorder.path

    def on_unmount(self) -> None:
        """Leaving the screen closes the capture (what was recorded is kept)."""
        self._close_capture(remove=False)
