"""The sequence runner's cost per second of 1 kHz data, against the plain capture recorder.

    .venv/bin/python benchmarks/runner.py [--rate 1000] [--repeats 3]

Both consume the same simulated recording (six-position + six rotations of a random MEMS unit,
mocks.rig.simulate) from an in-memory device that hands out 10 ms batches as fast as they are
read, and stream it into a capture CSV: ``record`` (``imu-station capture``'s loop) only writes,
the runner also runs the live checks on every batch, integrates the turns, posts the operator's
status (20 Hz of device time would be real time; here every batch is checked) and labels the
steps. The figures are CPU seconds per second of data (medians of the repeats) and how many
times faster than real time each runs: the margin that lets the runner keep up at 1 kHz while
the UI renders in the same process.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.errors import PortLost
from drivers.interface import Device
from drivers.link_stats import LinkMonitor, LinkStats
from mocks.rig import Move, Rotation, Static, simulate
from mocks.truth import UnitTruth
from station.acquisition.operator import BaseOperator
from station.acquisition.recorder import Recorder, record
from station.acquisition.runner import RecorderSink, RunOptions, SequenceRunner
from station.acquisition.sequences import builtin

BATCH_S = 0.01


class ReplayDevice(Device):
    """Serves a recording's samples in fixed batches, as fast as they are read; then reports closed."""

    port = "replay://"
    protocol = "native"

    def __init__(self, samples: np.ndarray, rate_hz: float):
        self.samples = samples
        self.batch = max(1, int(round(BATCH_S * rate_hz)))
        self.pos = 0
        self.monitor = LinkMonitor()
        self._info = {"serial": "SIM-BENCH", "model": "imu-sim", "firmware": "1.0.0", "rate_hz": rate_hz}

    def read(self, timeout: float | None = None) -> np.ndarray:
        if self.pos >= len(self.samples):
            # The end of the recording is the end of the link: both loops stop as on an unplugged unit.
            raise PortLost("end of the recording", self.port)
        out = self.samples[self.pos:self.pos + self.batch]
        self.pos += len(out)
        self.monitor.add_samples(out)
        return out

    @property
    def stats(self) -> LinkStats:
        return self.monitor.stats

    @property
    def info(self) -> dict:
        return self._info

    @property
    def closed(self) -> bool:
        return self.pos >= len(self.samples)

    def get_info(self, timeout: float = 1.0) -> dict:
        return self._info

    def set_rate(self, rate_hz: int, timeout: float = 1.0) -> None:
        raise NotImplementedError

    def start(self, timeout: float = 1.0) -> None:
        pass

    def stop(self, timeout: float = 1.0) -> None:
        pass

    def close(self) -> None:
        self.pos = len(self.samples)


def session_segments(hold_s: float) -> list:
    """The sequence as a person would do it: move, hold a little longer than asked, turn."""
    segments: list = []
    seq = builtin("six-position", hold_s=hold_s)
    for step in seq.steps:
        segments.append(Move(1.0))
        if step.kind == "pose":
            segments.append(Static(step.label, hold_s + 2.0))
        else:
            axis = ("+" if step.angle_deg > 0 else "-") + "xyz"[step.axis]
            segments += [Static(step.start_pose, 3.0), Rotation(axis, 360.0, 90.0, settle_s=3.0)]
    return segments


def cpu(fn) -> float:
    start = time.process_time()
    fn()
    return time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    hold = 5.0
    rec = simulate(UnitTruth.random(1), session_segments(hold), rate_hz=args.rate, seed=1)
    samples = rec.samples()
    duration = float(rec.t[-1] - rec.t[0])
    seq = builtin("six-position", hold_s=hold)
    with tempfile.TemporaryDirectory() as tmp:
        def run_runner() -> None:
            device = ReplayDevice(samples, args.rate)
            recorder = Recorder(Path(tmp) / "runner.csv", device=device.info, with_step=True)
            result = SequenceRunner(device, seq, BaseOperator(), RunOptions(read_timeout_s=0),
                                    sink=RecorderSink(recorder, device)).run()
            recorder.close()
            assert result.accepted == seq.labels, (result.outcome, result.reason, result.accepted)

        def run_record() -> None:
            record(ReplayDevice(samples, args.rate), Path(tmp) / "record.csv", handle_sigint=False)

        times = {"record (capture only)": [], "sequence runner": []}
        for _ in range(args.repeats):
            times["record (capture only)"].append(cpu(run_record))
            times["sequence runner"].append(cpu(run_runner))
    print(f"{len(samples)} samples, {duration:.1f} s of data at {args.rate:g} Hz, "
          f"batches of {BATCH_S * 1e3:g} ms, {args.repeats} repeats (median CPU time)")
    base = statistics.median(times["record (capture only)"])
    for name, values in times.items():
        t = statistics.median(values)
        print(f"  {name:22s} {t:7.3f} s CPU  {t / duration * 1e3:6.2f} ms per s of data  "
              f"{duration / t:6.1f}x real time  ({t / base:.2f}x record)")


if __name__ == "__main__":
    main()
