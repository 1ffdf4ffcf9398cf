"""Calibration speed, whole process against whole process: ``imu-station calibrate --method free --imu-tk``
against imu_tk's own C++/Ceres build on imu_tk's Xsens session, side by side in one run.

    .venv/bin/python benchmarks/imu_tk_process.py [--repeats 7] [--cache DIR]

imu_tk is built once with ``../shared/peers/imu_tk/build.sh`` into ``--cache`` (default
``~/.cache/imu-station/imu_tk``; skipped, saying why, when it cannot be built). Both processes read the
session from files (imu_tk its two text files, the station a capture CSV written from them), fit, and
write their result (imu_tk prints it; the station merges it into a parameter file and prints its report):

- imu_tk: ``test_imu_calib_quiet ACC GYRO`` (the upstream demo without its viewer);
- station: ``imu-station calibrate xsens.csv --method free --imu-tk --gravity 9.81744 --convention upper
  --initial-still 50 -o params.yaml`` (imu_tk's gravity, misalignment form and 50 s still period).

Runs alternate (imu_tk, station, imu_tk, ...) so that both see the same load; medians of ``--repeats``.
The parameters are compared entry by entry: the station's ``correction`` matrices (C = T K) and biases
against imu_tk's full-precision dump (``test_imu_calib_dump``). Start-up is measured too: ``imu-station
--help``, and the station's run with OpenBLAS allowed two threads (``OPENBLAS_NUM_THREADS=2``) against
the default the command sets (one). The station runs from its compiled bytecode, as installed
(``process_timing.installed_env``).
"""

from __future__ import annotations

import argparse
import gzip
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from process_timing import ProcessRun, installed_env, run_process  # noqa: E402

XSENS = REPO / "tests" / "data" / "xsens-imu_tk"
BUILD = REPO.parent / "shared" / "peers" / "imu_tk" / "build.sh"
STATION = [str(Path(sys.executable).with_name("imu-station"))]
OPTIONS = ["--method", "free", "--imu-tk", "--gravity", "9.81744", "--convention", "upper",
           "--initial-still", "50"]


def build_imu_tk(cache: Path) -> Path | str:
    """imu_tk's binaries folder, built once into ``cache``; or why it could not be built."""
    binaries = cache / "bin"
    if (binaries / "test_imu_calib_quiet").exists() and (binaries / "test_imu_calib_dump").exists():
        return binaries
    if not BUILD.exists():
        return f"{BUILD} is not there (the peers folder is not checked out beside the project)"
    print(f"building imu_tk into {cache} (about a minute, once) ...", flush=True)
    cache.parent.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["bash", str(BUILD), str(cache)], capture_output=True, text=True)
    if done.returncode != 0:
        return f"build.sh failed ({done.returncode}): {(done.stderr or done.stdout).strip()[-400:]}"
    return binaries


def inputs(folder: Path) -> tuple[Path, Path, Path]:
    """imu_tk's two text files, gunzipped, and the same session as a capture CSV."""
    from station.acquisition.capture import Capture
    from station.acquisition.capture_csv import write_csv

    paths = []
    for name in ("acc", "gyro"):
        path = folder / f"xsens_{name}.txt"
        with gzip.open(XSENS / f"xsens_{name}.txt.gz", "rb") as src, open(path, "wb") as dst:
            shutil.copyfileobj(src, dst)
        paths.append(path)
    acc, gyro = np.loadtxt(paths[0]), np.loadtxt(paths[1])
    csv = folder / "xsens.csv"
    write_csv(csv, Capture(acc[:, 0], acc[:, 1:], gyro[:, 1:]))
    return paths[0], paths[1], csv


def imu_tk_parameters(binaries: Path, acc: Path, gyro: Path, workdir: str) -> dict[str, np.ndarray]:
    """acc_T, acc_K, acc_B, gyro_T, gyro_K, gyro_B from imu_tk's full-precision dump (run in ``workdir``)."""
    out = subprocess.run([str(binaries / "test_imu_calib_dump"), str(acc), str(gyro)], check=True,
                         capture_output=True, text=True, cwd=workdir).stdout
    values = {}
    for name, body in re.findall(r"^(\w+)=\[(.*)\]$", out, flags=re.M):
        values[name] = np.array([[float(v) for v in row.split(",")] for row in body.split(";")]).squeeze()
    return values


def compare(params: Path, ref: dict[str, np.ndarray]) -> list[tuple[str, float]]:
    """Largest relative difference per quantity: C = T K (relative to its largest entry) and the bias."""
    with open(params) as fh:
        ours = yaml.safe_load(fh)
    rows = []
    for sensor, key in (("accel", "acc"), ("gyro", "gyro")):
        c_ref = ref[f"{key}_T"] @ np.diag(ref[f"{key}_K"])
        c_ours = np.asarray(ours[sensor]["correction"])
        rows.append((f"{sensor} C = T K", float(np.abs(c_ours - c_ref).max() / np.abs(c_ref).max())))
        b_ref, b_ours = ref[f"{key}_B"], np.asarray(ours[sensor]["bias"])
        rows.append((f"{sensor} bias", float(np.abs(b_ours / b_ref - 1.0).max())))
    return rows


def load() -> str:
    """The machine's load average over the last minute, against its cores (the runs share them)."""
    return f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"


def median(runs: list[ProcessRun], what: str) -> float:
    """Median wall or CPU seconds of some runs."""
    return statistics.median(getattr(r, what) for r in runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "imu-station" / "imu_tk")
    args = parser.parse_args()

    env = installed_env()
    print(f"load average at the start: {load()}")
    run_process([*STATION, "--help"], env=env)  # the bytecode cache filled before timing
    helps = [run_process([*STATION, "--help"], env=env) for _ in range(args.repeats)]
    print(f"start-up: imu-station --help {median(helps, 'wall'):.3f} s wall, "
          f"{median(helps, 'cpu'):.3f} s CPU (median of {args.repeats}; target under 0.15 s)")
    binaries = build_imu_tk(args.cache)
    with tempfile.TemporaryDirectory(prefix="imu-tk-bench-") as tmp:
        acc, gyro, csv = inputs(Path(tmp))
        params = Path(tmp) / "params.yaml"
        station = [*STATION, "calibrate", str(csv), *OPTIONS, "-o", str(params), "--replace"]
        two_threads = installed_env(OPENBLAS_NUM_THREADS="2")
        if isinstance(binaries, str):
            print(f"imu_tk: skipped, {binaries}")
            ours = [run_process(station, env=env) for _ in range(args.repeats)]
            print(f"imu-station calibrate --method free --imu-tk, whole process: "
                  f"{median(ours, 'wall'):.3f} s wall, {median(ours, 'cpu'):.3f} s CPU")
            print(f"load average at the end: {load()}")
            return
        theirs, ours, ours_two = [], [], []
        run_process(station, env=env)  # compiled modules cached before the first timed run
        for _ in range(args.repeats):
            # imu_tk writes its results (test_imu_*.calib) into its working folder
            theirs.append(run_process([str(binaries / "test_imu_calib_quiet"), str(acc), str(gyro)], cwd=tmp))
            ours.append(run_process(station, env=env))
            ours_two.append(run_process(station, env=two_threads))
        print(f"imu_tk's Xsens session, whole processes, median of {args.repeats} alternating runs "
              "(wall; CPU = user + system of the process):")
        for name, runs in (("imu_tk (C++/Ceres, test_imu_calib_quiet)", theirs),
                           ("imu-station calibrate --method free --imu-tk", ours),
                           ("the same, OpenBLAS on two threads", ours_two)):
            print(f"  {name:46s} {median(runs, 'wall'):.3f} s wall, {median(runs, 'cpu'):.3f} s CPU "
                  f"(walls {' '.join(format(r.wall, '.2f') for r in runs)})")
        print(f"  ratio station / imu_tk: wall {median(ours, 'wall') / median(theirs, 'wall'):.2f}, "
              f"CPU {median(ours, 'cpu') / median(theirs, 'cpu'):.2f} (below 1: the station is faster)")
        print(f"  two OpenBLAS threads against one: "
              f"wall x{median(ours_two, 'wall') / median(ours, 'wall'):.2f}, "
              f"CPU x{median(ours_two, 'cpu') / median(ours, 'cpu'):.2f}")
        print("parameters against imu_tk's (largest relative difference):")
        for name, diff in compare(params, imu_tk_parameters(binaries, acc, gyro, tmp)):
            print(f"  {name:16s} {diff:.1e}")
    print(f"load average at the end: {load()}")


if __name__ == "__main__":
    main()
