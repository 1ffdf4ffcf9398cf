"""``imu-station demo`` at several speeds of the simulated unit's clock: wall and CPU time, and the
recovered-against-true errors, against running the same sequence in real time (speed 1).

    .venv/bin/python benchmarks/demo.py [--speeds 10 20 40] [--repeats 3] [--seed 1]

Each run is the whole demo in this process (all of :data:`station.commands.demo.STEPS`, files in a
temporary folder). Figures are medians over ``--repeats`` runs; the real-time figure is the
sequence's own device-clock span, which is what the sequence takes on a real unit.
"""

from __future__ import annotations

import argparse
import io
import statistics
import tempfile
import time
from pathlib import Path

from station.commands import demo


def one_run(speed: float, seed: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="imu-demo-bench-") as tmp:
        ctx = demo.DemoContext(out_dir=Path(tmp), seed=seed, speed=speed, out=io.StringIO(),
                               err=io.StringIO())
        wall0, cpu0 = time.monotonic(), time.process_time()
        demo.run_demo(ctx)
        wall, cpu = time.monotonic() - wall0, time.process_time() - cpu0
    seq = ctx.results["sequence"]
    errors = ctx.results["calibration"]
    return {"wall_s": wall, "cpu_s": cpu, "sequence_wall_s": seq["wall_s"], "device_s": seq["device_s"],
            "redone": float(len(seq["redone"])), "sigma_max": max(ctx.results["sigma_ratios"]),
            **{name: value for name, value in errors.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speeds", type=float, nargs="+", default=[10.0, 20.0, 40.0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    print(f"imu-station demo, seed {args.seed}, poses of {demo.HOLD_S:g} s; medians of {args.repeats} runs")
    print(f"{'speed':>6} {'demo wall':>10} {'CPU':>7} {'sequence':>9} {'device':>8} {'vs real':>8} "
          f"{'redone':>6}  largest errors (accel scale/mis/bias, gyro scale/mis/bias), max |e|/sigma")
    for speed in args.speeds:
        runs = [one_run(speed, args.seed) for _ in range(args.repeats)]
        med = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
        errors = (f"{med['accel scale'] * 1e6:.0f} ppm/{med['accel misalignment'] * 1e6:.0f} urad/"
                  f"{med['accel bias'] * 1e3:.2f} mm/s^2, {med['gyro scale'] * 1e6:.0f} ppm/"
                  f"{med['gyro misalignment'] * 1e6:.0f} urad/{med['gyro bias'] * 1e6:.0f} urad/s")
        print(f"{speed:6g} {med['wall_s']:9.1f}s {med['cpu_s']:6.1f}s {med['sequence_wall_s']:8.1f}s "
              f"{med['device_s']:7.0f}s {med['device_s'] / med['sequence_wall_s']:7.1f}x "
              f"{med['redone']:6.0f}  "
              f"{errors}, {med['sigma_max']:.1f}", flush=True)


if __name__ == "__main__":
    main()
