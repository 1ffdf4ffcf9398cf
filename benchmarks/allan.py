"""Allan engine against allantools.oadev: time and peak memory on the same 10,000,000-sample series.

    .venv/bin/python benchmarks/allan.py [--samples 10000000] [--repeats 3]
    .venv/bin/python benchmarks/allan.py --k-monte-carlo 100

Both compute the overlapping Allan deviation of the same float64 rate series at the same cluster sizes
(station.engines.allan.deviation.cluster_sizes: 10 per decade up to N/4), the engine also on one worker thread
(what is left when the other cores are busy). Times are medians of ``--repeats`` runs in this process;
peak memory is measured in a fresh subprocess per implementation (VmHWM, with the input series
included, and above the baseline after making the series). A last part streams 6-axis records of two
lengths through the on-disk cumulative sums to show that memory does not grow with the record (the path
day-long recordings take). ``--k-monte-carlo RUNS`` measures instead how well K comes out of simulated
2 h records (white noise and random walk crossing near 170 s, both readings) against the Cramer-Rao
bound.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

RATE = 1000.0


def series(n: int) -> np.ndarray:
    """White noise plus a random walk, made in pieces so that making it costs no more than the series."""
    rng = np.random.default_rng(2024)
    y = np.empty(n)
    walk = 0.0
    piece = 1 << 20
    for a in range(0, n, piece):
        k = min(piece, n - a)
        steps = np.cumsum(rng.standard_normal(k)) * 1e-5 + walk
        walk = float(steps[-1])
        y[a:a + k] = rng.standard_normal(k) * 0.05 + steps
    return y


def run_ours(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    from station.engines.allan.deviation import overlapping_adev

    return overlapping_adev(y, RATE, m)


def run_ours_one_thread(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The engine on one worker thread: the speed-up left when the other cores are busy."""
    from station.engines.allan.deviation import overlapping_adev

    return overlapping_adev(y, RATE, m, workers=1)


def run_allantools(y: np.ndarray, m: np.ndarray) -> np.ndarray:
    import allantools

    return allantools.oadev(y, rate=RATE, data_type="freq", taus=m / RATE)[1]


def maxrss_mb() -> float:
    """Peak resident memory of this process (VmHWM: unlike ru_maxrss it does not inherit the parent's
    peak across fork and exec)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def child(which: str, n: int) -> None:
    """Run one implementation once and print 'peak baseline' in MB."""
    from station.engines.allan.deviation import cluster_sizes

    y = series(n)
    m = cluster_sizes(n)
    import allantools  # noqa: F401  - both children load the same modules before the baseline

    import station.engines.allan.deviation  # noqa: F401

    base = maxrss_mb()
    (run_ours if which == "ours" else run_allantools)(y, m)
    print(f"{maxrss_mb():.1f} {base:.1f}")


def child_stream(hours: float) -> None:
    """Stream 6 axes at 1 kHz through integrate_stream + the engine; print 'peak seconds' (MB, s)."""
    from station.acquisition.allan_source import AXES, integrate_stream
    from station.engines.allan.deviation import allan_curve

    n = int(hours * 3600 * RATE)
    rows = 200_000
    rng = np.random.default_rng(1)

    def chunks():
        for a in range(0, n, rows):
            k = min(rows, n - a)
            t = (a + np.arange(k)) / RATE
            data = rng.standard_normal((k, 6)) * 0.01
            yield t, data[:, 3:] + [0.0, 0.0, 9.81], data[:, :3]

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        with integrate_stream(chunks(), "synthetic", workdir=tmp) as rec:
            allan_curve(rec.phase, rec.rate_hz, AXES)
    print(f"{maxrss_mb():.1f} {time.perf_counter() - start:.1f}")


def k_bound(k_over_n: float, hours: float = 2.0, rate: float = 200.0, block: int = 20) -> float:
    """Cramer-Rao bound on sd(log K) for N = 1: the asymptotic Fisher information of the block-mean
    increments, sum over the Fourier frequencies 0 < k < n / 2 of u u^T with u = (a g, b h) / S, where
    S = a g + b h is their spectral density (allan_ml eq. 1 as a spectrum: g = (4 / L) s^2,
    h = L - (2 (L^2 - 1) / (3 L)) s^2, s = sin(pi k / n)), inverted."""
    a, b = rate, k_over_n**2 / rate
    n = int(hours * 3600 * rate) // block - 1
    s2 = np.sin(np.pi * np.arange(1, (n + 1) // 2) / n) ** 2
    g, h = 4.0 * s2 / block, block - 2.0 * (block * block - 1.0) / (3.0 * block) * s2
    u = np.stack([a * g, b * h]) / (a * g + b * h)
    return 0.5 * float(np.sqrt(np.linalg.inv(u @ u.T)[1, 1]))


def k_monte_carlo(runs: int) -> None:
    """K over ``runs`` seeds of 2 h at 200 Hz (N = 1e-3), both readings of "the lines cross at 170 s":
    the IEEE 952 fit of the curve, the reported K (likelihood where it applies), the likelihood alone."""
    from scipy import stats

    from station.engines.allan.deviation import allan_curve, integrate_rates
    from station.engines.allan.fit import ML_METHOD, identify_noise
    from station.engines.allan.likelihood import white_walk_ml

    rate, n_density, n = 200.0, 1e-3, int(2 * 3600 * 200.0)
    readings = {"N^2/tau = K^2 tau/3 at 170 s (K = sqrt(3) N/170)": math.sqrt(3.0) / 170.0,
                "N/sqrt(tau) = K sqrt(tau) at 170 s (K = N/170)": 1.0 / 170.0}
    for name, ratio in readings.items():
        k_true = ratio * n_density
        errors: dict[str, list[float]] = {"IEEE 952 fit": [], "reported": [], "likelihood alone": []}
        n_err = []
        for seed in range(runs):
            rng = np.random.default_rng(seed)
            y = (rng.standard_normal(n) * n_density * math.sqrt(rate)
                 + np.cumsum(rng.standard_normal(n) * k_true / math.sqrt(rate)))
            x = integrate_rates(y, rate)
            _, (axis,) = identify_noise(allan_curve(x, rate, ("gx",)), x)
            k = axis.terms["K"]
            fit = k.adev_value if (k.method or "").startswith(ML_METHOD) else k.value
            for key, value in (("IEEE 952 fit", fit), ("reported", k.value),
                               ("likelihood alone", white_walk_ml(x[0], rate).k)):
                errors[key].append(abs(value / k_true - 1.0) if value else math.inf)
            n_err.append(abs(axis.value("N") / n_density - 1.0))
        sd = k_bound(ratio)
        bound = stats.norm.cdf(math.log(1.25) / sd) - stats.norm.cdf(math.log(0.75) / sd)
        print(f"{name}: {runs} runs; bound sd(log K) {sd:.3f}, within 25 % {bound:.1%}; "
              f"N max |error| {max(n_err):.2%}")
        for key, e in errors.items():
            err = np.array(e)
            print(f"  {key}: K within 25 % {np.mean(err < 0.25):.0%}, median |error| {np.median(err):.1%}, "
                  f"null {np.mean(np.isinf(err)):.0%}")


def measure(args: list[str]) -> list[float]:
    out = subprocess.run([sys.executable, __file__, *args], check=True, capture_output=True, text=True)
    return [float(v) for v in out.stdout.split()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, default=10_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--child", choices=["ours", "allantools"])
    parser.add_argument("--stream-hours", type=float)
    parser.add_argument("--k-monte-carlo", type=int, metavar="RUNS",
                        help="instead: K over RUNS simulated 2 h records, against the Cramer-Rao bound")
    args = parser.parse_args()
    if args.k_monte_carlo:
        k_monte_carlo(args.k_monte_carlo)
        return
    if args.child:
        child(args.child, args.samples)
        return
    if args.stream_hours:
        child_stream(args.stream_hours)
        return

    from station.engines.allan.deviation import cluster_sizes

    n = args.samples
    y = series(n)
    m = cluster_sizes(n)
    print(f"series: {n:,} samples, {len(m)} cluster sizes 1..{m[-1]:,} (10 per decade up to N/4)")
    runs = (("allantools", run_allantools), ("ours", run_ours), ("ours, one thread", run_ours_one_thread))
    times: dict[str, list[float]] = {name: [] for name, _ in runs}
    cpu: dict[str, list[float]] = {name: [] for name, _ in runs}
    results = {}
    for _ in range(args.repeats):
        for name, fn in runs:
            start, start_cpu = time.perf_counter(), time.process_time()
            results[name] = fn(y, m)
            times[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    diff = max(float(np.max(np.abs(results[name] / results["allantools"] - 1.0)))
               for name in ("ours", "ours, one thread"))
    t_ref, t_ours = statistics.median(times["allantools"]), statistics.median(times["ours"])
    c_ref, c_ours = statistics.median(cpu["allantools"]), statistics.median(cpu["ours"])
    print(f"wall time (median of {args.repeats}): allantools.oadev {t_ref:.2f} s, "
          f"station allan {t_ours:.2f} s, speed-up x{t_ref / t_ours:.1f}")
    print(f"CPU time (median, all threads): allantools.oadev {c_ref:.2f} s, station allan {c_ours:.2f} s, "
          f"ratio x{c_ref / c_ours:.1f}")
    t_one = statistics.median(times["ours, one thread"])
    print(f"one worker thread (as when one core is free): station allan {t_one:.2f} s wall, "
          f"{statistics.median(cpu['ours, one thread']):.2f} s CPU, speed-up x{t_ref / t_one:.1f}")
    print(f"load average while measuring: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"largest relative difference of the deviations: {diff:.2e}")
    peak = {name: measure(["--child", name, "--samples", str(n)]) for name in ("allantools", "ours")}
    for name, (top, base) in peak.items():
        print(f"peak memory {name}: {top:.0f} MB (series and modules {base:.0f} MB, "
              f"computation +{top - base:.0f} MB)")
    (top_ref, base_ref), (top_ours, base_ours) = peak["allantools"], peak["ours"]
    print(f"peak memory ratio station/allantools: {top_ours / top_ref:.2f} total, "
          f"{(top_ours - base_ours) / max(top_ref - base_ref, 1e-9):.2f} of the computation's share")
    for hours in (0.5, 2.0):
        top, secs = measure(["--stream-hours", str(hours)])
        print(f"streamed 6 axes, {hours:g} h at 1 kHz ({int(hours * 3600 * RATE):,} samples, "
              f"{hours * 3600 * RATE * 48 / 1e6:.0f} MB of sums on disk): peak memory {top:.0f} MB, "
              f"{secs:.1f} s")


if __name__ == "__main__":
    main()
