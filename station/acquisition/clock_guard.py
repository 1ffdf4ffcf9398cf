"""Wild device timestamps on their way to a capture file: outliers left out and counted, real
jumps confirmed by the samples after them, and a clock that runs on across them.

The rule (``docs/reliability.md``, "Decoders and captures"):

- Each sample is compared with the line of the samples before it: the last one kept plus the
  sample period (median of the last steps) times the step of ``seq`` (1 when ``seq`` says
  nothing, e.g. protocols whose ``seq`` counts the samples received). A sample more than
  ``OUTLIER_PERIODS`` periods (at least ``MIN_TOLERANCE_US``) off that prediction **departs**.
- A departing sample is held. If the next sample is back on the old line, the held one was an
  **outlier**: left out of the file and counted (``outliers``), and the capture goes on. If
  ``CONFIRM`` samples in a row (the departing one included) agree on a new line, the clock
  really **jumped** (a unit restart, a clock set anew, a gap of lost samples that ``seq`` does
  not show): the samples are kept, the jump is recorded in ``jumps``, and when it went back the
  new piece is re-based to follow one period after the last row written, since the capture file
  needs ``t`` increasing. A sample that fits neither line ends the held ones as outliers and is
  held in turn.
- Samples on the line whose time does not increase (a replayed frame) are left out and counted
  in ``non_increasing``, as before.
- The first ``CONFIRM`` samples must agree before any is released (a wild first timestamp would
  otherwise anchor the line); at the end of the stream, held samples that nothing confirmed
  are outliers (none are, if no line was ever made: those then start it).

Every released sample also gets a **continuous time**: the device time with each jump replaced
by one period, which is what ``--duration`` counts.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from protocols.base import SAMPLE_DTYPE

OUTLIER_PERIODS = 50
MIN_TOLERANCE_US = 10_000
CONFIRM = 3
START_STEP_US = 5_000_000  # before the period is known, a step of at most this continues a line
MAX_SEQ_STEP = 1 << 20  # seq steps beyond this (or back) say nothing about the time step
PERIOD_WINDOW = 33
SMALL_BATCH = 8  # batches up to this size go sample by sample: numpy costs more than it saves
SEQ_MODULUS = 1 << 32

_Kept = tuple[np.void, str, int, int]  # a sample kept, its label, written and continuous t_us


@dataclass(frozen=True)
class ClockJump:
    """A jump of the device clock that the samples after it confirmed."""

    row: int  # rows released before it (the row the new piece starts at)
    step_s: float  # how far the clock jumped, beyond the one period expected

    def describe(self) -> str:
        """One sentence for the user: which way the device clock jumped, by how much, at which row."""
        kind = "went back" if self.step_s < 0 else "jumped ahead"
        return f"the device clock {kind} {abs(self.step_s):.6g} s at row {self.row}"


@dataclass
class Released:
    """Samples cleared by the guard, with their labels and continuous times (microseconds)."""

    samples: np.ndarray
    labels: list[str] | None
    continuous_us: np.ndarray


class ClockGuard:
    """Screens batches of samples for wild timestamps (see the module docstring for the rule)."""

    def __init__(self) -> None:
        self.outliers = 0
        self.non_increasing = 0
        self.jumps: list[ClockJump] = []
        self.released_rows = 0
        self._last: tuple[int, int] | None = None  # (raw t_us, seq) of the last sample kept
        self._last_out = 0  # written t_us of the last sample kept
        self._offset = 0  # added to the raw t_us to make the written one
        self._continuous = 0  # added to the written t_us to make the continuous time
        self._steps: deque[float] = deque(maxlen=PERIOD_WINDOW)
        self._period: float | None = None
        self._new_steps = 0  # steps added since the period was last renewed
        self._held: list[tuple[np.void, str]] = []

    def push(self, samples: np.ndarray, labels: list[str] | None = None) -> Released:
        """Screen a batch (``labels``: one per sample, or None); returns the samples cleared."""
        if len(samples) == 0:
            return self._release([], labels is not None)
        on_a_line = not self._held and self._period is not None and self._last is not None
        if len(samples) > SMALL_BATCH and on_a_line:
            fast = self._on_the_line(samples, labels)
            if fast is not None:
                return fast
        kept: list[_Kept] = []
        for i, sample in enumerate(samples):
            kept += self._one(sample, labels[i] if labels is not None else "")
        return self._release(kept, labels is not None)

    def finish(self, with_labels: bool = False) -> Released:
        """End of the stream: held samples that nothing confirmed are outliers, unless no line
        was ever made (then they start one, in increasing order)."""
        held, self._held = self._held, []
        if self._last is not None:
            self.outliers += len(held)
            return self._release([], with_labels)
        rising: list[tuple[np.void, str]] = []
        for sample, label in held:
            if rising and int(sample["t_us"]) <= int(rising[-1][0]["t_us"]):
                self.non_increasing += 1
                continue
            rising.append((sample, label))
        if rising:
            self._start_line(rising)
        return self._release([self._emit(s, label) for s, label in rising], with_labels)

    # ------------------------------------------------------------------ the line

    def _tolerance(self) -> float:
        assert self._period is not None
        return max(OUTLIER_PERIODS * self._period, MIN_TOLERANCE_US)

    def _expected_step(self, seq: int, ref_seq: int) -> int:
        step = (seq - ref_seq) % SEQ_MODULUS
        return step if 1 <= step <= MAX_SEQ_STEP else 1

    def _fits(self, t: int, seq: int, ref_t: int, ref_seq: int) -> bool:
        if self._period is None:
            return 0 < t - ref_t <= START_STEP_US
        return abs(t - ref_t - self._expected_step(seq, ref_seq) * self._period) <= self._tolerance()

    def _on_the_line(self, samples: np.ndarray, labels: list[str] | None) -> Released | None:
        """The whole batch at once when every sample fits the line and time increases, else None."""
        assert self._last is not None and self._period is not None
        t = samples["t_us"].astype(np.int64)
        seq = samples["seq"].astype(np.int64)
        prev_t = np.concatenate([[self._last[0]], t[:-1]])
        prev_seq = np.concatenate([[self._last[1]], seq[:-1]])
        dseq = (seq - prev_seq) % SEQ_MODULUS
        counted = (dseq >= 1) & (dseq <= MAX_SEQ_STEP)
        k = np.where(counted, dseq, 1)
        dt = t - prev_t
        if not ((np.abs(dt - k * self._period) <= self._tolerance()).all() and (dt > 0).all()):
            return None
        self._add_steps((dt[counted] / dseq[counted])[-PERIOD_WINDOW:].tolist())
        self._last = (int(t[-1]), int(seq[-1]))
        out = samples.copy()
        out["t_us"] = t + self._offset
        self._last_out = int(out["t_us"][-1])
        self.released_rows += len(out)
        return Released(out, labels, t + self._offset + self._continuous)

    def _one(self, sample: np.void, label: str) -> list[_Kept]:
        """One sample through the rule; returns the samples it releases."""
        t, seq = int(sample["t_us"]), int(sample["seq"])
        if self._last is not None and self._fits(t, seq, *self._last):
            self.outliers += len(self._held)
            self._held = []
            if t <= self._last[0]:
                self.non_increasing += 1
                return []
            self._keep_step(t, seq)
            return [self._emit(sample, label)]
        if self._held:
            ref = self._held[-1][0]
            ref_t, ref_seq = int(ref["t_us"]), int(ref["seq"])
            if t > ref_t and self._fits(t, seq, ref_t, ref_seq):
                self._held.append((sample, label))
                if len(self._held) >= CONFIRM:
                    return self._confirm()
                return []
            self.outliers += len(self._held)
        self._held = [(sample, label)]
        return []

    def _keep_step(self, t: int, seq: int) -> None:
        assert self._last is not None
        dseq = (seq - self._last[1]) % SEQ_MODULUS
        if 1 <= dseq <= MAX_SEQ_STEP:
            self._add_steps([(t - self._last[0]) / dseq])
        self._last = (t, seq)

    def _add_steps(self, steps: list[float]) -> None:
        """Per-seq time steps of kept samples; the period is their median, renewed every
        ``PERIOD_WINDOW // 2`` steps (a median per sample would cost more than the rest)."""
        self._steps.extend(steps)
        self._new_steps += len(steps)
        if self._period is None or self._new_steps >= PERIOD_WINDOW // 2:
            self._period = float(np.median(self._steps))
            self._new_steps = 0

    def _start_line(self, kept: list[tuple[np.void, str]]) -> None:
        first = kept[0][0]
        self._last = (int(first["t_us"]), int(first["seq"]))
        for sample, _ in kept[1:]:
            self._keep_step(int(sample["t_us"]), int(sample["seq"]))

    def _confirm(self) -> list[_Kept]:
        """``CONFIRM`` held samples agree: the line starts (first samples) or the clock jumped."""
        held, self._held = self._held, []
        first_t = int(held[0][0]["t_us"])
        if self._last is None:
            self._start_line(held)
            return [self._emit(s, label) for s, label in held]
        assert self._period is not None
        last_t, last_seq = self._last
        expected = self._expected_step(int(held[0][0]["seq"]), last_seq) * self._period
        self.jumps.append(ClockJump(self.released_rows, (first_t - last_t - expected) * 1e-6))
        if first_t + self._offset <= self._last_out:
            self._offset = round(self._last_out + self._period - first_t)
        last_continuous = self._last_out + self._continuous
        self._continuous = round(last_continuous + self._period - (first_t + self._offset))
        self._last = (first_t, int(held[0][0]["seq"]))
        for sample, _ in held[1:]:
            self._keep_step(int(sample["t_us"]), int(sample["seq"]))
        return [self._emit(s, label) for s, label in held]

    def _emit(self, sample: np.void, label: str) -> _Kept:
        """A sample kept: its written and continuous times under the offsets in force now."""
        written = int(sample["t_us"]) + self._offset
        self._last_out = written
        self.released_rows += 1
        return sample, label, written, written + self._continuous

    def _release(self, kept: list[_Kept], with_labels: bool) -> Released:
        # The samples' own dtype: a nine-axis unit's field (MAG_SAMPLE_DTYPE) goes through too.
        out = np.array([k[0] for k in kept], dtype=kept[0][0].dtype) if kept else np.zeros(0, SAMPLE_DTYPE)
        out["t_us"] = [k[2] for k in kept]
        labels = [k[1] for k in kept] if with_labels else None
        return Released(out, labels, np.array([k[3] for k in kept], dtype=np.int64))
