"""The noise model on real units: both ADIS16405 still recordings (10,000 s at 100 Hz) of
../shared/data/adis16405-smac (read from there when present, never copied), and Gauss-Markov recovery on
simulated records.

Part 1, per record and axis: the command's pipeline (integrate, curve at the default cluster sizes,
identify_noise with the model selection), then the model checked at cluster times a factor of two apart
from 0.02 s to the longest (m = 2, 4, 8, ...), with EDF from the model's own slope: how many fall
outside the 68 % interval and more than 10 % from the curve, inside the model's valid range; the same for
the IEEE 952 fit alone (the peer: what the station reported before), and the fit times (median per axis,
and the ratio to the IEEE fit's).

Part 2: white noise N = 7e-4 rad/s/sqrt(Hz) and a Gauss-Markov bias of sigma 5e-4 rad/s, tau_c 300 s,
10 h at 100 Hz (the mocks' generator), three axes a run: how often the largest process's sigma is within
15 % and tau_c within 30 %.

    .venv/bin/python benchmarks/allan_adis.py [--gm-runs 20] [--plot DIR]
"""

from __future__ import annotations

import argparse
import gzip
import statistics
import time
from pathlib import Path

import numpy as np

from mocks.truth import FLICKER_FLOOR, GM_ADEV_PEAK, NoiseGenerator, NoiseSpec
from station.engines.allan.deviation import (
    AllanCurve,
    allan_curve,
    alpha_from_slope,
    confidence_interval,
    edf_table,
    integrate_rates,
)
from station.engines.allan.fit import AxisNoise, dominant_alpha, fit_axis, identify_noise
from station.engines.allan.model import ieee_model

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "adis16405-smac"
RECORDS = ("adis_16405_imu2.csv.gz", "adis_16405_imu3.csv.gz")
AXES = ("gx", "gy", "gz", "ax", "ay", "az")
RATE = 100.0
G = 9.80665
TOLERANCE = 0.10


def read_record(path: Path) -> np.ndarray:
    """gyro deg/s and accel g columns to rad/s and m/s^2."""
    with gzip.open(path, "rt") as f:
        v = np.loadtxt(f, delimiter=",", skiprows=1)
    return np.column_stack([np.radians(v[:, :3]), v[:, 3:] * G])


def outside_dyadic(phase: np.ndarray, curve: AllanCurve, axis: int, model_adev, valid: tuple[float, float]
                   ) -> tuple[int, int, list[float]]:
    """Cluster times m = 2^k (tau from 0.02 s) in ``valid`` where the model is outside the 68 % interval
    and more than 10 % from the curve; EDF from the model's slope."""
    m = 2 ** np.arange(1, int(np.log2(curve.n_samples / 4)) + 1)
    c2 = allan_curve(phase[axis:axis + 1], curve.rate_hz, (AXES[axis],), m=m)
    model = model_adev(c2.tau)
    edf = edf_table(alpha_from_slope(c2.tau, model[:, None]), m, c2.n_samples + 1)[:, 0]
    lo, hi = confidence_interval(c2.adev[:, 0], edf)
    inside = (c2.tau >= valid[0] * (1 - 1e-9)) & (c2.tau <= valid[1] * (1 + 1e-9))
    bad = ((model < lo) | (model > hi)) & (np.abs(model / c2.adev[:, 0] - 1) > TOLERANCE) & inside
    return int(bad.sum()), int(inside.sum()), [float(t) for t in c2.tau[bad]]


def ieee_only(curve: AllanCurve) -> tuple[AllanCurve, list[AxisNoise], float]:
    """The IEEE 952 fit as identify_noise's two passes make it (no model selection), and its time."""
    start = time.perf_counter()
    first = [fit_axis(curve.tau, curve.adev[:, j], curve.edf[:, j], curve.duration_s, n)
             for j, n in enumerate(curve.axes)]
    refined = curve.with_alpha(np.column_stack([dominant_alpha(curve.tau, f) for f in first]))
    noise = [fit_axis(refined.tau, refined.adev[:, j], refined.edf[:, j], refined.duration_s, n)
             for j, n in enumerate(refined.axes)]
    return refined, noise, time.perf_counter() - start


def adis(plot_dir: Path | None) -> None:
    """Part 1."""
    if not DATA.is_dir():
        print(f"{DATA} is not there: part 1 skipped")
        return
    fit_times, peer_times, cpu_times = [], [], []
    print("record  axis  outside/points (model)  outside/points (IEEE fit)  valid tau (s)      model")
    for name in RECORDS:
        phase = integrate_rates(read_record(DATA / name), RATE)
        curve = allan_curve(phase, RATE, AXES)
        refined, ieee, peer_s = ieee_only(curve)
        start, start_cpu = time.perf_counter(), time.process_time()
        final, noise = identify_noise(curve, phase)
        fit_s = time.perf_counter() - start
        fit_times.append(fit_s / len(AXES))
        cpu_times.append((time.process_time() - start_cpu) / len(AXES))
        peer_times.append(peer_s / len(AXES))
        for j, axis in enumerate(noise):
            m = axis.noise_model
            assert m is not None
            out, pts, where = outside_dyadic(phase, final, j, axis.model, m.valid_tau)
            peer = ieee_model(ieee[j], refined.tau, refined.adev[:, j], refined.edf[:, j],
                              refined.ci_low[:, j], refined.ci_high[:, j], RATE)
            p_out, p_pts, _ = outside_dyadic(phase, final, j, ieee[j].model, peer.valid_tau)
            print(f"{name[11:15]}    {axis.axis}    {out:2d}/{pts:2d} {where!s:14}  {p_out:2d}/{p_pts:2d}"
                  f"                      {m.valid_tau[0]:.3g} .. {m.valid_tau[1]:.4g}   {m.describe()}")
        if plot_dir is not None:
            from station.plots.allan import write_png

            write_png(plot_dir / f"{name[:-7]}.png", final, noise, title=name)
    med, peer = statistics.median(fit_times), statistics.median(peer_times)
    print(f"fit time per axis, median of the records: {med:.2f} s wall, {statistics.median(cpu_times):.2f} s "
          f"CPU (IEEE 952 fit alone {peer:.3f} s wall, ratio {med / peer:.0f}x)")


def gauss_markov_recovery(runs: int) -> None:
    """Part 2."""
    sigma, tau_c, rate, hours = 5e-4, 300.0, 100.0, 10.0
    spec = NoiseSpec(N=[7e-4] * 3, B=[sigma * GM_ADEV_PEAK / FLICKER_FLOOR] * 3, b_corr_time_s=tau_c)
    s_err, t_err, times = [], [], []
    s_sd, t_sd, s_log, t_log = [], [], [], []  # reported relative 1-sigma against the log errors
    for seed in range(runs):
        y = NoiseGenerator(spec, rate, np.random.SeedSequence(seed)).next(int(hours * 3600 * rate))
        phase = integrate_rates(y, rate)
        curve = allan_curve(phase, rate, ("gx", "gy", "gz"))
        start = time.perf_counter()
        _, noise = identify_noise(curve, phase)
        times.append((time.perf_counter() - start) / 3)
        for axis in noise:
            gms = axis.noise_model.gauss_markov if axis.noise_model is not None else []
            big = max(gms, key=lambda g: g.sigma.value, default=None)
            s_err.append(np.inf if big is None else abs(big.sigma.value / sigma - 1))
            t_err.append(np.inf if big is None else abs(big.tau_c.value / tau_c - 1))
            if big is not None and big.sigma.stddev is not None and big.tau_c.stddev is not None:
                s_sd.append(big.sigma.stddev / big.sigma.value)
                t_sd.append(big.tau_c.stddev / big.tau_c.value)
                s_log.append(np.log(big.sigma.value / sigma))
                t_log.append(np.log(big.tau_c.value / tau_c))
    s_err_a, t_err_a = np.array(s_err), np.array(t_err)
    both = np.count_nonzero((s_err_a < 0.15) & (t_err_a < 0.30))
    print(f"Gauss-Markov sigma {sigma:g} rad/s, tau_c {tau_c:g} s, {hours:g} h at {rate:g} Hz, {runs} runs "
          f"x 3 axes: sigma within 15 % {np.count_nonzero(s_err_a < 0.15)}/{len(s_err)}, tau_c within 30 % "
          f"{np.count_nonzero(t_err_a < 0.30)}/{len(t_err)}, both {both}/{len(s_err)} "
          f"({both / len(s_err):.0%}); "
          f"median |error| sigma {np.median(s_err_a):.1%}, tau_c {np.median(t_err_a):.1%}; "
          f"fit time per axis median {statistics.median(times):.2f} s")
    if s_sd:
        rms_s, rms_t = np.sqrt(np.mean(np.square(s_log))), np.sqrt(np.mean(np.square(t_log)))
        print(f"1-sigma reported on {len(s_sd)}/{len(s_err)} axes: median sigma {np.median(s_sd):.1%}, tau_c "
              f"{np.median(t_sd):.1%}; scatter (RMS log error) sigma {rms_s:.1%}, tau_c {rms_t:.1%}")


def main() -> None:
    """Run both parts."""
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gm-runs", type=int, default=20)
    parser.add_argument("--plot", type=Path, metavar="DIR", help="write each record's Allan plot there")
    args = parser.parse_args()
    adis(args.plot)
    if args.gm_runs:
        gauss_markov_recovery(args.gm_runs)


if __name__ == "__main__":
    main()
