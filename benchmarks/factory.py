"""Factory line throughput: four simulated units at once (run-many, one process per unit) against one alone.

Each repeat runs ``imu-station run-many --simulate N`` end to end (unit and table on ptys, runner,
calibration, export, records into one SQLite database) and takes the wall time from start to the
last unit's end; the figures are medians over the repeats. The target: four at once take at most
1.5 times as long as one alone (the work is paced by the sequence's holds and turns, so concurrent
units should overlap almost completely).

    python benchmarks/factory.py [--repeats 3] [--units 4] [--plan PLAN.yaml]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PLAN = """\
schema: imu-station/plan/1
name: bench-line
sequence: {file: seq.yaml}
device: {rate_hz: 200}
run: {timeout_s: 300, step_timeout_s: 30}
limits:
  accel.bias: {max_abs: 80, unit: mg}
  gyro.bias: {max_abs: 3, unit: deg/s}
export: [c, json]
"""
SEQUENCE = """\
name: six-and-three-turns
hold_s: 2
settle_s: 0.5
rotation_rate_dps: 180
steps: [+x, -x, +y, -y, +z, -z, rot+x, rot+y, rot+z]
"""


def run_line(work: Path, plan: Path, units: int, seed: int) -> dict:
    db = work / f"bench-{units}-{seed}.sqlite"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "station.cli", "run-many", "--plan", str(plan), "--simulate",
                           str(units), "--seed", str(seed), "--db", str(db), "--json"],
                          cwd=work, capture_output=True, text=True, env={**os.environ, "COLUMNS": "120"})
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"run-many exited {done.returncode}:\n{done.stderr[-3000:]}")
    out = json.loads(done.stdout)
    per_unit = [u["elapsed_s"] for u in out["units"]]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "unit_s": per_unit, "cpu_s": cpu}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--units", type=int, default=4)
    parser.add_argument("--plan", type=Path, help="a plan of your own (default: 6 poses of 2 s, 3 turns)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="imu-factory-bench-") as tmp:
        work = Path(tmp)
        if args.plan is None:
            (work / "seq.yaml").write_text(SEQUENCE)
            (work / "plan.yaml").write_text(PLAN)
            plan = work / "plan.yaml"
        else:
            plan = args.plan.resolve()
        results: dict[int, list[dict]] = {1: [], args.units: []}
        for r in range(args.repeats):
            for n in (1, args.units):  # interleaved, so machine load drifts affect both alike
                res = run_line(work, plan, n, seed=100 * r)
                results[n].append(res)
                units = ", ".join(f"{u:.1f}" for u in res["unit_s"])
                print(f"repeat {r + 1}: {n} unit(s): {res['wall_s']:.1f} s wall, units {units} s, "
                      f"{res['cpu_s']:.1f} s CPU", flush=True)
    one = statistics.median(x["wall_s"] for x in results[1])
    many = statistics.median(x["wall_s"] for x in results[args.units])
    cpu_one = statistics.median(x["cpu_s"] for x in results[1])
    cpu_many = statistics.median(x["cpu_s"] for x in results[args.units])
    print(f"\nmedians over {args.repeats} repeats (cores: {os.cpu_count()}, load average now "
          f"{os.getloadavg()[0]:.1f}):")
    print(f"  1 unit alone         {one:7.1f} s wall   {cpu_one:6.1f} s CPU")
    print(f"  {args.units} units at once     {many:7.1f} s wall   {cpu_many:6.1f} s CPU")
    ratio = many / one
    print(f"  ratio {args.units} at once / 1 alone: {ratio:.2f}x (target <= 1.5x: "
          f"{'met' if ratio <= 1.5 else 'NOT met'}); throughput {args.units / ratio:.2f}x one station")
    return 0


if __name__ == "__main__":
    sys.exit(main())
