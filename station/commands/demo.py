"""``imu-station demo``: the station's main job on the simulated unit, with no hardware and no arguments.

The demo is a list of steps (:data:`STEPS`) run in order over one :class:`DemoContext`. Each step
reads what earlier steps left in the context and adds its own results; resources (the simulated
unit, open ports) go on the context's exit stack and are released at the end, whatever happens.

Everything goes through the path a real unit takes: the simulated unit is served on a
pseudo-terminal (its device clock sped up, so minutes of sequence take seconds), the serial
driver reads it, the sequence runner walks the twelve-position + rotation sequence with a
simulated operator moving the unit, the recorder writes the labelled capture file, and the
calibration, the parameter file and the firmware export are the ones ``calibrate`` and
``export`` use. Only the last comparison looks at the simulator's truth.

Why this module is long: the demo is one story told in order (unit, capture, sequence,
calibration, export, comparison with the truth), each step a short function the next one reads;
splitting it would scatter the one page a newcomer reads to see the whole job.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from protocols.units import STANDARD_GRAVITY
from station.common.text import printable
from station.console.options import MAX_SPEED, SEED, SPEED, add_output_option, check_range, describe_range
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    import numpy as np
    from rich.progress import Progress, TaskID

    from drivers.link_stats import LinkStats
    from station.acquisition.operator import ScriptedOperator
    from station.acquisition.recorder import CaptureResult
    from station.acquisition.runner import LiveStatus, RunResult
    from station.engines.calibration.common import CalibrationReport
    from station.engines.shared.sensor_model import SensorCalibration

NAME = "demo"
HELP = "run the station on a simulated unit: no hardware, no arguments needed"
DESCRIPTION = """\
Run the station's main job on a simulated unit, with no hardware. The simulated IMU (a random
MEMS unit, seeded) is served on a pseudo-terminal: a real serial port path, the native protocol
on the wire, its device clock running --speed times faster than the wall clock. The demo
captures a few seconds from it and checks every sample against what the simulator sent; then
runs the twelve-position + rotation sequence with the sequence runner, a simulated operator
moving the unit as each step asks, into a labelled capture file; calibrates it (turntable
method), writes the parameter file, exports it for firmware (imu_calib.h/.c/.bin, compiled with
gcc as a check when gcc is there), and prints the recovered intrinsics against the simulator's
true ones, with the link statistics. Files go to --out (default ./demo-out)."""
EPILOG = """\
examples:
  imu-station demo
  imu-station demo --seed 7 --hold 20 --speed 10 --out /tmp/demo"""

# The sequence, as a careful operator runs it: 10 s per pose, 360 deg turns at 90 deg/s with 1 s
# still before and after. At x20 it takes about 10 s of wall clock.
HOLD_S = 10.0
ROTATION_RATE_DPS = 90.0
SETTLE_S = 1.0
DEMO_SPEED = 20.0
# Wall-clock seconds a step may wait for the unit before the run gives up (a stalled simulator).
STEP_TIMEOUT_S = 30.0
STATION_ID = "demo-station"


@dataclass
class DemoContext:
    """What the steps share: settings, the simulated unit, and each step's results."""

    out_dir: Path
    seed: int = 1
    rate_hz: int = 200
    seconds: float = 5.0
    scenario: str = "still"
    speed: float = DEMO_SPEED
    hold_s: float = HOLD_S
    rotation_rate_dps: float = ROTATION_RATE_DPS
    settle_s: float = SETTLE_S
    out: IO[str] = field(default_factory=lambda: sys.stdout)
    err: IO[str] = field(default_factory=lambda: sys.stderr)
    stack: contextlib.ExitStack = field(default_factory=contextlib.ExitStack)
    server: Any = None  # mocks.pty_server.PtyServer once started
    port: str = ""
    capture_path: Path | None = None
    capture: CaptureResult | None = None
    sequence_path: Path | None = None
    sequence_run: RunResult | None = None
    report: CalibrationReport | None = None
    params_path: Path | None = None
    links: dict[str, tuple[LinkStats, int]] = field(default_factory=dict)  # file name -> (stats, sent)
    files: list[tuple[Path, str]] = field(default_factory=list)  # every file written, with what it is
    results: dict[str, Any] = field(default_factory=dict)  # figures each step reports

    def say(self, text: str) -> None:
        """Print one line of the demo's story on :attr:`out`."""
        print(text, file=self.out, flush=True)

    def wrote(self, path: Path, what: str) -> None:
        """Note a file the demo wrote, with what it is, for the list at the end."""
        self.files.append((path, what))


Step = Callable[[DemoContext], None]


class DemoFailed(StationError):
    """A demo check did not hold (a bug: the demo runs on a clean simulated link)."""


# --- the simulated unit and a first capture ---------------------------------------------------------

def start_simulated_unit(ctx: DemoContext) -> None:
    """A random MEMS unit (seeded) on a pseudo-terminal, streaming the native protocol."""
    from mocks.pty_server import PtyServer

    ctx.server = ctx.stack.enter_context(PtyServer(seed=ctx.seed, rate_hz=ctx.rate_hz, scenario=ctx.scenario,
                                                   record=True, speed=ctx.speed))
    ctx.port = ctx.server.port_path
    info = ctx.server.device.info()
    ctx.say(f"    simulated unit {printable(info['serial'])} ({printable(info['model'])}) on {ctx.port}, "
            f"{ctx.rate_hz} Hz, "
            f"scenario '{ctx.scenario}', device clock x{ctx.speed:g}")


def capture_samples(ctx: DemoContext) -> None:
    """Capture ``ctx.seconds`` of device clock into ``out_dir/capture.h5``, as `imu-station capture` does."""
    from station.acquisition.port_capture import capture_to_file
    from station.console.status_line import CaptureStatusLine

    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    ctx.capture_path = ctx.out_dir / "capture.h5"
    sent_before = ctx.server.stats.samples_sent
    ctx.capture = capture_to_file(ctx.port, ctx.capture_path, duration_s=ctx.seconds, rate_hz=ctx.rate_hz,
                                  err=ctx.err, status=lambda seconds: CaptureStatusLine(ctx.err, seconds))
    if ctx.capture.error is not None:
        raise ctx.capture.error
    ctx.links[ctx.capture_path.name] = (ctx.capture.link, ctx.server.stats.samples_sent - sent_before)
    ctx.wrote(ctx.capture_path, f"{ctx.seconds:g} s still, as `imu-station capture` records it")
    ctx.say(f"    wrote {ctx.capture.rows} samples ({ctx.capture.device_time_s:.2f} s of device clock) to "
            f"{ctx.capture_path}")


def verify_capture(ctx: DemoContext) -> None:
    """Every sample in the file must be, bit for bit, one the simulator sent, none missing between."""
    import numpy as np

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


# --- the main job: the sequence, the calibration, the parameter file, the firmware export -------------

def run_sequence(ctx: DemoContext) -> None:
    """The twelve-position + rotation sequence through the driver, the runner and the recorder.

    A simulated operator moves the unit as each step asks (as ``tui --simulate`` and the factory
    do); the runner decides when the unit is in pose and still, captures each step and checks
    it; the recorder streams the labelled samples to ``out_dir/sequence.h5``.
    """
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from drivers import open_device
    from station.acquisition.operator import SimulatedOperator
    from station.acquisition.recorder import Recorder
    from station.acquisition.runner import RecorderSink, RunOptions, SequenceRunner
    from station.acquisition.sequences import builtin

    sequence = builtin("twelve-position", rotations=True, hold_s=ctx.hold_s,
                       rotation_rate_dps=ctx.rotation_rate_dps, settle_s=ctx.settle_s)
    ctx.out_dir.mkdir(parents=True, exist_ok=True)
    ctx.sequence_path = ctx.out_dir / "sequence.h5"
    ctx.say(f"    {sequence.name}: {len(sequence)} steps (poses of {ctx.hold_s:g} s, 360 deg turns at "
            f"{ctx.rotation_rate_dps:g} deg/s with {ctx.settle_s:g} s still before and after), "
            f"{sequence.nominal_duration_s:.0f} s of capture")
    sent_before = ctx.server.stats.samples_sent
    started = time.monotonic()
    progress = Progress(TextColumn("sequence"), BarColumn(), MofNCompleteColumn(),
                        TextColumn("{task.fields[status]}"), TimeElapsedColumn(),
                        console=Console(file=ctx.err), transient=False)
    with open_device(ctx.port) as device, progress:
        device.get_info()
        task = progress.add_task("sequence", total=len(sequence), status="starting")
        inner = _progress_operator(progress, task)
        operator = SimulatedOperator(ctx.server.device, inner, move_s=1.0)
        recorder = Recorder(ctx.sequence_path, device=device.info, with_step=True, port=device.port,
                            protocol=device.protocol)
        runner = SequenceRunner(device, sequence, operator, RunOptions(step_timeout_s=STEP_TIMEOUT_S),
                                sink=RecorderSink(recorder, device))
        try:
            result = runner.run()
        finally:
            # The link with the clock guard's counts (outliers left out, jumps), not the device's alone.
            recorder.close(runner.link_stats().as_dict())
        link = runner.link_stats()
        progress.update(task, completed=len(sequence), status=result.outcome)
    wall_s = time.monotonic() - started
    ctx.sequence_run = result
    ctx.links[ctx.sequence_path.name] = (link, ctx.server.stats.samples_sent - sent_before)
    ctx.wrote(ctx.sequence_path, "the labelled twelve-position + rotation capture")
    redone = [f"{s.label} x{s.attempts}" for s in result.steps if s.attempts > 1]
    if result.outcome != "completed" or result.accepted != sequence.labels:
        failed = [f"{s.label}: {s.status} ({'; '.join(s.problems)})" for s in result.steps if not s.ok]
        raise DemoFailed(f"the sequence ended '{result.outcome}' ({result.reason}); "
                         + ("; ".join(failed) or "no step failed"))
    ctx.results["sequence"] = {"device_s": link.device_time_s, "wall_s": wall_s, "samples": recorder.rows,
                               "redone": redone}
    ctx.say(f"    all {len(sequence)} steps accepted"
            + (f" (redone: {', '.join(redone)})" if redone else ", each at the first attempt")
            + f": {link.device_time_s:.1f} s of device clock in {wall_s:.1f} s of wall clock; "
            f"{recorder.rows} samples to {ctx.sequence_path}")


def _progress_operator(progress: Progress, task: TaskID) -> ScriptedOperator:
    """The factory's answers (go on, redo a failed step while offered), with the live state on a bar."""
    from station.acquisition.operator import FACTORY_ANSWERS, ScriptedOperator

    class ProgressOperator(ScriptedOperator):
        def status(self, status: LiveStatus) -> None:
            super().status(status)
            capturing = status.state.value in ("capturing", "settling")
            done = status.index + (status.progress if capturing else 0.0)
            label = f"{status.step.label:<5} {status.state.value}"
            if status.angle_deg is not None:
                label += f" {status.angle_deg:+4.0f} deg"
            progress.update(task, completed=done, status=label)

    return ProgressOperator(answers=FACTORY_ANSWERS)


def report_link(ctx: DemoContext) -> None:
    """The link statistics of every capture, and the simulator's own count of what it sent."""
    ctx.results["link"] = ctx.links[ctx.capture_path.name][0].as_dict() if ctx.capture_path else {}
    if ctx.sequence_path is not None and ctx.sequence_path.name in ctx.links:
        ctx.results["sequence_link"] = ctx.links[ctx.sequence_path.name][0].as_dict()

    def rows(link: LinkStats, sent: int) -> list[tuple[str, str]]:
        return [
            ("samples received", f"{link.samples}"),
            ("rate (device clock)", f"{link.rate_hz:.2f} Hz"),
            ("device clock span", f"{link.device_time_s:.2f} s"),
            ("bytes", f"{link.bytes}"),
            ("damaged frames", f"{link.errors} ({link.crc_errors} CRC, {link.truncated} truncated, "
                               f"{link.length_errors} length)"),
            ("resyncs / garbage bytes", f"{link.resyncs} / {link.garbage_bytes}"),
            ("lost (seq gaps)", f"{link.lost}"),
            ("dropped (slow consumer)", f"{link.overflow_drops}"),
            ("sent by the simulator", f"{sent} (while the port was open)"),
        ]

    if not ctx.links:
        ctx.say("    no capture yet: nothing to report")
        return
    columns = {name: rows(link, sent) for name, (link, sent) in ctx.links.items()}
    names = [name for name, _ in next(iter(columns.values()))]
    width = max(len(name) for name in names)
    cells = {name: [value for _, value in col] for name, col in columns.items()}
    widths = {name: max(len(name), *(len(v) for v in values)) for name, values in cells.items()}
    ctx.say(f"    {'':<{width}}  " + "  ".join(f"{name:<{widths[name]}}" for name in cells).rstrip())
    for i, row in enumerate(names):
        ctx.say(f"    {row:<{width}}  " + "  ".join(f"{cells[n][i]:<{widths[n]}}" for n in cells).rstrip())


def calibrate_unit(ctx: DemoContext) -> None:
    """The turntable method on the labelled capture read back from its file, as `calibrate` does;
    the accel and gyro sections, with the unit's info, go to ``out_dir/params.yaml``."""
    import numpy as np

    from station.acquisition.capture import read_capture
    from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
    from station.export.params.file import ParamsFile

    assert ctx.sequence_path is not None
    capture = read_capture(ctx.sequence_path)
    # The simulated site's gravity; on a real station it comes from --gravity or --latitude.
    gravity = ctx.server.device.truth.gravity
    rate = capture.device.get("rate_hz")
    # A capture without step labels is refused by TurntableCapture itself.
    data = TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step,
                            rate_hz=float(rate) if rate is not None else None)
    ctx.report = calibrate_turntable(data, TurntableSettings(gravity=gravity))
    report = ctx.report
    accel, gyro = _both_triads(report.accel, report.gyro, "the turntable calibration")
    labels = [label for label, _ in capture.segments()]
    ctx.say(f"    {len(capture)} samples read back, {len(labels)} labelled steps; g = {gravity:.5f} m/s^2")
    acc_rms = "not given" if accel.residual_rms is None else f"{accel.residual_rms:.2e} m/s^2"
    gyro_rms = "not given" if gyro.residual_rms is None else f"{np.degrees(gyro.residual_rms):.4f} deg"
    ctx.say(f"    accel: {accel.method}, residual RMS {acc_rms}")
    ctx.say(f"    gyro:  {gyro.method}, angle residual RMS {gyro_rms}")
    for warning in report.warnings:
        ctx.say(f"    warning: {warning}")
    params = ParamsFile()
    params.update_device(capture.device)
    params.accel, params.gyro = accel, gyro
    ctx.params_path = ctx.out_dir / "params.yaml"
    params.save(ctx.params_path)
    ctx.wrote(ctx.params_path, "the parameter file (device, accel, gyro)")
    ctx.say(f"    parameter file for {printable(params.device.get('serial'))}: {ctx.params_path}")


# The check the demo compiles with the export: load the blob, correct one raw sample with it and
# with the parameters linked in from the header; both must give the same numbers.
_C_CHECK = r"""
#include <stdio.h>
#include <stdlib.h>
#include "imu_calib.h"

static unsigned char blob[65536];

int main(int argc, char **argv) {
    imu_calib_t cal;
    float raw_acc[3], raw_gyro[3], acc[3], gyro[3], acc2[3], gyro2[3];
    size_t n;
    int i, code;
    FILE *f;
    if (argc != 8) return 2;
    f = fopen(argv[1], "rb");
    if (f == NULL) return 2;
    n = fread(blob, 1, sizeof blob, f);
    fclose(f);
    code = imu_calib_load(&cal, blob, n);
    printf("%d %s\n", code, imu_calib_strerror(code));
    if (code != IMU_CALIB_OK) return 1;
    for (i = 0; i < 3; i++) {
        raw_acc[i] = strtof(argv[2 + i], NULL);
        raw_gyro[i] = strtof(argv[5 + i], NULL);
    }
    imu_calib_apply(&cal, 25.0f, 0.0f, raw_acc, raw_gyro, acc, gyro);
    imu_calib_apply(&imu_calib_unit, 25.0f, 0.0f, raw_acc, raw_gyro, acc2, gyro2);
    for (i = 0; i < 3; i++) {
        if (acc[i] != acc2[i] || gyro[i] != gyro2[i]) return 3;
    }
    printf("%.9g %.9g %.9g %.9g %.9g %.9g\n", acc[0], acc[1], acc[2], gyro[0], gyro[1], gyro[2]);
    return 0;
}
"""
C_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]


def export_firmware(ctx: DemoContext) -> None:
    """imu_calib.h/.c/.bin into ``out_dir/firmware`` as `export --format c` writes them; with gcc,
    compile them and check that the blob corrects a raw sample as the station does."""
    # the compiler's tools load here, not at every start-up (--help included)
    import shutil
    import subprocess
    import tempfile

    import numpy as np

    from station.engines.shared.correction import apply_calibration
    from station.export.firmware.c_source import BLOB_NAME, write_c_export
    from station.export.params.file import ParamsFile
    from station.export.params.sections import g_sensitivity

    assert ctx.params_path is not None
    params = ParamsFile.load(ctx.params_path)
    fw_dir = ctx.out_dir / "firmware"
    fw_dir.mkdir(parents=True, exist_ok=True)
    for path in write_c_export(params, fw_dir, STATION_ID, int(time.time())):
        ctx.wrote(path, "firmware export (C99 header, source, parameter blob)")
    ctx.say(f"    wrote imu_calib.h, imu_calib.c, imu_calib.bin to {fw_dir}/ (station id '{STATION_ID}')")
    gcc = shutil.which("gcc")
    if gcc is None:
        ctx.results["firmware_check"] = None
        ctx.say("    gcc not found: the compile check is skipped")
        return
    # The unit lying +z up, turning at 90 deg/s about z: its raw reading from the simulator's truth.
    truth = ctx.server.device.truth
    true_acc = np.array([0.0, 0.0, truth.gravity])
    true_gyro = np.array([0.0, 0.0, np.radians(90.0)])
    raw_acc = (truth.accel.matrix @ true_acc + truth.accel.bias).astype(np.float32)
    raw_gyro = (truth.gyro.matrix @ true_gyro + truth.gyro.bias
                + truth.g_sensitivity @ true_acc).astype(np.float32)
    with tempfile.TemporaryDirectory(prefix="imu-demo-cc-") as tmp:
        check_c = Path(tmp) / "check.c"
        check_c.write_text(_C_CHECK, encoding="ascii")
        exe = Path(tmp) / "check"
        build = subprocess.run([gcc, *C_FLAGS, f"-I{fw_dir}", str(fw_dir / "imu_calib.c"), str(check_c),
                                "-lm", "-o", str(exe)], capture_output=True, text=True)
        if build.returncode != 0:
            raise DemoFailed(f"gcc could not compile the export in {fw_dir}: {build.stderr.strip()}")
        numbers = [f"{v:.9g}" for v in (*raw_acc, *raw_gyro)]
        ran = subprocess.run([str(exe), str(fw_dir / BLOB_NAME), *numbers], capture_output=True, text=True)
    lines = ran.stdout.splitlines()
    if ran.returncode != 0 or len(lines) != 2:
        raise DemoFailed(f"the compiled check failed on {fw_dir / BLOB_NAME} (exit {ran.returncode}): "
                         f"{ran.stdout.strip()} {ran.stderr.strip()}")
    c_out = np.array([float(x) for x in lines[1].split()])
    accel, gyro = _both_triads(params.accel, params.gyro, str(ctx.params_path))
    acc_out, gyro_out = apply_calibration(raw_acc[None, :].astype(float), raw_gyro[None, :].astype(float),
                                          accel_cal=accel, gyro_cal=gyro, g_sensitivity=g_sensitivity(params))
    station = np.concatenate([acc_out[0], gyro_out[0]])
    agreement = float(np.max(np.abs(c_out - station) / np.maximum(1.0, np.abs(station))))
    ctx.results["firmware_check"] = {"load": lines[0], "c": c_out.tolist(), "station": station.tolist(),
                                     "agreement": agreement}
    if agreement > 1e-5:
        raise DemoFailed(f"the compiled C and the station disagree by {agreement:.1e} (relative) on a sample")
    ctx.say(f"    compiled with gcc {' '.join(C_FLAGS)}; a check program loads imu_calib.bin "
            f"(imu_calib_load: {lines[0]})")
    ctx.say("    and corrects the raw reading of the unit lying +z up, turning at 90 deg/s about z:")
    ctx.say(f"      acc  ({_vec(c_out[:3], 5)}) m/s^2, true (0, 0, {truth.gravity:.5f})")
    ctx.say(f"      gyro ({_vec(c_out[3:], 5)}) rad/s, true (0, 0, {np.radians(90.0):.5f})")
    ctx.say(f"    the blob and the linked-in parameters give the same numbers; the station's own correction "
            f"agrees to {agreement:.0e}")


# --- the comparison with the simulator's truth ------------------------------------------------------

_OFF_DIAGONAL = ((1, 0), (2, 0), (2, 1), (0, 1), (0, 2), (1, 2))


def compare_with_truth(ctx: DemoContext) -> None:
    """Recovered scale, misalignment and bias of both triads against the simulator's true ones,
    with each error and the 1-sigma the calibration reported."""
    import numpy as np
    from rich import box
    from rich.console import Console
    from rich.table import Table

    assert ctx.report is not None
    truth = ctx.server.device.truth
    table = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False)
    for name in ("triad", "parameter", "recovered", "true", "error", "1-sigma", "|error|/sigma"):
        table.add_column(name, justify="left" if name in ("triad", "parameter") else "right")
    worst: dict[str, float] = {}
    ratios: list[float] = []
    accel, gyro = _both_triads(ctx.report.accel, ctx.report.gyro, "the turntable calibration")
    for triad, cal, tr in (("accel", accel, truth.accel), ("gyro", gyro, truth.gyro)):
        sd = cal.stddev
        entries = [(f"scale {'xyz'[i]}", "scale", cal.scale[i], tr.scale[i], sd["scale"][i])
                   for i in range(3)]
        entries += [(f"S {'xyz'[i]}{'xyz'[j]}", "misalignment", cal.misalignment[i, j], tr.misalignment[i, j],
                     np.asarray(sd["misalignment"])[i, j]) for i, j in _OFF_DIAGONAL]
        entries += [(f"bias {'xyz'[i]}", "bias", cal.bias[i], tr.bias[i], sd["bias"][i]) for i in range(3)]
        for row, (label, group, got, true, sigma) in enumerate(entries):
            error = float(got - true)
            ratio = abs(error) / float(sigma)
            ratios.append(ratio)
            key = f"{triad} {group}"
            worst[key] = max(worst.get(key, 0.0), abs(error))
            table.add_row(triad if row == 0 else "", label, f"{got:+.6f}", f"{true:+.6f}", f"{error:+.1e}",
                          f"{sigma:.1e}", f"{ratio:.1f}")
        table.add_section()
    ctx.say("    scale: raw per true; misalignment S (row, column): rad; bias: m/s^2 (accel), rad/s (gyro)")
    rendered = io.StringIO()
    Console(file=rendered, width=120).print(table)
    for line in rendered.getvalue().splitlines():
        ctx.say(f"    {line}".rstrip())
    within = sum(r <= 3.0 for r in ratios)
    ctx.results["calibration"] = worst
    ctx.results["sigma_ratios"] = ratios
    g = STANDARD_GRAVITY
    ctx.say(f"    largest errors: accel scale {worst['accel scale'] * 1e6:.0f} ppm, misalignment "
            f"{worst['accel misalignment'] * 1e6:.0f} urad, bias {worst['accel bias'] / g * 1e6:.0f} ug; "
            f"gyro scale {worst['gyro scale'] * 1e6:.0f} ppm,")
    ctx.say(f"    misalignment {worst['gyro misalignment'] * 1e6:.0f} urad, bias "
            f"{np.degrees(worst['gyro bias']) * 3600:.1f} deg/h; {within} of {len(ratios)} errors within "
            f"3 sigma (largest {max(ratios):.1f} sigma)")


def list_files(ctx: DemoContext) -> None:
    """Every file the demo wrote, with its size."""
    width = max(len(str(path)) for path, _ in ctx.files)
    for path, what in ctx.files:
        ctx.say(f"    {str(path):<{width}}  {_size(path.stat().st_size):>9}  {what}")


def _both_triads(accel: SensorCalibration | None, gyro: SensorCalibration | None,
                 where: str) -> tuple[SensorCalibration, SensorCalibration]:
    if accel is None or gyro is None:
        raise DemoFailed(f"{where} has no {'accel' if accel is None else 'gyro'} calibration")
    return accel, gyro


def _size(n: int) -> str:
    return f"{n} B" if n < 1024 else f"{n / 1024:.1f} KiB" if n < 1024**2 else f"{n / 1024**2:.1f} MiB"


def _vec(v: np.ndarray, digits: int) -> str:

    return ", ".join(f"{x:+.{digits}f}" for x in v)


STEPS: list[tuple[str, Step]] = [
    ("start the simulated unit", start_simulated_unit),
    ("capture from it", capture_samples),
    ("verify the capture", verify_capture),
    ("run the twelve-position + rotation sequence", run_sequence),
    ("report the link", report_link),
    ("calibrate (turntable method) and write the parameter file", calibrate_unit),
    ("export for firmware (C) and compile it", export_firmware),
    ("compare recovered against true", compare_with_truth),
    ("files written", list_files),
]


def run_demo(ctx: DemoContext, steps: list[tuple[str, Step]] | None = None) -> DemoContext:
    """Run ``steps`` (default :data:`STEPS`) in order; resources are released at the end.

    ``ctx.results["step_s"]`` gets the wall-clock seconds of each step, by title.

    Parameters
    ----------
    ctx : DemoContext
        Settings and, as the steps run, their results.
    steps : list of (title, step), optional
        The steps to run; default all of :data:`STEPS`.

    Returns
    -------
    DemoContext
        ``ctx``, with every step's results.
    """
    steps = STEPS if steps is None else steps
    timings = ctx.results.setdefault("step_s", {})
    with ctx.stack:
        for number, (title, step) in enumerate(steps, 1):
            ctx.say(f"[{number}/{len(steps)}] {title}")
            started = time.monotonic()
            step(ctx)
            timings[title] = time.monotonic() - started
    return ctx


MAX_STEP_S = 600.0  # the longest pose or first capture the demo takes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the demo's options to ``parser`` (each range-checked when the demo starts)."""
    add_output_option(parser, dest="out", default=Path("demo-out"), metavar="DIR",
                      help="folder for the demo's files (default: ./demo-out)")
    parser.add_argument("--seconds", type=float, default=5.0, metavar="S",
                        help="seconds of device clock in the first capture, "
                             f"{describe_range(0, MAX_STEP_S, low_open=True)} (default: 5)")
    parser.add_argument("--rate", type=int, default=200, metavar="HZ", help="sample rate (default: 200)")
    parser.add_argument("--seed", type=SEED, default=1, help="seed of the simulated unit (default: 1)")
    parser.add_argument("--hold", type=float, default=HOLD_S, metavar="S",
                        help=f"seconds of each pose of the sequence (default: {HOLD_S:g})")
    parser.add_argument("--speed", type=SPEED, default=DEMO_SPEED, metavar="X",
                        help=f"the simulated unit's clock runs X times faster than the wall clock, at most "
                             f"{MAX_SPEED:g} (default: {DEMO_SPEED:g})")


def run(args: argparse.Namespace) -> int:
    """Run every step of the demo (:data:`STEPS`) and say where its files are."""
    from mocks.device import MAX_RATE_HZ, MIN_RATE_HZ

    check_range("--rate", args.rate, MIN_RATE_HZ, MAX_RATE_HZ, unit="Hz, the simulated unit's rates")
    check_range("--hold", args.hold, 0.0, MAX_STEP_S, low_open=True, unit="s", what="seconds per pose")
    check_range("--seconds", args.seconds, 0.0, MAX_STEP_S, low_open=True, unit="s",
                what="a capture length")
    started = time.monotonic()
    ctx = DemoContext(out_dir=args.out, seed=args.seed, rate_hz=args.rate, seconds=args.seconds,
                      speed=args.speed, hold_s=args.hold)
    run_demo(ctx)
    ctx.say(f"demo done in {time.monotonic() - started:.1f} s: files in {ctx.out_dir}/")
    return ExitCode.OK
