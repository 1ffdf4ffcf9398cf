"""Link statistics: what came over the wire, what was lost, and the rate on the device clock."""

from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

from protocols.base import DecoderStats

SEQ_MODULUS = 1 << 32
# A seq step larger than half the counter range is the counter going back (device reset or a
# replayed frame), not four billion lost samples.
_SEQ_BACKWARDS = 1 << 31
# Seq steps up to this many missing values count at once; larger ones (and steps back) wait for
# the next sample to tell a real gap or reset from a lone outlier.
MAX_PLAIN_GAP = 1000
RATE_WINDOW_S = 2.0


@dataclass
class LinkStats:
    """A snapshot of one link since it was opened. All counts are totals."""

    samples: int = 0  # good sample frames decoded
    bytes: int = 0  # bytes read from the port
    rate_hz: float = 0.0  # samples received per second of device clock, over the last ~2 s
    device_time_s: float = 0.0  # device clock span from the first to the last sample
    crc_errors: int = 0
    resyncs: int = 0
    garbage_bytes: int = 0
    length_errors: int = 0
    truncated: int = 0
    bad_payloads: int = 0
    lost: int = 0  # samples missing from seq gaps (u32 wrap understood), less seq_skipped
    seq_skipped: int = 0  # seq values the protocol spent on packets without a sample (not lost)
    seq_resets: int = 0  # times seq went backwards and went on from there (device restart)
    seq_outliers: int = 0  # samples whose seq jumped away alone (a replayed frame, a wild counter)
    overflow_drops: int = 0  # samples dropped because the consumer did not keep up
    # Filled by the capture recorder (station.acquisition.clock_guard), which sees the device clock
    # as a line: samples whose time departed from it alone (left out), and jumps the samples after
    # them confirmed (a unit restart, a clock set anew).
    clock_outliers: int = 0
    clock_jumps: int = 0

    @property
    def errors(self) -> int:
        """Frames that arrived damaged (CRC, length, truncation, bad payload)."""
        return self.crc_errors + self.length_errors + self.truncated + self.bad_payloads

    def as_dict(self) -> dict[str, float | int]:
        """Every counter by name, ``errors`` included (what capture files and JSON reports keep)."""
        out = asdict(self)
        out["errors"] = self.errors
        return out

    def summary(self) -> str:
        """One line for a person: samples, rate, errors by kind, resyncs, garbage, lost, dropped."""
        skipped = f" ({self.seq_skipped} seq skipped by non-sample packets)" if self.seq_skipped else ""
        return (f"{self.samples} samples, {self.rate_hz:.1f} Hz, {self.errors} errors "
                f"({self.crc_errors} CRC, {self.truncated} truncated, {self.length_errors} length), "
                f"{self.resyncs} resyncs, {self.garbage_bytes} garbage bytes, {self.lost} lost{skipped}, "
                f"{self.overflow_drops} dropped (overflow)" + self._clock_summary())

    def _clock_summary(self) -> str:
        parts = []
        if self.seq_outliers:
            parts.append(f"{self.seq_outliers} seq outlier{'s' * (self.seq_outliers != 1)}")
        if self.clock_outliers:
            parts.append(f"{self.clock_outliers} clock outlier{'s' * (self.clock_outliers != 1)} (left out)")
        if self.clock_jumps:
            parts.append(f"{self.clock_jumps} clock jump{'s' * (self.clock_jumps != 1)}")
        return "".join(", " + p for p in parts)


class LinkMonitor:
    """Keeps :class:`LinkStats` up to date from decoded batches and the decoder's counters.

    Not thread-safe by itself: the device calls it under its own lock.
    """

    def __init__(self) -> None:
        self.stats = LinkStats()
        self._last_seq: int | None = None
        self._pending_seq: int | None = None  # after a large seq step, until the next sample says
        self._gaps = 0  # seq values missing between consecutive samples
        self._first_t_us: int | None = None
        self._window: deque[tuple[int, int]] = deque()  # (t_us of a batch's last sample, samples so far)

    def add_bytes(self, n: int) -> None:
        """Count ``n`` bytes read from the link."""
        self.stats.bytes += n

    def add_samples(self, samples: np.ndarray) -> None:
        """Count a batch of ``SAMPLE_DTYPE`` records: seq gaps, resets and the device-clock rate."""
        n = len(samples)
        if n == 0:
            return
        s = self.stats
        seq = samples["seq"].astype(np.int64)
        prev = np.empty(n, dtype=np.int64)
        prev[0] = seq[0] - 1 if self._last_seq is None else self._last_seq
        prev[1:] = seq[:-1]
        gap = (seq - prev - 1) % SEQ_MODULUS
        if self._pending_seq is None and (gap <= MAX_PLAIN_GAP).all():
            self._gaps += int(gap.sum())
            self._last_seq = int(seq[-1])
        else:
            for value in seq.tolist():
                self._one_seq(value)
        s.lost = max(0, self._gaps - s.seq_skipped)
        s.samples += n
        t_us = samples["t_us"]
        if self._first_t_us is None:
            self._first_t_us = int(t_us[0])
        t_last = int(t_us[-1])
        if self._window and t_last < self._window[-1][0]:
            # The clock went back (a restart, or the return from a wild timestamp): a window that
            # starts in the other clock would stop sliding, and the rate become a long average.
            self._window.clear()
        s.device_time_s = max(0.0, (t_last - self._first_t_us) * 1e-6)
        self._window.append((t_last, s.samples))
        while len(self._window) > 2 and (t_last - self._window[1][0]) * 1e-6 >= RATE_WINDOW_S:
            self._window.popleft()
        t0, n0 = self._window[0]
        if t_last > t0:
            s.rate_hz = (s.samples - n0) / ((t_last - t0) * 1e-6)

    def _one_seq(self, value: int) -> None:
        """The seq rule one sample at a time, when some step is large: a large step (forward
        beyond ``MAX_PLAIN_GAP``, or back) waits for the next sample. If that one continues from
        the sample before, the large step was an outlier (a wild counter, a replayed frame):
        counted in ``seq_outliers``, not as samples lost or a reset. Else it was real: a long
        gap of lost samples, or a reset when it went back."""
        s = self.stats
        last = self._last_seq
        if last is None:
            self._last_seq = value
            return
        pending = self._pending_seq
        if pending is not None:
            self._pending_seq = None
            step = (value - last) % SEQ_MODULUS
            if 1 <= step <= MAX_PLAIN_GAP + 1 or step == 0:
                s.seq_outliers += 1
                self._gaps += max(0, step - 2)  # the outlier took the place of one missing value
                self._last_seq = value
                return
            jump = (pending - last - 1) % SEQ_MODULUS
            if jump >= _SEQ_BACKWARDS:
                s.seq_resets += 1
            else:
                self._gaps += jump
            last = self._last_seq = pending
        gap = (value - last - 1) % SEQ_MODULUS
        if gap <= MAX_PLAIN_GAP:
            self._gaps += gap
            self._last_seq = value
        else:
            self._pending_seq = value

    def add_overflow(self, n: int) -> None:
        """Count ``n`` samples dropped because the consumer did not keep up."""
        self.stats.overflow_drops += n

    def update_decoder(self, dec: DecoderStats) -> None:
        """Copy the decoder's frame counters (CRC, length, truncation, resyncs, skipped seq) in."""
        s = self.stats
        s.crc_errors = dec.crc_errors
        s.resyncs = dec.resyncs
        s.garbage_bytes = dec.garbage_bytes
        s.length_errors = dec.length_errors
        s.truncated = dec.truncated
        s.bad_payloads = dec.bad_payloads
        s.seq_skipped = dec.seq_skipped
        s.lost = max(0, self._gaps - s.seq_skipped)
