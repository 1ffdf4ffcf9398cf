"""The TUI's CPU on a simulated 1 kHz unit: the live view at idle, and the wizard during a step's capture.

Each measurement runs in a process of its own: the app headless (textual's ``App.run_test``) on the
simulated unit ``imu-station tui --simulate --rate 1000`` serves (its pty server is a thread of the same
process, as in the command), driven by Pilot key presses. Once the screen is up and warm, the process's
own CPU (user + system, every thread: ``resource.getrusage``) is read over ``--seconds`` of wall clock;
CPU per wall second is the share of one core the TUI takes, whatever else loads the machine. The
threads' shares are given too (``/proc/self/task``), named by Python thread (the pty server, the reader
worker, the event loop).

    .venv/bin/python benchmarks/tui_live.py [--seconds 20] [--repeat 3] [--rate 1000] [--only live|wizard]
                                            [--against REV|none]
    .venv/bin/python benchmarks/tui_live.py --only live --profile live.prof   (cProfile of the event loop)

Targets (issue 30): at most 0.15 of a core on the live view at idle, 0.25 during the wizard's capture.
Each run is followed by the same run on the code of ``--against`` (default: the TUI before issue 30's
work), extracted with ``git archive`` into a temporary folder, so one run prints both figures and their
ratio under the same load. The figure without the pty server's thread is what the TUI itself costs on a
real unit, where the simulator is not in its process.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

TARGETS = {"live": 0.15, "wizard": 0.25}
BEFORE = "40fe9cc"  # the TUI as landed before issue 30's live-view work (plotext traces, 20 Hz checks)
CLOCK_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")
WARM_S = 3.0  # after the screen is up: first drawings, caches, the reader's first batches


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _threads_cpu() -> dict[str, float]:
    """CPU seconds of each thread of this process, keyed by its Python name (else its native id)."""
    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat", encoding="ascii") as fh:
                fields = fh.read().rpartition(")")[2].split()
        except OSError:
            continue
        name = names.get(int(tid), f"tid {tid}")
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) * CLOCK_TICK_S
    return out


async def _measure(kind: str, seconds: float, rate_hz: float, profile: str | None) -> dict:
    from station.acquisition.run_records import State
    from station.tui.app import StationApp
    from station.tui.config import TuiConfig
    from station.tui.screens.wizard import WizardScreen

    # The wizard's first step holds long enough to measure inside its capture.
    hold = seconds + WARM_S + 30.0 if kind == "wizard" else 5.0
    app = StationApp(TuiConfig(simulate=True, seed=1, rate_hz=rate_hz, hold_s=hold))
    async with app.run_test(size=(120, 40)) as pilot:
        async def until(condition, timeout_s: float, what: str) -> None:
            deadline = time.monotonic() + timeout_s
            while not condition():
                if time.monotonic() > deadline:
                    raise SystemExit(f"timed out waiting for {what}")
                await pilot.pause(0.1)

        await until(lambda: app.session is not None, 60, "the simulated unit")
        await pilot.press("enter")  # connect -> live view
        await until(lambda: type(app.screen).__name__ == "LiveScreen", 10, "the live view")
        if kind == "wizard":
            await pilot.pause(0.5)
            await pilot.press("enter")  # live -> wizard
            await until(lambda: isinstance(app.screen, WizardScreen) and app.screen.prompt is not None, 30,
                        "the start prompt")
            await pilot.press("enter")  # start
            wizard = app.screen
            assert isinstance(wizard, WizardScreen)
            seen: dict[str, object] = {}
            original = wizard._on_status

            def spy(event) -> None:
                seen["state"] = event.payload.state
                original(event)

            wizard._on_status = spy  # type: ignore[method-assign]
            await until(lambda: seen.get("state") is State.CAPTURING, 60, "the first step's capture")
        await pilot.pause(WARM_S)
        profiler = None
        if profile:
            import cProfile

            profiler = cProfile.Profile()
            profiler.enable()
        threads0, cpu0, wall0 = _threads_cpu(), _cpu(), time.monotonic()
        await pilot.pause(seconds)
        cpu1, wall1, threads1 = _cpu(), time.monotonic(), _threads_cpu()
        if profiler is not None:
            profiler.disable()
            profiler.dump_stats(profile)
        if kind == "wizard":
            assert seen.get("state") is State.CAPTURING, f"the capture ended early: {seen.get('state')}"
        stats = app.session.device.stats if app.session is not None else None
        app.exit(0)
    wall = wall1 - wall0
    return {"kind": kind, "wall_s": wall, "cpu_s": cpu1 - cpu0, "core": (cpu1 - cpu0) / wall,
            "threads": {k: (v - threads0.get(k, 0.0)) / wall for k, v in threads1.items()},
            "lost": stats.lost if stats is not None else None}


def _child(args: argparse.Namespace) -> None:
    result = asyncio.run(_measure(args.child, args.seconds, args.rate, args.profile))
    print(json.dumps(result), flush=True)


def _run_child(kind: str, args: argparse.Namespace, tree: Path, i: int) -> dict:
    """One measurement in a process of its own, on the code in ``tree``."""
    cmd = [sys.executable, __file__, "--child", kind, "--seconds", str(args.seconds),
           "--rate", str(args.rate)]
    if args.profile:
        cmd += ["--profile", args.profile]
    env = dict(os.environ, PYTHONPATH=str(tree))  # before the editable install's finder: that tree's code
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tree, env=env, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"{kind} run {i} in {tree} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _line(label: str, r: dict) -> str:
    top = sorted(r["threads"].items(), key=lambda kv: -kv[1])[:3]
    threads = ", ".join(f"{k} {v:.3f}" for k, v in top)
    return f"  {label}: {r['core']:.3f} core ({threads}), lost {r['lost']}"


def _tui_alone(r: dict) -> float:
    """The process's share without the simulated unit's pty server (a thread of it here, not with a real
    unit)."""
    return r["core"] - r["threads"].get("pty-server", 0.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0, help="measured wall seconds (default 20)")
    parser.add_argument("--repeat", type=int, default=3, help="processes per case; the median is kept")
    parser.add_argument("--rate", type=float, default=1000.0, help="the simulated unit's rate, Hz")
    parser.add_argument("--only", choices=sorted(TARGETS), help="one case only")
    parser.add_argument("--against", default=BEFORE, metavar="REV",
                        help=f"also measure the code of this commit, run for run, and give the ratio "
                             f"(default {BEFORE}, the TUI before issue 30's work; 'none' to skip)")
    parser.add_argument("--profile", metavar="FILE", help="cProfile the event loop's thread into FILE "
                        "(one run; the reader and server threads are not in it)")
    parser.add_argument("--child", choices=sorted(TARGETS), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args)
        return
    kinds = [args.only] if args.only else ["live", "wizard"]
    with open("/proc/loadavg", encoding="ascii") as fh:
        load = fh.read().split()[:3]
    print(f"load average {' '.join(load)} on {os.cpu_count()} cores; rate {args.rate:g} Hz, "
          f"{args.seconds:g} s measured, median of {args.repeat}")
    root = Path(__file__).resolve().parent.parent
    against = None if args.profile or args.against == "none" else args.against
    with tempfile.TemporaryDirectory(prefix="tui-live-before-") as tmp:
        before_tree = Path(tmp)
        if against is not None:
            # The commit's files alone (git archive): no worktree, nothing in the repository changes.
            archive = subprocess.run(["git", "-C", str(root), "archive", against], capture_output=True,
                                     check=True).stdout
            subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        for kind in kinds:
            runs, befores = [], []
            for i in range(1 if args.profile else args.repeat):
                # Run for run, so both see the same load.
                runs.append(_run_child(kind, args, root, i))
                print(_line(f"{kind} run {i + 1}", runs[-1]), flush=True)
                if against is not None:
                    befores.append(_run_child(kind, args, before_tree, i))
                    print(_line(f"{kind} run {i + 1}, {against}", befores[-1]), flush=True)
            median = statistics.median(r["core"] for r in runs)
            alone = statistics.median(_tui_alone(r) for r in runs)
            target = TARGETS[kind]
            print(f"{kind:6s}: {median:.3f} of a core (median; {alone:.3f} without the simulated unit's "
                  f"thread), target {target:.2f}: ratio {median / target:.2f} "
                  f"{'OK' if median <= target else 'OVER'}", flush=True)
            if befores:
                old = statistics.median(r["core"] for r in befores)
                old_alone = statistics.median(_tui_alone(r) for r in befores)
                print(f"{'':6s}  {against}: {old:.3f} ({old_alone:.3f} without it): now {median / old:.2f} "
                      f"of it ({alone / old_alone:.2f} without it)", flush=True)
    with open("/proc/loadavg", encoding="ascii") as fh:
        print(f"load average after: {' '.join(fh.read().split()[:3])}")


if __name__ == "__main__":
    main()
