"""The sequence runner: a state machine that walks an operator through a sequence and records it.

For each step the runner asks the :class:`~station.acquisition.operator.Operator` to place the
unit, waits until the checks say it is in the asked pose and still, captures the step
automatically, and reviews the captured samples (saturation, dropouts, pose, turn angle)::

    PLACING --in pose and still--> CAPTURING --hold done--> REVIEW --ok--> next step
       ^            |                   | moved                 | failed check: operator chooses
       |            |                   v                       v redo / skip / accept / abort
       +-------- redo request <---- PLACING (automatic retry)

    rotation:  PLACING -> SETTLING (still, before) -> ROTATING (integrated angle)
               -> SETTLING (still, after) -> REVIEW

Samples of an accepted step carry its label in the capture; samples of redone attempts and
of the time between steps carry "". Abort (or a lost link) ends the run keeping everything
captured so far. Samples reach the sink only once their label is final, so a sink may stream
them to disk.

Every sample read passes the same :class:`~station.acquisition.clock_guard.ClockGuard` as a
capture's before anything uses its time (the stillness window, the hold and settle timing, the
turn integration, the sinks): a sample whose device time departs alone from the line is left
out and counted, a jump the samples after it confirm (a unit restart) is kept and reported, and
a clock that went back is re-based to run on. The guard's counts join the link statistics
(:meth:`SequenceRunner.link_stats`). A step's review does not count the samples the guard left
out, nor the restart of ``seq`` at a confirmed jump, as samples lost on the link.

The runner is blocking: the TUI runs it in a thread worker, a factory script calls it directly.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.errors import DriverError
from drivers.interface import Device
from drivers.link_stats import LinkStats
from protocols.base import SAMPLE_DTYPE
from station.acquisition import checks
from station.acquisition.checks import Limits
from station.acquisition.clock_guard import ClockGuard
from station.acquisition.operator import Action, Operator, Prompt

# What a run reports lives below both this module and the operator's (which receives it), so the
# two do not import each other; the sinks live apart from the state machine. All stay importable
# from here, where callers have always found them.
from station.acquisition.run_records import LiveStatus as LiveStatus
from station.acquisition.run_records import RunResult as RunResult
from station.acquisition.run_records import State as State
from station.acquisition.run_records import StepRecord as StepRecord
from station.acquisition.sequences import PoseStep, RotationStep, Sequence, Step
from station.acquisition.sinks import MemorySink as MemorySink
from station.acquisition.sinks import RecorderSink as RecorderSink
from station.acquisition.sinks import SampleSink as SampleSink
from station.acquisition.sinks import samples_to_capture as samples_to_capture


@dataclass(frozen=True)
class RunOptions:
    """How the runner decides. Times in seconds.

    ``ready_s``: the unit must be in pose and still this long before capture starts.
    ``step_timeout_s``: how long to wait for the asked pose or turn before a ``timeout`` prompt
    (None waits for ever, as a person at the TUI may). ``max_attempts``: attempts of a step
    before a failed review counts as failed rather than asking again.
    """

    limits: Limits = field(default_factory=Limits)
    ready_s: float = 0.3
    step_timeout_s: float | None = None
    status_rate_hz: float = 20.0
    max_attempts: int = 3
    confirm_start: bool = True
    read_timeout_s: float = 0.05


def _mean3(vectors: np.ndarray) -> tuple[float, float, float]:
    """Mean of (N, 3) vectors as a plain tuple."""
    x, y, z = vectors.mean(axis=0)
    return float(x), float(y), float(z)


class _Window:
    """The last ``span_s`` seconds of samples (device clock), for the live checks."""

    def __init__(self, span_s: float):
        self.span_us = int(span_s * 1e6)
        self.samples = np.zeros(0, SAMPLE_DTYPE)

    def add(self, batch: np.ndarray) -> None:
        if not len(batch):
            return
        joined = np.concatenate([self.samples, batch]) if len(self.samples) else batch
        newest = int(batch["t_us"][-1])
        first = int(np.searchsorted(joined["t_us"], newest - self.span_us, side="left"))
        self.samples = joined[first:]

    def clear(self) -> None:
        self.samples = np.zeros(0, SAMPLE_DTYPE)

    @property
    def span_s(self) -> float:
        s = self.samples
        return (int(s["t_us"][-1]) - int(s["t_us"][0])) * 1e-6 if len(s) > 1 else 0.0


class _Abort(Exception):
    def __init__(self, outcome: str, reason: str, error: BaseException | None = None):
        super().__init__(reason)
        self.outcome = outcome
        self.reason = reason
        self.error = error


class _Restart(Exception):
    """Start the current step again (operator's redo, or the unit moved during a hold)."""


class _Skip(Exception):
    pass


class SequenceRunner:
    """Runs ``sequence`` on ``device`` with ``operator``; :meth:`run` blocks until the end.

    ``sink`` receives every sample with its final label (default: kept in memory, and the
    result's capture is built from it). ``clock`` is the wall clock for timeouts.
    """

    def __init__(self, device: Device, sequence: Sequence, operator: Operator,
                 options: RunOptions | None = None, sink: SampleSink | None = None,
                 clock: Callable[[], float] = time.monotonic):
        self.device = device
        self.sequence = sequence
        self.operator = operator
        self.options = options or RunOptions()
        self.memory = MemorySink()
        self.sinks: list[SampleSink] = [self.memory] + ([sink] if sink is not None else [])
        self.clock = clock
        self.window = _Window(self.options.limits.still_window_s)
        self.records: list[StepRecord] = []
        self.guard = ClockGuard()
        self._pending: list[np.ndarray] = []  # samples of the current attempt, label not yet final
        self._pending_row = 0  # the guard's row of the attempt's first sample
        self._pending_outliers = 0  # the guard's outlier count when the attempt's first sample came
        self._last_status = -math.inf
        self._index = 0
        self._attempt = 1
        self._state = State.STARTING

    # ---- reading -------------------------------------------------------------------------------

    def link_stats(self) -> LinkStats:
        """The device's link statistics with the clock guard's counts (outliers left out, jumps).

        Returns
        -------
        LinkStats
        """
        stats = self.device.stats
        stats.clock_outliers = self.guard.outliers
        stats.clock_jumps = len(self.guard.jumps)
        return stats

    def _emit(self, samples: np.ndarray, label: str) -> None:
        link = self.link_stats().as_dict() if len(self.sinks) > 1 else None
        for sink in self.sinks:
            sink.write(samples, label, link)

    def _read(self) -> np.ndarray:
        """One batch from the device through the clock guard (which may hold a few samples back
        for the ones after them)."""
        try:
            batch = self.guard.push(self.device.read(self.options.read_timeout_s)).samples
        except DriverError as exc:
            raise _Abort("link-error", str(exc), exc) from None
        if len(batch):
            self.window.add(batch)
        return batch

    def _keep(self, batch: np.ndarray) -> None:
        """Add a batch (just read) to the attempt's samples."""
        if not self._pending:
            self._pending_row = self.guard.released_rows - len(batch)
            self._pending_outliers = self.guard.outliers
        self._pending.append(batch)

    def _poll(self) -> None:
        action = self.operator.poll()
        if action is Action.ABORT:
            raise _Abort("aborted", "the operator aborted the run")
        if action is Action.REDO:
            raise _Restart
        if action is Action.SKIP:
            raise _Skip

    def _status(self, message: str, force: bool = False, **kw: Any) -> None:
        now = self.clock()
        if not force and now - self._last_status < 1.0 / self.options.status_rate_hz:
            return
        self._last_status = now
        w = self.window.samples
        stats = self.device.stats
        step = self.sequence.steps[self._index]
        self.operator.status(LiveStatus(
            index=self._index, total=len(self.sequence), step=step, state=self._state, attempt=self._attempt,
            message=message,
            acc_mean=_mean3(w["acc"]) if len(w) else None,
            gyro_mean=_mean3(w["gyro"]) if len(w) else None,
            temp=float(w["temp"][-1]) if len(w) else None,
            rate_hz=stats.rate_hz, lost=stats.lost + stats.overflow_drops, link_errors=stats.errors, **kw))

    # ---- the run -------------------------------------------------------------------------------

    def run(self) -> RunResult:
        """Walk the whole sequence; never raises for the operator's abort or a lost link."""
        op = self.operator
        op.begin(self.sequence)
        outcome, reason, error = "completed", "", None
        try:
            if self.options.confirm_start:
                prompt = Prompt("start", f"Sequence {self.sequence.name}: {len(self.sequence)} steps, about "
                                f"{self.sequence.nominal_duration_s:.0f} s of capture. Start?",
                                (Action.ACCEPT, Action.ABORT), Action.ACCEPT)
                if op.confirm(prompt) is Action.ABORT:
                    raise _Abort("aborted", "the operator did not start the run")
            for index, step in enumerate(self.sequence.steps):
                self._index = index
                self.records.append(self._run_step(step))
                op.step_finished(self.records[-1])
        except _Abort as stop:
            outcome, reason, error = stop.outcome, stop.reason, stop.error
            self._flush_pending("")
            if self._index < len(self.sequence) and len(self.records) <= self._index:
                step = self.sequence.steps[self._index]
                self.records.append(StepRecord(step.label, step.kind, "aborted", self._attempt,
                                               problems=[reason]))
        self._state = State.DONE
        self._drain_received()
        result = RunResult(outcome, self.memory.capture(self.device.info, self.link_stats().as_dict(),
                                                        source=getattr(self.device, "port", "")),
                           self.records, self.sequence, error=error, reason=reason)
        op.end(result)
        return result

    def _drain_received(self) -> None:
        """Keep what already arrived (unlabelled) without waiting for more, and what the clock
        guard still holds that it can place."""
        try:
            self._emit(self.guard.push(self.device.read(0)).samples, "")
        except DriverError:
            pass
        self._emit(self.guard.finish().samples, "")

    def _flush_pending(self, label: str) -> None:
        if self._pending:
            self._emit(np.concatenate(self._pending), label)
            self._pending = []

    def _run_step(self, step: Step) -> StepRecord:
        self._attempt = 1
        while True:
            try:
                record = self._attempt_step(step)
            except _Restart:
                self._flush_pending("")
                self._attempt += 1
                continue
            except _Skip:
                self._flush_pending("")
                return StepRecord(step.label, step.kind, "skipped", self._attempt)
            if not record.problems:
                self._flush_pending(step.label)
                return record
            action = self._review(step, record)
            if action is Action.REDO:
                self._flush_pending("")
                self._attempt += 1
                continue
            if action is Action.ACCEPT:
                self._flush_pending(step.label)
                record.status = "accepted"
                return record
            self._flush_pending("")
            if action is Action.SKIP:
                record.status = "skipped"
                return record
            record.status = "failed" if self._attempt >= self.options.max_attempts else "aborted"
            self.records.append(record)
            raise _Abort("aborted", f"step {step.label}: " + "; ".join(record.problems))

    def _review(self, step: Step, record: StepRecord) -> Action:
        self._state = State.REVIEW
        choices: tuple[Action, ...] = (Action.REDO, Action.SKIP, Action.ACCEPT, Action.ABORT)
        if self._attempt >= self.options.max_attempts:
            # Out of attempts: a script that keeps answering redo must not loop for ever.
            choices = (Action.SKIP, Action.ACCEPT, Action.ABORT)
        default = choices[0]
        self._status("; ".join(record.problems), force=True)
        return self.operator.confirm(Prompt(
            "review", f"Step {step.label} (attempt {self._attempt}) did not pass its checks.",
            choices, default, step, tuple(record.problems)))

    def _attempt_step(self, step: Step) -> StepRecord:
        self._pending = []
        self.window.clear()
        self._state = State.PLACING
        self.operator.place(step, self._index, len(self.sequence))
        tolerance = self.options.limits.pose_tolerance_deg
        if isinstance(step, PoseStep):
            self._wait_ready(step, lambda acc: checks.pose_check(acc, step.up, tolerance))
            self._capture_still(step, step.hold_s, State.CAPTURING)
            return self._check_pose_step(step)
        axis = step.axis
        self._wait_ready(step, lambda acc: checks.vertical_axis_check(acc, axis, tolerance))
        self._capture_still(step, step.settle_s, State.SETTLING)
        return self._rotate(step)

    def _timed_out(self, since: float, step: Step, what: str) -> bool:
        """Ask what to do when the wait is over its time; True when the wait starts again."""
        limit = self.options.step_timeout_s
        if limit is None or self.clock() - since < limit:
            return False
        self._state = State.REVIEW
        action = self.operator.confirm(Prompt(
            "timeout", f"Step {step.label}: {what} after {limit:.0f} s.",
            (Action.REDO, Action.SKIP, Action.ABORT), Action.REDO, step))
        if action is Action.ABORT:
            raise _Abort("timeout", f"step {step.label}: {what} after {limit:.0f} s")
        if action is Action.SKIP:
            raise _Skip
        return True

    def _wait_ready(self, step: Step, pose_of: Callable[[np.ndarray], checks.PoseCheck]) -> None:
        """Read until the unit is in pose and still for ``ready_s``; samples read meanwhile are unlabelled."""
        self._state = State.PLACING
        limits = self.options.limits
        since = self.clock()
        ready_from: int | None = None
        what = f"place the unit with {step.label if isinstance(step, PoseStep) else step.start_pose} up"
        while True:
            self._poll()
            batch = self._read()
            self._emit(batch, "")
            w = self.window.samples
            if not len(w):
                if self._timed_out(since, step, "no samples from the unit"):
                    since = self.clock()
                continue
            still = checks.stillness(w["acc"], w["gyro"], limits)
            pose = pose_of(w["acc"])
            full = self.window.span_s >= 0.9 * limits.still_window_s
            ok = full and still.still and pose.ok
            newest = int(w["t_us"][-1])
            if ok and ready_from is None:
                ready_from = newest
            elif not ok:
                ready_from = None
            held = (newest - ready_from) * 1e-6 if ready_from is not None else 0.0
            if pose.ok:
                message = "in pose, keep still" if not still.still else "in pose and still"
            else:
                message = f"{what} (now {pose.nearest or '?'} up, {pose.angle_deg:.0f} deg off)"
            self._status(message, stillness=still, pose=pose,
                         progress=min(1.0, held / self.options.ready_s) if self.options.ready_s else 1.0)
            if ready_from is not None and held >= self.options.ready_s:
                return
            if self._timed_out(since, step, f"not in pose and still ({message})"):
                since = self.clock()

    def _capture_still(self, step: Step, duration_s: float, state: State) -> None:
        """Keep ``duration_s`` of samples in the attempt while the unit stays still (motion restarts)."""
        self._state = state
        limits = self.options.limits
        start_us: int | None = None
        while True:
            self._poll()
            batch = self._read()
            if not len(batch):
                continue
            self._keep(batch)
            if start_us is None:
                start_us = int(batch["t_us"][0])
            w = self.window.samples
            still = checks.stillness(w["acc"], w["gyro"], limits)
            if not still.still and self.window.span_s >= 0.5 * limits.still_window_s:
                self._status("moved during the capture: hold still, starting the step again",
                             force=True, stillness=still)
                raise _Restart
            elapsed = (int(batch["t_us"][-1]) - start_us) * 1e-6
            self._status(f"capturing {step.label}: keep still", stillness=still,
                         progress=min(1.0, elapsed / duration_s))
            if elapsed >= duration_s:
                return

    def _attempt_samples(self) -> np.ndarray:
        return np.concatenate(self._pending) if self._pending else np.zeros(0, SAMPLE_DTYPE)

    def _common_checks(self, record: StepRecord, s: np.ndarray) -> None:
        limits = self.options.limits
        record.samples = len(s)
        record.duration_s = (int(s["t_us"][-1]) - int(s["t_us"][0])) * 1e-6 if len(s) > 1 else 0.0
        record.saturation = checks.saturation(s["acc"], s["gyro"], limits)
        if not record.saturation.ok:
            record.problems.append(f"saturated: {record.saturation.acc_samples} accelerometer and "
                                   f"{record.saturation.gyro_samples} gyroscope samples at the limit")
        record.dropouts = self._dropouts(s["seq"])
        if record.dropouts.lost_fraction > limits.max_lost_fraction:
            record.problems.append(f"{record.dropouts.lost} samples lost in {record.dropouts.gaps} gaps")

    def _dropouts(self, seq: np.ndarray) -> checks.Dropouts:
        """Samples lost on the link during the attempt: ``seq`` gaps, less the samples the clock
        guard left out (they arrived, with a wild time) and the restart of ``seq`` at a jump."""
        rows = [j.row - self._pending_row for j in self.guard.jumps]
        cuts = [row for row in rows if 0 < row < len(seq)]
        pieces = [checks.dropouts(piece) for piece in np.split(seq, cuts)]
        lost = sum(p.lost for p in pieces)
        gaps = sum(p.gaps for p in pieces)
        left_out = min(self.guard.outliers - self._pending_outliers, lost)
        return checks.Dropouts(len(seq), lost - left_out, gaps - min(left_out, gaps))

    def _check_pose_step(self, step: PoseStep) -> StepRecord:
        s = self._attempt_samples()
        record = StepRecord(step.label, step.kind, "accepted", self._attempt)
        self._common_checks(record, s)
        record.pose = checks.pose_check(s["acc"], step.up, self.options.limits.pose_tolerance_deg)
        if not record.pose.ok:
            record.problems.append(f"pose {record.pose.angle_deg:.1f} deg from {step.label} "
                                   f"(measured {record.pose.nearest} up)")
        return record

    def _rotate(self, step: RotationStep) -> StepRecord:
        """Ask for the turn, follow the integrated angle, then keep the still settle after it."""
        limits = self.options.limits
        before = self._attempt_samples()
        bias = float(np.mean(before["gyro"][:, step.axis]))
        target = step.angle_deg
        reach = abs(target) - checks.rotation_tolerance_deg(target, limits)
        self._state = State.ROTATING
        self.operator.rotate(step)
        angle = 0.0
        last_t_us = int(before["t_us"][-1])
        last_rate = float(before["gyro"][-1, step.axis]) - bias
        still_since: int | None = None
        since = self.clock()
        while True:
            self._poll()
            batch = self._read()
            if len(batch):
                self._keep(batch)
                t = np.concatenate([[last_t_us], batch["t_us"].astype(np.int64)]) * 1e-6
                rate = np.concatenate([[last_rate], batch["gyro"][:, step.axis].astype(float) - bias])
                angle += math.degrees(float(np.sum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))))
                last_t_us, last_rate = int(batch["t_us"][-1]), float(rate[-1])
                w = self.window.samples
                still = checks.stillness(w["acc"], w["gyro"], limits)
                turned = math.copysign(1.0, target) * angle >= reach
                if turned and still.still and self.window.span_s >= 0.9 * limits.still_window_s:
                    still_since = still_since if still_since is not None else int(w["t_us"][0])
                else:
                    still_since = None
                settled = (last_t_us - still_since) * 1e-6 if still_since is not None else 0.0
                self._state = State.SETTLING if still_since is not None else State.ROTATING
                msg = (f"turned {angle:+.0f} of {target:+.0f} deg: hold still" if turned
                       else f"turn {target:+.0f} deg about +{'xyz'[step.axis]}: {angle:+.0f} so far")
                self._status(msg, stillness=still, angle_deg=angle, target_deg=target,
                             progress=min(1.0, settled / step.settle_s))
                if settled >= step.settle_s:
                    break
            if self._timed_out(since, step, f"turn not completed ({angle:+.0f} of {target:+.0f} deg)"):
                since = self.clock()
        s = self._attempt_samples()
        record = StepRecord(step.label, step.kind, "accepted", self._attempt)
        self._common_checks(record, s)
        total = checks.integrated_angle_deg(s["t_us"] * 1e-6, s["gyro"].astype(float), step.axis, bias)[-1]
        record.rotation = checks.rotation_check(total, target, limits)
        if not record.rotation.ok:
            record.problems.append(f"turned {total:+.1f} deg, asked {target:+.0f} "
                                   f"(tolerance {record.rotation.tolerance_deg:.0f})")
        return record
