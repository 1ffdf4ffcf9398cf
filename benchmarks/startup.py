"""Start of a computing command (issue 30): ``allan``, ``thermal`` and ``calibrate`` on small files, the
first run of a fresh install against the runs after it, and what the imports and numba's first call
cost.

A fresh install is one whose numba cache is empty. numba writes its cache beside the package where
it can, and in the user's cache directory where the package is read-only (a system or container
install); both start empty, so the first ``allan`` compiles the Allan loop and the ones after load it.
Each command runs with ``NUMBA_CACHE_DIR`` set to an empty folder for its first run and to the same,
now filled, folder for the next ones; whole processes, median of ``--repeats`` (the first run once
per repeat, each in a new empty folder). The target: a fresh install's first ``allan`` on a
10-minute record under 3 s.

The inputs are made here from the simulated unit: a 10-minute still record at 200 Hz (allan), a
3-hour chamber sweep at 10 Hz (thermal), and imu_tk's Xsens session from tests/data (calibrate
--method free).

    .venv/bin/python benchmarks/startup.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = {
    "allan (10 min at 200 Hz)": ["allan", "{dir}/still.csv", "--force"],
    "thermal (3 h sweep at 10 Hz)": ["thermal", "{dir}/sweep.csv", "-o", "{dir}/t.yaml", "--replace"],
    "calibrate --method free (imu_tk session)": ["calibrate", "{dir}/xsens.csv", "--method", "free",
                                                 "--imu-tk", "--gravity", "9.81744", "--convention",
                                                 "upper", "--initial-still", "50"],
}


def _inputs(folder: Path) -> None:
    from mocks.chamber import chamber_sweep
    from mocks.device import SimDevice
    from mocks.truth import UnitTruth
    from station.acquisition.capture import Capture
    from station.acquisition.capture_csv import write_csv

    device = SimDevice(seed=1, rate_hz=200.0)
    samples = device.produce(600.0)
    write_csv(folder / "still.csv", Capture(samples["t_us"] * 1e-6, samples["acc"].astype(float),
                                            samples["gyro"].astype(float), samples["temp"].astype(float)))
    write_csv(folder / "sweep.csv", chamber_sweep(UnitTruth.random(1), rate_hz=10.0, seed=1).to_capture())
    data = ROOT / "tests" / "data" / "xsens-imu_tk"
    acc, gyro = (np.loadtxt(data / f"xsens_{n}.txt.gz") for n in ("acc", "gyro"))
    write_csv(folder / "xsens.csv", Capture(acc[:, 0], acc[:, 1:], gyro[:, 1:]))


def _run(argv: list[str], cache: Path) -> tuple[float, float]:
    """Wall and CPU seconds of one whole ``imu-station`` process."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    start, before = time.perf_counter(), os.times()
    subprocess.run([sys.executable, "-m", "station", *argv], env=env, check=True, capture_output=True)
    after = os.times()
    return time.perf_counter() - start, (after.children_user - before.children_user
                                         + after.children_system - before.children_system)


def _numba_first_call(cache: Path) -> str:
    # The deviation's first call compiles (or loads) the numba loop; a tiny record costs nothing else.
    code = ("import time; t0 = time.perf_counter(); import numpy as np; t1 = time.perf_counter(); "
            "import numba; t2 = time.perf_counter(); from station.engines.allan import allan_curve; "
            "x = np.cumsum(np.random.default_rng(0).normal(size=(1, 5001)), axis=1); "
            "t3 = time.perf_counter(); allan_curve(x, 100.0, ['gx']); t4 = time.perf_counter(); "
            "print(f'import numpy {t1 - t0:.3f} s, numba {t2 - t1:.3f} s; first deviation {t4 - t3:.3f} s')")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-c", code], env=env, check=True, capture_output=True,
                          text=True).stdout.strip()


def _imports(argv: list[str], folder: Path) -> str:
    """The three costliest top-level imports of one run (``python -X importtime``), cumulative."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-m", "station", *argv], capture_output=True,
                          text=True)
    rows = []
    for line in done.stderr.splitlines():
        parts = line.split("|")
        if line.startswith("import time:") and len(parts) == 3 and parts[1].strip().isdigit() \
                and not parts[2].startswith("  "):
            rows.append((int(parts[1]), parts[2].strip()))
    total = sum(us for us, _ in rows)
    top = ", ".join(f"{name} {us / 1e6:.2f} s" for us, name in sorted(rows, reverse=True)[:3])
    return f"imports {total / 1e6:.2f} s ({top})"


def main() -> None:
    """Print each command's first and later runs, the imports, and numba's first call."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        _inputs(folder)
        print(f"load {os.getloadavg()[0]:.2f}; medians of {args.repeats}")
        for name, template in COMMANDS.items():
            argv = [a.replace("{dir}", tmp) for a in template]
            firsts, laters = [], []
            for i in range(args.repeats):
                cache = folder / f"cache-{name[:5]}-{i}"
                firsts.append(_run(argv, cache))
                laters.append(_run(argv, cache))
            first = statistics.median(w for w, _ in firsts), statistics.median(c for _, c in firsts)
            later = statistics.median(w for w, _ in laters), statistics.median(c for _, c in laters)
            print(f"{name}: first run {first[0]:.2f} s wall ({first[1]:.2f} s CPU), later {later[0]:.2f} s "
                  f"({later[1]:.2f} s CPU); {_imports(argv, folder)}")
            if name.startswith("allan"):
                print(f"  fresh install's first allan / 3 s target: {first[0] / 3.0:.2f}")
        print(f"numba, empty cache: {_numba_first_call(folder / 'cache-probe')}")
        print(f"numba, cache filled: {_numba_first_call(folder / 'cache-probe')}")


if __name__ == "__main__":
    main()
