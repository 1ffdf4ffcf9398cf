"""``imu-station demo``: the station's main job on the simulated unit, with no hardware and no arguments.

The demo is a list of steps (:data:`STEPS`) run in order over one :class:`DemoContext`. Each step
reads what earlier steps left in the context and adds its own results; resources (the simulated
unit, open ports) go on the context's exit stack and are released at the end, whatever happens.
A later capability extends the demo by appending its step, e.g. a calibration step that reads
``ctx.capture_path`` and writes the parameter file into ``ctx.out_dir``.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from station.acquisition.recorder import CaptureResult
from station.errors import StationError

NAME = "demo"
HELP = "run the station on a simulated unit: no hardware, no arguments needed"
DESCRIPTION = """\
Run the station's main job on a simulated unit, with no hardware: start the simulated IMU on a
pseudo-terminal (a real serial port path, the native protocol on the wire), capture a few
seconds from it through the same driver a real unit uses, check every captured sample against
what the simulator sent, and report the link statistics. Files go to --out (default ./demo-out)."""
EPILOG = """\
examples:
  imu-station demo
  imu-station demo --seconds 10 --rate 1000 --out /tmp/demo"""


@dataclass
class DemoContext:
    """What the steps share: settings, the simulated unit, and each step's results."""

    out_dir: Path
    seed: int = 1
    rate_hz: int = 200
    seconds: float = 5.0
    scenario: str = "still"
    out: IO[str] = field(default_factory=lambda: sys.stdout)
    err: IO[str] = field(default_factory=lambda: sys.stderr)
    stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack)
    server: Any = None  # mocks.pty_server.PtyServer once started
    port: str = ""
    capture_path: Path | None = None
    capture: CaptureResult | None = None
    results: dict[str, Any] = field(default_factory=dict)  # figures each step reports

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)


Step = Callable[[DemoContext], None]


def start_simulated_unit(ctx: DemoContext) -> None:
    """A random MEMS unit (seeded) on a pseudo-terminal, streaming the native protocol."""
    from mocks.pty_server import PtyServer

    ctx.server = ctx.stack.enter_context(
        PtyServer(seed=ctx.seed, rate_hz=ctx.rate_hz, scenario=ctx.scenario, record=True))
    ctx.port = ctx.server.port_path
    info = ctx.server.device.info()
    ctx.say(f"    simulated unit {info['serial']} ({info['model']}) on {ctx.port}, {ctx.rate_hz} Hz, "
            f"scenario '{ctx.scenario}'")


def capture_samples(ctx: DemoContext) -> None:
    """Capture ``ctx.seconds`` of device clock into ``out_dir/capture.h5``, as `imu-station capture` does."""
    from station.commands.capture import capture_to_file

    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    ctx.capture_path = ctx.out_dir / "capture.h5"
    ctx.capture = capture_to_file(ctx.port, ctx.capture_path, duration_s=ctx.seconds, rate_hz=ctx.rate_hz,
                                  err=ctx.err)
    if ctx.capture.error is not None:
        raise ctx.capture.error
    ctx.say(f"    wrote {ctx.capture.rows} samples ({ctx.capture.device_time_s:.2f} s of device clock) to "
            f"{ctx.capture_path}")


def verify_capture(ctx: DemoContext) -> None:
    """Every sample in the file must be, bit for bit, one the simulator sent, none missing between."""
    from station.acquisition.capture_h5 import read_samples

    assert ctx.capture_path is not None
    got = read_samples(ctx.capture_path)
    sent = ctx.server.sent()
    k = int(np.searchsorted(sent["t_us"], got["t_us"][0])) if len(got) else 0
    exact = len(got) > 0 and got.tobytes() == sent[k:k + len(got)].tobytes()
    ctx.results["verified"] = exact
    if not exact:
        raise DemoFailed(f"{ctx.capture_path}: the captured samples differ from those the simulator sent")
    ctx.say(f"    all {len(got)} samples equal, bit for bit, those the simulator sent (from its sample {k})")


def report_link(ctx: DemoContext) -> None:
    """The link statistics of the capture, and the simulator's own count."""
    assert ctx.capture is not None
    link = ctx.capture.link
    ctx.results["link"] = link.as_dict()
    rows = [
        ("samples received", f"{link.samples}"),
        ("rate (device clock)", f"{link.rate_hz:.2f} Hz"),
        ("bytes", f"{link.bytes}"),
        ("damaged frames", f"{link.errors} ({link.crc_errors} CRC, {link.truncated} truncated, "
                           f"{link.length_errors} length)"),
        ("resyncs / garbage bytes", f"{link.resyncs} / {link.garbage_bytes}"),
        ("lost (seq gaps)", f"{link.lost}"),
        ("dropped (slow consumer)", f"{link.overflow_drops}"),
        ("samples the simulator sent", f"{ctx.server.stats.samples_sent}"),
    ]
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        ctx.say(f"    {name:<{width}}  {value}")


# --- calibration step (issue 3) -----------------------------------------------------------------

def calibrate_unit(ctx: DemoContext) -> None:
    """A twelve-position + rotation calibration of the same simulated unit, recovered against true.

    The labelled sequence (about 4 minutes of device time) is generated with ``mocks.rig.simulate``
    rather than captured over the pty in real time, so the demo stays short.
    """
    from mocks.rig import sequence_segments, simulate
    from station.acquisition.capture_csv import write_csv
    from station.engines.calibration_turntable import calibrate_turntable
    from station.export.params_file import ParamsFile

    truth = ctx.server.device.truth
    segments = sequence_segments("twelve-position", True, hold_s=10.0)
    rec = simulate(truth, segments, rate_hz=100.0, seed=ctx.seed)
    capture = rec.to_capture()
    csv_path = ctx.out_dir / "twelve-position.csv"
    write_csv(csv_path, capture)
    ctx.say(f"    twelve poses of 10 s + six 360 deg turns, {len(rec.t)} samples at 100 Hz generated by the "
            f"simulator (not over the pty: it would take {rec.t[-1]:.0f} s in real time) -> {csv_path}")
    report = calibrate_turntable(capture.t, capture.acc, capture.gyro, capture.step, truth.gravity)
    params = ParamsFile()
    params.update_device(capture.device)
    params.accel, params.gyro = report.accel, report.gyro
    params_path = ctx.out_dir / "params.yaml"
    params.save(params_path)
    ctx.say(f"    {'':22s} {'recovered':>36s}   {'true':>36s}   max |error|")
    errors = {}
    for name, cal, tr in (("accel", report.accel, truth.accel), ("gyro", report.gyro, truth.gyro)):
        for what, got, true in (("scale", cal.scale, tr.scale), ("bias", cal.bias, tr.bias),
                                ("misalignment S_yx S_zx S_zy", cal.misalignment[[1, 2, 2], [0, 0, 1]],
                                 tr.misalignment[[1, 2, 2], [0, 0, 1]])):
            err = float(np.abs(got - true).max())
            errors[f"{name} {what}"] = err
            row = f"{name} {what.split()[0]}"
            ctx.say(f"    {row:22s} {_vec(got):>36s}   {_vec(true):>36s}   {err:.1e}")
    ctx.results["calibration"] = errors
    ctx.say(f"    parameter file: {params_path}")


def _vec(v: np.ndarray) -> str:
    return " ".join(f"{x:+.6f}" for x in v)


STEPS: list[tuple[str, Step]] = [
    ("start the simulated unit", start_simulated_unit),
    ("capture from it", capture_samples),
    ("verify the capture", verify_capture),
    ("report the link", report_link),
    ("calibrate the unit (twelve positions + rotations)", calibrate_unit),
]


class DemoFailed(StationError):
    """A demo check did not hold (a bug: the demo runs on a clean simulated link)."""


def run_demo(ctx: DemoContext, steps: list[tuple[str, Step]] | None = None) -> DemoContext:
    """Run ``steps`` (default :data:`STEPS`) in order; resources are released at the end."""
    steps = STEPS if steps is None else steps
    with ctx.stack:
        for number, (title, step) in enumerate(steps, 1):
            ctx.say(f"[{number}/{len(steps)}] {title}")
            step(ctx)
    return ctx


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("demo-out"), metavar="DIR",
                        help="folder for the demo's files (default: ./demo-out)")
    parser.add_argument("--seconds", type=float, default=5.0, help="seconds to capture (default: 5)")
    parser.add_argument("--rate", type=int, default=200, metavar="HZ", help="sample rate (default: 200)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the simulated unit (default: 1)")


def run(args: argparse.Namespace) -> int:
    ctx = DemoContext(out_dir=args.out, seed=args.seed, rate_hz=args.rate, seconds=args.seconds)
    run_demo(ctx)
    ctx.say(f"demo done: files in {ctx.out_dir}/")
    return 0
