"""Day-long Allan records: ``imu-station allan`` on a 12 h 1 kHz capture file against allantools.oadev.

    .venv/bin/python benchmarks/allan_day.py [--hours 12] [--repeats 3] [--also-hours 48] [--dir DIR]

Writes a station capture file (.h5, schema imu-station/capture/1) of ``--hours`` at 1 kHz, six axes of
white noise plus a random walk (N and K known), in chunks, so that making it needs little memory; then,
``--repeats`` times each, in fresh processes:

- ``imu-station allan FILE --json``, the whole command (start-up, reading, integration, every axis, the
  fit), its wall time and peak resident memory (the child's ru_maxrss, from wait4);
- allantools.oadev on ONE axis of the same file held in memory (read before the clock starts), at the
  same cluster sizes (``station.engines.allan.deviation.cluster_sizes``: 10 per decade up to N/4),
  its wall time.

Prints the medians, the ratio of the command's time for six axes to allantools' for one, the peak memory
against the 1 GiB budget, the largest relative difference of the two deviations on that axis, N and
K of every axis beside the injected ones, and where the command's time goes (reading and integrating,
the deviation of six axes, the noise-model fit) in one more run. ``--also-hours 48`` does the command
alone on a 48 h file (the allantools run would not fit in memory beside it). The files are deleted at
the end.
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
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

RATE = 1000.0
ROWS = 1 << 20  # rows written at a time
# injected noise per axis (gx gy gz in rad/s, ax ay az in m/s^2): white noise density N and rate random
# walk K; their lines (N^2 / tau = K^2 tau / 3) cross at tau = sqrt(3) N / K, 140..300 s, well inside
# a twentieth of the record, where K is resolved
N_TRUE = np.array([1e-4, 1.2e-4, 0.9e-4, 1e-3, 1.1e-3, 1.3e-3])
K_TRUE = np.array([1e-5, 1.5e-5, 0.8e-5, 1e-4, 0.9e-4, 1.3e-4])
GIB = 1 << 30


def write_capture(path: Path, hours: float, seed: int = 7) -> int:
    """A station capture file of ``hours`` at 1 kHz, written ROWS at a time; returns the samples."""
    from protocols.base import SAMPLE_DTYPE
    from station.acquisition.capture_h5 import H5CaptureWriter

    n = int(hours * 3600 * RATE)
    rng = np.random.default_rng(seed)
    walk = np.zeros(6)
    white_sd = N_TRUE * math.sqrt(RATE)  # a density N gives a sample sd N sqrt(rate)
    step_sd = K_TRUE / math.sqrt(RATE)  # a random walk K gives steps of sd K sqrt(tau0)
    writer = H5CaptureWriter(path, device={"serial": "bench-day", "rate_hz": RATE})
    batch = np.zeros(ROWS, dtype=SAMPLE_DTYPE)
    for a in range(0, n, ROWS):
        k = min(ROWS, n - a)
        b = batch[:k]
        steps = np.cumsum(rng.standard_normal((k, 6)) * step_sd, axis=0) + walk
        walk = steps[-1]
        values = rng.standard_normal((k, 6)) * white_sd + steps
        b["seq"] = np.arange(a, a + k)
        b["t_us"] = np.arange(a, a + k, dtype=np.uint64) * np.uint64(1000)
        b["gyro"] = values[:, :3]
        b["acc"] = values[:, 3:] + [0.0, 0.0, 9.81]
        b["temp"] = 25.0
        writer.write(b)
    writer.close()
    return n


def measured_child(args: list[str]) -> dict:
    """Run this script as a child with ``args`` and read the JSON line it prints."""
    out = subprocess.run([sys.executable, __file__, *args], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def child_command(path: str, workdir: str) -> None:
    """Measure one command run from a helper process of its own: the rusage of its only child is exact."""
    import resource

    curve = Path(workdir) / "curve.csv"
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "station", "allan", path, "--json", "--workdir", workdir,
                           "--curve", str(curve)], capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"imu-station allan failed ({done.returncode}): {done.stderr[-2000:]}")
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # of its only child: the command
    table = np.genfromtxt(curve, delimiter=",", names=True)
    curve.unlink()
    print(json.dumps({"wall": wall, "cpu": usage.ru_utime + usage.ru_stime, "peak": usage.ru_maxrss * 1024,
                      "result": json.loads(done.stdout), "tau": table["tau"].tolist(),
                      "gx": table["gx"].tolist()}))


def child_allantools(path: str) -> None:
    """allantools.oadev on axis gx of the file, held in memory, at the engine's cluster sizes."""
    import allantools
    import h5py

    from station.engines.allan.deviation import cluster_sizes

    with h5py.File(path, "r") as f:
        y = f["gyro"][:, 0].astype(np.float64)
    m = cluster_sizes(len(y))
    start, start_cpu = time.perf_counter(), time.process_time()
    taus, adev, _, _ = allantools.oadev(y, rate=RATE, data_type="freq", taus=m / RATE)
    wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    print(json.dumps({"wall": wall, "cpu": cpu, "m": m.tolist(), "taus": taus.tolist(),
                      "adev": adev.tolist()}))


def child_phases(path: str, workdir: str) -> None:
    """The command's stages timed in one process: reading and integrating, the curve, the fit, and within
    the fit the likelihood of K and the model choice (their functions wrapped by a timer)."""
    from station.acquisition.allan_source import AXES, capture_chunks, integrate_stream
    from station.engines.allan import fit as allan_fit
    from station.engines.allan import model as allan_model
    from station.engines.allan.deviation import allan_curve, cluster_sizes
    from station.engines.allan.fit import identify_noise

    times = {}
    within: dict[str, list[float]] = {}

    def timed(module: object, name: str, label: str) -> None:
        inner = getattr(module, name)

        def wrapper(*args: object, **kwargs: object) -> object:
            wall, cpu = time.perf_counter(), time.process_time()
            try:
                return inner(*args, **kwargs)
            finally:
                total = within.setdefault(label, [0.0, 0.0])
                total[0] += time.perf_counter() - wall
                total[1] += time.process_time() - cpu

        setattr(module, name, wrapper)

    timed(allan_fit, "white_walk_ml", "  of which the likelihood of K (allan_ml)")
    timed(allan_model, "choose_model", "  of which the model choice (allan_model)")
    start, start_cpu = time.perf_counter(), time.process_time()

    def lap(name: str) -> None:
        nonlocal start, start_cpu
        times[name] = (time.perf_counter() - start, time.process_time() - start_cpu)
        start, start_cpu = time.perf_counter(), time.process_time()

    chunks, _, _ = capture_chunks(path)
    with integrate_stream(chunks, path, workdir=workdir) as record:
        lap("read and integrate (allan_source)")
        curve = allan_curve(record.phase, record.rate_hz, AXES, cluster_sizes(record.n_samples))
        lap("Allan deviation, six axes (engines.allan)")
        identify_noise(curve, record.phase)
        lap("noise model fit (engines.allan_fit)")
    times.update({k: (v[0], v[1]) for k, v in within.items()})
    print(json.dumps(times))


def terms(result: dict) -> list[tuple[float | None, float | None]]:
    """(N, K) per axis, gx..az, from the command's JSON (None where the command reports none)."""
    noise = result["noise"]
    out = []
    for sensor in ("gyro", "accel"):
        for i in range(3):
            n, k = noise[sensor]["N"], noise[sensor]["K"]
            out.append((n[i] if n else None, k[i] if k else None))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--hours", type=float, default=12.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--also-hours", type=float, default=0.0, help="then the command alone on this length")
    parser.add_argument("--dir", type=Path, default=None, help="folder for the files (default: temp)")
    parser.add_argument("--child-command", nargs=2, metavar=("FILE", "WORKDIR"), help=argparse.SUPPRESS)
    parser.add_argument("--child-allantools", metavar="FILE", help=argparse.SUPPRESS)
    parser.add_argument("--child-phases", nargs=2, metavar=("FILE", "WORKDIR"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_command:
        child_command(*args.child_command)
        return
    if args.child_allantools:
        child_allantools(args.child_allantools)
        return
    if args.child_phases:
        child_phases(*args.child_phases)
        return

    print(f"load average at the start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory(prefix="allan-day-", dir=args.dir) as tmp:
        folder = Path(tmp)
        path = folder / "day.h5"
        start = time.perf_counter()
        n = write_capture(path, args.hours)
        print(f"capture: {args.hours:g} h at {RATE:g} Hz, {n:,} samples x 6 axes, "
              f"{path.stat().st_size / 1e9:.2f} GB, written in {time.perf_counter() - start:.0f} s")
        ours, theirs = [], []
        result: dict = {}
        reference: dict = {}
        for _ in range(args.repeats):
            run = measured_child(["--child-command", str(path), str(folder)])
            ours.append(run)
            result = run["result"]
            reference = measured_child(["--child-allantools", str(path)])
            theirs.append(reference)
        report(ours, theirs, result, reference, args.repeats)
        phases = measured_child(["--child-phases", str(path), str(folder)])
        print("where the command's time goes (one run, in one process; wall, CPU):")
        for name, (wall, cpu) in phases.items():
            print(f"  {name:44s} {wall:6.1f} s {cpu:6.1f} s")
        path.unlink()
        if args.also_hours:
            path = folder / "long.h5"
            n = write_capture(path, args.also_hours, seed=8)
            print(f"capture: {args.also_hours:g} h at {RATE:g} Hz, {n:,} samples x 6 axes, "
                  f"{path.stat().st_size / 1e9:.2f} GB")
            runs = [measured_child(["--child-command", str(path), str(folder)]) for _ in range(args.repeats)]
            wall = statistics.median(r["wall"] for r in runs)
            peak = max(r["peak"] for r in runs)
            print(f"imu-station allan, {args.also_hours:g} h, six axes: {wall:.1f} s wall (median of "
                  f"{args.repeats}), peak memory {peak / GIB:.2f} GiB "
                  f"({'within' if peak <= GIB else 'OVER'} 1 GiB)")
            print_terms(runs[-1]["result"])
    print(f"load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


def report(ours: list[dict], theirs: list[dict], result: dict, reference: dict, repeats: int) -> None:
    """The figures of the 12 h comparison (wall, and CPU: user + system of the processes)."""
    wall, cpu = (statistics.median(r[k] for r in ours) for k in ("wall", "cpu"))
    ref, ref_cpu = (statistics.median(r[k] for r in theirs) for k in ("wall", "cpu"))
    peak = max(r["peak"] for r in ours)
    print(f"imu-station allan, six axes, whole process: {wall:.1f} s wall, {cpu:.1f} s CPU (median of "
          f"{repeats}; walls {', '.join(format(r['wall'], '.1f') for r in ours)})")
    print(f"allantools.oadev, ONE axis in memory:      {ref:.1f} s wall, {ref_cpu:.1f} s CPU (median of "
          f"{repeats}; walls {', '.join(format(r['wall'], '.1f') for r in theirs)})")
    print(f"ratio six axes / allantools one axis: wall {wall / ref:.2f}, CPU {cpu / ref_cpu:.2f} "
          "(target < 1)")
    print(f"peak memory of the command: {peak / GIB:.2f} GiB ({peak / 1e6:.0f} MB), "
          f"{'within' if peak <= GIB else 'OVER'} the 1 GiB budget")
    ours_gx, ref_gx = np.asarray(ours[-1]["gx"]), np.asarray(reference["adev"])
    same = np.allclose(ours[-1]["tau"], reference["taus"], rtol=1e-9)
    print(f"gx against allantools at {len(ref_gx)} cluster sizes ({'the same' if same else 'OTHER'} taus): "
          f"largest relative difference {np.max(np.abs(ours_gx / ref_gx - 1.0)):.1e} (the curve file has 9 "
          "significant digits)")
    print_terms(result)


def print_terms(result: dict) -> None:
    """N and K per axis beside the injected ones."""
    for j, (axis, (n, k)) in enumerate(zip(("gx", "gy", "gz", "ax", "ay", "az"), terms(result), strict=True)):
        shown = [f"{v:.4g}" if v is not None else "none" for v in (n, k)]
        print(f"  {axis}: N {shown[0]} (injected {N_TRUE[j]:.4g}), K {shown[1]} (injected {K_TRUE[j]:.4g})")


if __name__ == "__main__":
    main()
