"""Many units at 1 kHz on one station: CPU per unit, samples lost and the feed's backlog, against
today's design (one ``imu-station capture`` process per port) measured in the same run.

One feeder process serves every simulated unit on its own pty from precomputed frames
(``mocks.pty_fleet``: each unit's stream is encoded once, then copied to its pty on the clock),
so what is measured is the station. First ``--old-units`` units are captured the old way, one
``imu-station capture --port P -o FILE`` process each; then ``--units`` units by one
``imu-station capture --port P1 --port P2 ... -o DIR`` process. Each capture runs ``--seconds``
of device clock with its stderr on a terminal (a pty), so the live status lines are drawn as
an operator would see them. The station's CPU comes from ``/proc/PID/stat`` (user + system,
every thread): over the steady middle of the capture (start-up excluded) and for the whole
process. Samples lost: the rows each file lacks of the ``--seconds`` x rate due, and any gap in
its ``t``. Backlog: the most bytes that waited for the station at a feeder tick, also in
milliseconds of the unit's stream: what the pty's line buffer holds (FIONREAD sees at most its
4 KiB, so how often it was full is printed too) and what a full pty refused (the feed backing up).

    .venv/bin/python benchmarks/many_units.py [--units 32] [--old-units 4] [--rate 1000] [--seconds 30]
        [--format csv|h5] [--repeats 1] [--write-ms 10]

Each unit's frames reach its pty in writes of ``--write-ms`` of frames (10 ms by default: what a USB
serial adapter hands over, ten frames of a 1 kHz unit a write); ``--write-ms 0`` is the former feed
(whatever is due at each 10 ms tick of the feeder, in one write). The one-process figure is also
given against the 0.3-core target of issue 30 (``--target-cores``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from process_timing import cpu_s

from protocols.native import SAMPLE_FRAME_SIZE
from station.acquisition.capture import read_capture

ROOT = Path(__file__).resolve().parent.parent
START_UP_S = 4.0  # left out of the steady figure: imports, opening the ports, the first file writes
END_S = 3.0  # left out at the end: the last writes and closing

FLEET = """
import json, sys
from mocks.device import SimDevice
from mocks.pty_fleet import FleetUnit, PtyFleet
units = [FleetUnit(SimDevice(seed=1000 + i, rate_hz={rate}), {stream_s}) for i in range({count})]
with PtyFleet(units, tick_s={tick_s}, watch_s={watch_s}, write_s={write_s}) as fleet:
    print(json.dumps(fleet.ports), flush=True)
    sys.stdin.read()  # until the benchmark closes our stdin
    print(json.dumps({{"late_ticks": fleet.late_ticks, "units": [vars(s) for s in fleet.stats]}}), flush=True)
"""


@dataclass
class Measured:
    """One capture process: CPU in the steady window and in all, wall seconds, exit code."""

    steady_cores: float
    total_cpu_s: float
    wall_s: float
    returncode: int


def watch(args: list[str], seconds: float) -> subprocess.Popen[bytes]:
    """Start a station process with its stderr on a pty (drained by a thread) and stdout to a pipe."""
    master, slave = os.openpty()
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=slave, cwd=ROOT)
    os.close(slave)

    def drain() -> None:
        try:
            while os.read(master, 65536):
                pass
        except OSError:
            pass
        os.close(master)

    threading.Thread(target=drain, daemon=True).start()
    return proc


def measure(procs: list[subprocess.Popen[bytes]], seconds: float) -> list[Measured]:
    """CPU of each process over the steady window, then until it exits (``os.wait4``'s rusage)."""
    started = time.monotonic()
    time.sleep(START_UP_S)
    first = [cpu_s(p.pid) for p in procs]
    t1 = time.monotonic()
    time.sleep(max(1.0, seconds - START_UP_S - END_S))
    second = [cpu_s(p.pid) for p in procs]
    t2 = time.monotonic()
    out = []
    for proc, a, b in zip(procs, first, second, strict=True):
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.append(Measured((b - a) / (t2 - t1), usage.ru_utime + usage.ru_stime, time.monotonic() - started,
                            proc.returncode))
    return out


def loss(path: Path, due: int, period_us: int) -> tuple[int, int]:
    """(rows missing of ``due``, gaps in ``t``) of one capture file; a missing file lacks every row."""
    if not path.exists():
        return due, 0
    t_us = np.round(read_capture(path).t * 1e6).astype(np.int64)
    gaps = int(np.count_nonzero(np.diff(t_us) > period_us * 1.5))
    return max(0, due - len(t_us)), gaps


def station(*options: str) -> list[str]:
    """The command line of ``imu-station`` with ``options``."""
    return [sys.executable, "-m", "station", "capture", *options]


def run_once(args: argparse.Namespace, out: Path) -> dict[str, float]:
    """One run: the old design on ``--old-units``, then the one-process capture on ``--units``."""
    count = args.old_units + args.units
    if args.write_ms > 0:  # writes of --write-ms of frames each, on a feeder tick of half that
        tick_s, write_s = args.write_ms / 2000, args.write_ms / 1000
    else:  # the former feed: every 10 ms tick, whatever is due in one write
        tick_s, write_s = 0.01, None
    fleet = subprocess.Popen([sys.executable, "-c", FLEET.format(rate=args.rate, stream_s=args.seconds + 3,
                                                                 watch_s=args.seconds - 0.5, count=count,
                                                                 tick_s=tick_s, write_s=write_s)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert fleet.stdout is not None and fleet.stdin is not None
    ports = json.loads(fleet.stdout.readline())
    old_ports, new_ports = ports[: args.old_units], ports[args.old_units :]
    suffix = ".csv" if args.format == "csv" else ".h5"
    duration = f"{args.seconds:g}"

    old_dir = out / f"old-{args.format}"
    old_dir.mkdir()
    old = measure([watch(station("--port", p, "--duration", duration, "-o", str(old_dir / f"{i}{suffix}")),
                         args.seconds) for i, p in enumerate(old_ports)], args.seconds) if old_ports else []
    new_dir = out / f"new-{args.format}"
    fleet_cpu1 = cpu_s(fleet.pid)
    new_started = time.monotonic()
    new_args = [a for p in new_ports for a in ("--port", p)]
    (new,) = measure([watch(station(*new_args, "--duration", duration, "--format", args.format, "-o",
                                    str(new_dir)), args.seconds)], args.seconds)
    fleet_cores = (cpu_s(fleet.pid) - fleet_cpu1) / (time.monotonic() - new_started)
    fleet.stdin.close()
    report = json.loads(fleet.stdout.readline())
    fleet.wait()

    due = int(round(args.seconds * args.rate))
    period_us = int(round(1e6 / args.rate))
    old_loss = [loss(old_dir / f"{i}{suffix}", due, period_us) for i in range(args.old_units)]
    new_files = sorted(new_dir.glob(f"*{suffix}"))
    new_loss = [loss(f, due, period_us) for f in new_files]
    new_loss += [(due, 0)] * (args.units - len(new_files))
    units = report["units"]
    frame_ms = 1000.0 / (args.rate * SAMPLE_FRAME_SIZE)
    new_units = units[args.old_units :]
    return {
        "old_cores_per_unit": statistics.fmean(m.steady_cores for m in old) if old else math.nan,
        "old_total_cpu_s_per_unit": statistics.fmean(m.total_cpu_s for m in old) if old else math.nan,
        "old_lost": sum(m for m, _ in old_loss), "old_gaps": sum(g for _, g in old_loss),
        "old_failed": sum(m.returncode != 0 for m in old),
        "new_cores": new.steady_cores, "new_cores_per_unit": new.steady_cores / args.units,
        "new_total_cpu_s": new.total_cpu_s, "new_wall_s": new.wall_s, "new_returncode": new.returncode,
        "new_lost": sum(m for m, _ in new_loss), "new_gaps": sum(g for _, g in new_loss),
        "new_files": len(new_files),
        "max_backlog_bytes": max(u["max_backlog_bytes"] for u in new_units),
        "max_backlog_ms": max(u["max_backlog_bytes"] for u in new_units) * frame_ms,
        "max_unwritten_bytes": max(u["max_unwritten_bytes"] for u in new_units),
        "full_line_share": sum(u["full_line_ticks"] for u in new_units)
        / max(1, sum(u["watched_ticks"] for u in new_units)),
        "fleet_cores": fleet_cores, "fleet_late_ticks": report["late_ticks"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--units", type=int, default=32, help="units captured by one process (default 32)")
    parser.add_argument("--old-units", type=int, default=4,
                        help="units captured the old way, one process each (default 4)")
    parser.add_argument("--rate", type=int, default=1000, help="sample rate in Hz (default 1000)")
    parser.add_argument("--seconds", type=float, default=30.0, help="seconds of device clock (default 30)")
    parser.add_argument("--format", choices=("csv", "h5"), default="csv", help="capture files (default csv)")
    parser.add_argument("--repeats", type=int, default=1, help="runs; medians are printed (default 1)")
    parser.add_argument("--write-ms", type=float, default=10.0,
                        help="each unit's frames handed over in writes of this many ms of frames, as a USB "
                             "serial adapter does (default 10); 0: the former feed, everything due at each "
                             "10 ms tick of the feeder in one write")
    parser.add_argument("--target-cores", type=float, default=0.3,
                        help="the one-process capture's target in cores (default 0.3, issue 30)")
    args = parser.parse_args()

    load_before = os.getloadavg()[0]
    runs = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            runs.append(run_once(args, Path(tmp)))

    def med(key: str) -> float:
        return statistics.median(r[key] for r in runs)

    feed = (f"writes of {args.write_ms:g} ms of frames" if args.write_ms > 0
            else "the former feed (everything due at each 10 ms tick, one write)")
    print(f"{args.units} units + {args.old_units} old-design units at {args.rate} Hz, {args.seconds:g} s of "
          f"device clock, {args.format}, {feed}; medians of {len(runs)} run(s); a 2-core machine shared "
          f"with others (load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after)")
    print(f"  one process, {args.units} units:  {med('new_cores'):.3f} cores in the steady window "
          f"({med('new_cores_per_unit'):.4f} per unit), {med('new_total_cpu_s'):.2f} CPU-s in all for "
          f"{med('new_wall_s'):.1f} s wall (start-up included), exit {int(med('new_returncode'))}")
    print(f"  target: {args.target_cores:g} of a core for {args.units} units, 0 lost: "
          f"{med('new_cores') / args.target_cores:.2f}x the target's cores, {int(med('new_lost'))} lost")
    print(f"  lost: {int(med('new_lost'))} samples missing, {int(med('new_gaps'))} gaps in t, "
          f"{int(med('new_files'))} of {args.units} files")
    print(f"  backlog: at most {int(med('max_backlog_bytes'))} bytes seen waiting for the station "
          f"({med('max_backlog_ms'):.1f} ms of a unit's stream); the pty's 4 KiB line buffer was full at "
          f"{med('full_line_share') * 100:.3f} % of the unit-ticks; the feed backed up by "
          f"{int(med('max_unwritten_bytes'))} bytes (0: a pty never filled, so no unit ever waited "
          f"~0.4 s)")
    print(f"  feeder: {med('fleet_cores'):.3f} cores, {int(med('fleet_late_ticks'))} late ticks")
    if args.old_units == 0:
        return
    print(f"  old design, one process per unit ({args.old_units} units): {med('old_cores_per_unit'):.4f} "
          f"cores per unit in the steady window, {med('old_total_cpu_s_per_unit'):.2f} CPU-s per unit in "
          f"all; lost {int(med('old_lost'))}, gaps {int(med('old_gaps'))}, {int(med('old_failed'))} failed")
    ratio = med("old_cores_per_unit") / med("new_cores_per_unit")
    print(f"  ratio: the old design costs {ratio:.1f}x the CPU per unit; {args.units} units the old way "
          f"would need ~{med('old_cores_per_unit') * args.units:.2f} cores")


if __name__ == "__main__":
    main()
