"""The magnetometer step: turn the unit until the field has been seen from enough directions.

The screen draws the two halves of the sphere of field directions (in the sensor's axes) with the
cells already visited, marks where the field points now, and says which way to turn next (the
largest missing group of directions, :meth:`station.engines.magnetometer.coverage.MagCoverage.advice`).
Directions are taken from the hard-iron centre estimated so far: the least-squares sphere through
the readings, once it is determined beyond the readings' noise
(:func:`station.engines.magnetometer.determined.sphere_centre`: its radius at least ten times the
noise and its centre known to 5 % of it). Before that nothing counts: a sphere through the noise of
a still unit sees every direction, and raw readings are not field directions. The step starts from
fresh samples (those queued while no screen read the unit, a results screen or a question, are
dropped) and never replaces an earlier session's capture without asking. It finishes by itself at
:data:`TARGET_SHARE` of the sphere; Enter finishes it earlier once the calibration can use the share
(``MIN_COVERAGE``; below ``WARN_COVERAGE`` it warns, and says so). Everything read is recorded to the
magnetometer capture (``TuiConfig.mag_capture_path``), for ``imu-station calibrate FILE --method
mag``. A unit without a magnetometer is told apart within seconds and the screen says so.
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
from station.engines.magnetometer.determined import (
    MIN_RADIUS_NOISE,
    NOISE_WINDOW,
    reading_noise,
    sphere_centre,
)
from station.errors import StationError
from station.tui.art import bar
from station.tui.mag_art import hemispheres
from station.tui.messages import LinkFailed, Snapshot
from station.tui.pump import pump
from station.tui.screens.ask import AskScreen
from station.tui.screens.station_screen import StationScreen

# The share of the sphere at which the step finishes by itself: a hand-turned unit reaches it in a
# minute or two; a desk-bound session does not, and is finished with Enter.
TARGET_SHARE = 0.8
# Directions kept a second for the coverage (a hand turns slowly: more adds nothing but work).
KEEP_HZ = 25.0
# Seconds of samples without a field before the unit is taken for one without a magnetometer.
NO_MAG_AFTER_S = 2.0
# Directions kept before the sphere through them is tried, and full-rate readings per noise chunk.
MIN_CENTRE_SAMPLES = 30
NOISE_CHUNK = NOISE_WINDOW + 2
# Reads that drain what waited before the step (a read returns what arrived since the last).
DRAIN_READS = 100


class MagProgress:
    """The field directions of a session so far, thinned to :data:`KEEP_HZ`, the readings' noise
    (``determined`` eq. (1), from full-rate chunks), and their coverage."""

    def __init__(self) -> None:
        self.readings: list[np.ndarray] = []
        self.samples = 0  # samples read, with or without a field
        self.with_field = 0
        self.first_t_us: int | None = None
        self.last_t_us = 0
        self.waiting: str | None = None  # why no direction counts yet (the centre not determined)
        self._last_bin = -1  # the last 1/KEEP_HZ s bin of device time a reading was kept from
        self._chunk: list[np.ndarray] = []  # full-rate readings not yet in a noise chunk
        self._noise: list[float] = []  # each full chunk's noise

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
        self._add_noise(mag[index])
        bins = t[index] // int(1e6 / KEEP_HZ)
        first = np.concatenate([[bins[0] != self._last_bin], bins[1:] != bins[:-1]])
        self._last_bin = int(bins[-1])
        if first.any():
            self.readings.append(mag[index[first]])

    def _add_noise(self, mag: np.ndarray) -> None:
        """Full-rate readings into chunks of :data:`NOISE_CHUNK`, each giving its noise (eq. (1))."""
        self._chunk.append(mag)
        pending = np.concatenate(self._chunk)
        while len(pending) >= NOISE_CHUNK:
            self._noise.append(reading_noise(pending[:NOISE_CHUNK]))
            pending = pending[NOISE_CHUNK:]
        self._chunk = [pending]

    @property
    def noise(self) -> float | None:
        """The readings' noise, microtesla: the low percentile of the chunks' (the unit paused in them);
        None before a chunk is full."""
        return float(np.percentile(self._noise, 20.0)) if self._noise else None

    @property
    def seconds(self) -> float:
        """Device time read so far."""
        return 0.0 if self.first_t_us is None else (self.last_t_us - self.first_t_us) * 1e-6

    @property
    def no_magnetometer(self) -> bool:
        """Samples came for :data:`NO_MAG_AFTER_S` and not one carried a field."""
        return self.with_field == 0 and self.seconds >= NO_MAG_AFTER_S

    def centre(self, m: np.ndarray) -> np.ndarray | None:
        """The hard iron as far as the readings tell: the sphere through them once it is determined
        beyond the noise (``determined`` eqs. (2)-(3)), else None, :attr:`waiting` saying why."""
        noise = self.noise
        if len(m) < MIN_CENTRE_SAMPLES or noise is None:
            self.waiting = "turn the unit: its field's centre is found once it has turned a little"
            return None
        found = sphere_centre(m, noise)
        self.waiting = None if found.determined else (
            "keep turning, through larger angles: the field has not moved enough beyond the noise "
            f"({noise:.2g} uT) to place its centre")
        return found.start.bias if found.determined else None

    def coverage(self) -> tuple[MagCoverage, np.ndarray | None]:
        """The coverage of the directions so far, and the field's direction now (None before any, or
        while the centre is not determined: then nothing counts)."""
        if not self.readings:
            return field_coverage(np.zeros((0, 3))), None
        m = np.concatenate(self.readings)
        self.readings = [m]
        centre = self.centre(m)
        if centre is None:
            return field_coverage(np.zeros((0, 3))), None
        centred = m - centre
        # a reading within a few noise of the centre has no direction to speak of
        centred = centred[np.linalg.norm(centred, axis=1) >= MIN_RADIUS_NOISE * (self.noise or 0.0)]
        return field_coverage(centred), (centred[-1] if len(centred) else None)


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
        """Ask before replacing an earlier session's capture; then open it, move a simulated unit, and
        start reading."""
        self.title = "imu-station · magnetometer"
        path = self.station.config.mag_capture_path()
        if path is None or not path.exists():
            self._start(path)
            return
        other = free_name(path)
        answers = [("r", f"replace {path.name}"), ("k", f"keep it: record to {other.name}")]

        def answered(reply: tuple[str, str] | None) -> None:
            key = reply[0] if reply is not None else "back"
            if key in ("r", "k"):
                self._start(path if key == "r" else other)
            else:
                self.station.show("live")

        question = f"A magnetometer session is already saved in {path}."
        self.app.push_screen(AskScreen(question, answers), answered)

    def _start(self, path: Path | None) -> None:
        """Open the capture at ``path`` (None: none kept), move a simulated unit, and start reading."""
        session = self.session
        try:
            if path is not None:
                self.recorder = Recorder(path, device=session.info, port=session.name,
                                         protocol=session.device.protocol)
        except (StationError, OSError) as exc:
            self.post_message(LinkFailed(exc))
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
        # Samples that waited while no screen read the unit (the results screen, a question) are of
        # before the step: a still unit's, which the coverage and the capture must not take.
        for _ in range(DRAIN_READS):
            if not len(device.read(0.0)):
                break
        self.app.call_from_thread(self._turn_simulated_unit)

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
                waiting = self.progress.waiting
            self.post_message(Snapshot({"coverage": coverage, "now": now, "seconds": seconds,
                                        "samples": samples, "waiting": waiting}))

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
        # the bar shows the share of the sphere, as the words beside it (not the share of the target)
        self.query_one("#coverage", ProgressBar).update(progress=coverage.share)
        guide = Text()
        guide.append(f"covered {coverage.share:4.0%} of the sphere", style="bold")
        guide.append(f" (target {TARGET_SHARE:.0%})\n")
        width = max(10, self.query_one("#guide", Static).content_size.width - 2)
        guide.append(bar(coverage.share, width) + "\n", style="green")
        waiting = message.data.get("waiting")
        if now is not None:
            guide.append(f"field now along {direction_label(now)}, {np.linalg.norm(now):.1f} uT\n")
        if waiting:
            guide.append(waiting + "\n", style="yellow")
        elif coverage.missing:
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


def free_name(path: Path) -> Path:
    """``path`` with the first of ``-2``, ``-3``, ... before its suffix that names no file yet."""
    suffix = "".join(path.suffixes) if path.name.endswith(".csv.gz") else path.suffix
    stem = path.name[:len(path.name) - len(suffix)] if suffix else path.name
    number = 2
    while (candidate := path.with_name(f"{stem}-{number}{suffix}")).exists():
        number += 1
    return candidate
