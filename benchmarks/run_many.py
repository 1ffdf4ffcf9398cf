"""CPU per unit of the TUI's live view and of run-many's units: the threaded reader (before) against the
paced polled port (after), measured side by side in one run.

**TUI live view.** One simulated 1 kHz unit is served on a pty by a feeder process
(``mocks.pty_fleet``) that writes each frame as it is due, every ``--tick-ms`` (1 ms: as a unit on
a USB link sends it); ``imu-station tui --port PTY`` runs in a terminal of its own (a pty,
120x40, drawn as an operator sees it), connects, is taken to the live screen with Enter and left
there; its CPU (``/proc/PID/stat``, every thread) is taken over ``--seconds``. Before: the session's
device constructed as the threaded ``SerialDevice`` and the live view's old rates (20 snapshots a
second, the traces redrawn with each); then the threaded device at today's rates (what the reader
alone saves); after: the TUI as it is (``drivers.paced_port``).

**run-many's units.** What run-many starts for each unit is one ``imu-station run --port P
--table-port T`` process; ``--units`` of them run at once on simulated units and tables served
by one feeder process (``mocks.pty_server`` with ``--tick-ms`` blocks and ``mocks.turntable_sim``),
the plan's rate 1 kHz. The CPU of the ``run`` processes over the whole run (``os.wait4``: start-up,
sequence, calibration, export), divided by the units; before: each unit's port opened as a
``SerialDevice``.

The "before" processes are the same command with the old device (and rates) put in place by a
few lines run first (``THREADED``, ``OLD_RATES``). Figures are medians of ``--repeats``; the
variants interleave, so that the load of a shared machine touches them alike. On a loaded machine
a variant that wants more CPU than it gets is measured at what it got: the TUI's "before" wants
far more (see docs/workflows/tui.md).

    .venv/bin/python benchmarks/run_many.py [--part both|tui|run-many] [--units 4] [--repeats 3]
        [--seconds 10] [--tick-ms 1]
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time
from pathlib import Path

from factory import SEQUENCE  # the factory benchmark's sequence: six poses and three turns
from process_timing import cpu_s

ROOT = Path(__file__).resolve().parent.parent
TUI_SETTLE_S = 3.0  # after Enter: the live screen mounted and drawing

# Run before the command in a "before" process: the unit's port opened as the threaded device.
THREADED = """
import drivers.paced_port as paced
from drivers.serial_device import SerialDevice
paced.open_paced = lambda port, protocol="native", baudrate=921600: SerialDevice(port, protocol, baudrate)
import station.tui.session, station.factory.run
station.tui.session.open_paced = paced.open_paced
station.factory.run.open_paced = paced.open_paced
"""
# ... and the live view's snapshots as they were: 20 a second, the traces redrawn with each.
OLD_RATES = """
import station.tui.screens.live
station.tui.screens.live.UI_RATE_HZ = 20.0
station.tui.screens.live.PLOT_RATE_HZ = 1000.0
"""
COMMAND = """
import sys
{before}
from station.cli import main
sys.exit(main(sys.argv[1:]))
"""

TUI_FEEDER = """
import json, sys
from mocks.device import SimDevice
from mocks.pty_fleet import FleetUnit, PtyFleet
with PtyFleet([FleetUnit(SimDevice(seed=7, rate_hz=1000), {stream_s})], tick_s={tick_s}) as fleet:
    print(json.dumps(fleet.ports), flush=True)
    sys.stdin.read()
"""

RIG_FEEDER = """
import json, sys
from contextlib import ExitStack
from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from mocks.truth import UnitTruth
from mocks.turntable_sim import TurntableSim
with ExitStack() as stack:
    ports = []
    for i in range({units}):
        device = SimDevice(UnitTruth.random(200 + i), seed=200 + i, rate_hz=1000, scenario="still")
        server = stack.enter_context(PtyServer(device, block_s={tick_s}))
        table = stack.enter_context(TurntableSim(server.device))
        ports.append([server.port_path, table.port_path])
    print(json.dumps(ports), flush=True)
    sys.stdin.read()
"""

PLAN = """\
schema: imu-station/plan/1
name: bench-one-loop
sequence: {file: seq.yaml}
device: {rate_hz: 1000}
run: {timeout_s: 300, step_timeout_s: 30}
limits:
  accel.bias: {max_abs: 80, unit: mg}
export: [json]
"""

def station(before: str, *args: str) -> list[str]:
    """The command line of ``imu-station ARGS``, with ``before`` run first (the old device, rates)."""
    return [sys.executable, "-c", COMMAND.format(before=before), *args]


def feeder(script: str) -> tuple[subprocess.Popen[str], object]:
    """Start a feeder process; returns it and what it printed first (its ports, as JSON)."""
    proc = subprocess.Popen([sys.executable, "-c", script], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, cwd=ROOT)
    assert proc.stdout is not None
    return proc, json.loads(proc.stdout.readline())


def stop(proc: subprocess.Popen[str]) -> None:
    """End a feeder (it ends when its stdin closes)."""
    assert proc.stdin is not None
    proc.stdin.close()
    proc.wait(timeout=30)


def tui_cores(before: str, seconds: float, tick_s: float) -> float:
    """Cores the TUI uses idle on the live screen of a 1 kHz unit (a terminal of 120x40)."""
    fleet, ports = feeder(TUI_FEEDER.format(stream_s=seconds + 20, tick_s=tick_s))
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    screen = bytearray()

    def drain() -> None:
        try:
            while data := os.read(master, 65536):
                screen.extend(data)
                del screen[:-200_000]
        except OSError:
            pass

    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": "120", "LINES": "40"}
    proc = subprocess.Popen(station(before, "tui", "--port", ports[0]), stdin=slave, stdout=slave,
                            stderr=slave, cwd=ROOT, env=env, start_new_session=True)
    os.close(slave)
    threading.Thread(target=drain, daemon=True).start()
    try:
        deadline = time.monotonic() + 30
        while b"Connected" not in screen:
            if time.monotonic() > deadline or proc.poll() is not None:
                raise SystemExit("the TUI did not connect:\n" + screen[-2000:].decode(errors="replace"))
            time.sleep(0.2)
        os.write(master, b"\r")
        time.sleep(TUI_SETTLE_S)
        if b"time (s)" not in screen:
            raise SystemExit("the TUI did not show the live view:\n"
                             + screen[-3000:].decode(errors="replace"))
        first, t1 = cpu_s(proc.pid), time.monotonic()
        time.sleep(seconds)
        cores = (cpu_s(proc.pid) - first) / (time.monotonic() - t1)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        os.close(master)
        stop(fleet)
    return cores


def run_many_cpu(before: str, units: int, work: Path, tick_s: float,
                 run: int) -> tuple[float, float, list[int]]:
    """CPU seconds per unit of ``units`` ``imu-station run`` processes at once on simulated units and
    tables, their wall time, and their exit codes."""
    rigs, ports = feeder(RIG_FEEDER.format(units=units, tick_s=tick_s))
    db = work / f"run-{run}-{len(before)}.sqlite"
    try:
        start = time.monotonic()
        procs = [subprocess.Popen(station(before, "run", "--plan", str(work / "plan.yaml"), "--json",
                                          "--port", unit, "--table-port", table, "--serial", "auto",
                                          "--db", str(db), "--files", str(work / "files")),
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=work)
                 for unit, table in ports]  # type: ignore[union-attr]
        cpu, codes = 0.0, []
        for proc in procs:
            _, status, usage = os.wait4(proc.pid, 0)
            cpu += usage.ru_utime + usage.ru_stime
            codes.append(os.waitstatus_to_exitcode(status))
        wall = time.monotonic() - start
    finally:
        stop(rigs)
    return cpu / units, wall, codes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", choices=("both", "tui", "run-many"), default="both")
    parser.add_argument("--units", type=int, default=4, help="run-many: units at once (default 4)")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each; medians printed (default 3)")
    parser.add_argument("--seconds", type=float, default=10.0, help="TUI: seconds measured (default 10)")
    parser.add_argument("--tick-ms", type=float, default=1.0,
                        help="the units write what is due every this many ms (default 1: a USB link)")
    args = parser.parse_args()
    tick_s = args.tick_ms / 1000.0
    print(f"2-core machine shared with others (load average {os.getloadavg()[0]:.1f}); medians of "
          f"{args.repeats}; the units write every {args.tick_ms:g} ms")
    if args.part in ("both", "tui"):
        variants = {"before: reader thread, 20 snapshots/s, traces with each": THREADED + OLD_RATES,
                    "reader thread, today's drawing rates (the reader alone)": THREADED,
                    "after: paced port, 10 snapshots/s, traces 4/s": ""}
        cores: dict[str, list[float]] = {name: [] for name in variants}
        for _ in range(args.repeats):
            for name, before in variants.items():
                cores[name].append(tui_cores(before, args.seconds, tick_s))
        print(f"TUI live view, one unit at 1 kHz, {args.seconds:g} s idle on the live screen (cores):")
        for name, found in cores.items():
            print(f"  {name:56s} {statistics.median(found):.3f}   ({', '.join(f'{c:.3f}' for c in found)})")
        old, reader, new = (statistics.median(found) for found in cores.values())
        print(f"  ratio before/after: {old / new:.2f}; the reader alone: {reader / new:.2f}")
    if args.part in ("both", "run-many"):
        with tempfile.TemporaryDirectory(prefix="imu-run-many-bench-") as tmp:
            work = Path(tmp)
            (work / "plan.yaml").write_text(PLAN)
            (work / "seq.yaml").write_text(SEQUENCE)
            found: dict[str, list[tuple[float, float, list[int]]]] = {THREADED: [], "": []}
            for r in range(args.repeats):
                for before in found:
                    found[before].append(run_many_cpu(before, args.units, work, tick_s, r))
        print(f"run-many's units: {args.units} 'imu-station run' processes at once, 1 kHz, 6 poses and 3 "
              f"turns (CPU of the whole process, start-up, calibration and export included):")
        medians = {}
        for before, label in ((THREADED, "before (reader thread)"), ("", "after (paced port)")):
            cpu = statistics.median(c for c, _, _ in found[before])
            wall = statistics.median(w for _, w, _ in found[before])
            codes = sorted({c for _, _, cs in found[before] for c in cs})
            medians[before] = cpu
            print(f"  {label:24s} {cpu:.2f} CPU-s per unit ({cpu / wall:.3f} cores) for {wall:.1f} s wall; "
                  f"exit codes {codes}")
        print(f"  ratio before/after: {medians[THREADED] / medians['']:.2f}")


if __name__ == "__main__":
    main()
