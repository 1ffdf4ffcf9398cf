"""Calibration engine benchmark, in one run:

1. imucal's FerrarisCalibration (PyPI) and this engine's turntable method on the same simulated
   Ferraris-style captures (six holds, then turns about every axis), parameter errors against the
   simulated truth side by side, per group (accel matrix, accel bias, gyro matrix, gyro bias).
2. The turntable-free method timed on imu_tk's Xsens session (51,175 rows), imu_tk's settings and
   the station's defaults, medians of repeats; imu_tk's compiled gyro stage takes about 0.3 s.

    .venv/bin/python benchmarks/calibration.py [--seeds 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import gzip
import os
import sys
from functools import partial
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from imucal import FerrarisCalibration  # noqa: E402
from imucal.ferraris_calibration import FerrarisSignalRegions  # noqa: E402
from timing import median_wall_cpu  # noqa: E402

from mocks.rig import sequence_segments, simulate  # noqa: E402
from mocks.truth import UnitTruth  # noqa: E402
from station.engines.calibration_free import (  # noqa: E402
    FreeSettings,
    calibrate_free,
    fit_gyroscope,
    gyro_blocks,
)
from station.engines.calibration_turntable import calibrate_turntable  # noqa: E402
from station.engines.static_detect import moving_variance_norm, static_intervals, variance_norm  # noqa: E402

XSENS = REPO.parent / "shared" / "data" / "xsens-imu_tk"
IMUCAL_REGIONS = (("+x", "x_p"), ("-x", "x_a"), ("+y", "y_p"), ("-y", "y_a"), ("+z", "z_p"), ("-z", "z_a"),
                  ("rot-x", "x_rot"), ("rot-y", "y_rot"), ("rot-z", "z_rot"))
GROUPS = ("accel matrix", "accel bias (m/s^2)", "gyro matrix", "gyro bias (rad/s)")


def errors(matrix_a, bias_a, matrix_g, bias_g, truth: UnitTruth) -> list[float]:
    pairs = ((matrix_a, truth.accel.matrix), (bias_a, truth.accel.bias), (matrix_g, truth.gyro.matrix),
             (bias_g, truth.gyro.bias))
    return [float(np.abs(np.asarray(est) - true).max()) for est, true in pairs]


def compare_with_imucal(seeds: int, hold_s: float, rate_hz: float) -> None:
    print(f"1. Ferraris-style captures: six holds of {hold_s:g} s and 360 deg turns at 90 deg/s about every "
          f"axis both ways, {rate_hz:g} Hz, UnitTruth.random(seed) MEMS noise, seeds 0..{seeds - 1}")
    ours, theirs = [], []
    for seed in range(seeds):
        truth = UnitTruth.random(seed)
        segments = sequence_segments("six-position", True, hold_s=hold_s)
        rec = simulate(truth, segments, rate_hz=rate_hz, seed=seed)
        rep = calibrate_turntable(rec.t, rec.acc, rec.gyro, rec.step, truth.gravity)
        ours.append(errors(rep.accel.matrix, rep.accel.bias, rep.gyro.matrix, rep.gyro.bias, truth))
        regions = {}
        for label, name in IMUCAL_REGIONS:
            rows = rec.step == label
            regions[f"acc_{name}"] = rec.acc[rows]
            regions[f"gyr_{name}"] = np.degrees(rec.gyro[rows])
        info = FerrarisCalibration(grav=truth.gravity).compute(FerrarisSignalRegions(**regions), rate_hz,
                                                               "m/s^2", "deg/s")
        # imucal got raw and true rates both in deg/s (raw = K_g R_g w + K_ga a + b_g), so K_g R_g is
        # unitless like the truth's matrix and only its bias needs converting
        theirs.append(errors(info.K_a @ info.R_a, info.b_a, info.K_g @ info.R_g, np.radians(info.b_g), truth))
    ours_a, theirs_a = np.array(ours), np.array(theirs)
    print(f"   {'group (max abs error per capture)':36s} {'this engine: RMS':>18s} {'max':>10s}   "
          f"{'imucal: RMS':>12s} {'max':>10s}   ratio")
    worst = 0.0
    for k, group in enumerate(GROUPS):
        rms_o = float(np.sqrt(np.mean(ours_a[:, k] ** 2)))
        rms_t = float(np.sqrt(np.mean(theirs_a[:, k] ** 2)))
        worst = max(worst, rms_o / rms_t)
        print(f"   {group:36s} {rms_o:18.3e} {ours_a[:, k].max():10.3e}   {rms_t:12.3e} "
              f"{theirs_a[:, k].max():10.3e}   {rms_o / rms_t:.3f}")
    verdict = "at most imucal's on every group" if worst <= 1.0 + 1e-9 else "WORSE than imucal on some group"
    print(f"   this engine's RMS error is {verdict} (largest ratio {worst:.3f})")


def _read(path: Path) -> np.ndarray:
    with gzip.open(path, "rt") as fh:
        return np.loadtxt(fh)


def time_free(repeats: int) -> None:
    if not XSENS.is_dir():
        print(f"2. skipped: {XSENS} not found")
        return
    acc = _read(XSENS / "xsens_acc.txt.gz")
    gyro = _read(XSENS / "xsens_gyro.txt.gz")
    t = acc[:, 0]
    print(f"2. turntable-free method on imu_tk's Xsens session ({len(t)} rows), median of {repeats} runs")
    runs = {"imu_tk settings (upper, 101-sample window)": (50.0, "upper", FreeSettings.imu_tk()),
            "station defaults (lower, 1 s window, detected still)": (None, "lower", FreeSettings())}
    for name, (still, convention, settings) in runs.items():
        run = partial(calibrate_free, t, acc[:, 1:], gyro[:, 1:], 9.81744, still, convention, settings)
        wall_s, cpu_s, report = median_wall_cpu(run, repeats)
        print(f"   {name:54s} total {wall_s:.3f} s wall, {cpu_s:.3f} s CPU, "
              f"k = {report.details['chosen_multiplier']:g}, "
              f"{report.accel.extra['static_intervals']} intervals")
    # the gyroscope stage alone, as imu_tk's 0.3 s figure is for its gyro stage
    report = calibrate_free(t, acc[:, 1:], gyro[:, 1:], 9.81744, 50.0, "upper", FreeSettings.imu_tk())
    vnorm = moving_variance_norm(acc[:, 1:], 101)
    intervals = static_intervals(vnorm, 6 * variance_norm(acc[:5001, 1:]), 50)
    intervals = intervals[(intervals[:, 1] - intervals[:, 0]) >= 100]
    calibrated = (acc[:, 1:] - report.accel.bias) @ report.details["accel_correction"].T
    directions = np.array([calibrated[a:b + 1].mean(axis=0) for a, b in intervals])
    gyro_s, gyro_cpu, _ = median_wall_cpu(
        lambda: fit_gyroscope(gyro_blocks(t, gyro[:, 1:] - report.gyro.bias, intervals, directions)), repeats)
    print(f"   gyroscope stage alone (37 blocks, analytic Jacobian): {gyro_s:.3f} s wall, "
          f"{gyro_cpu:.3f} s CPU; imu_tk (Ceres, autodiff, compiled) about 0.3 s: ratio "
          f"{gyro_cpu / 0.3:.2f} (CPU)")
    print(f"   (machine load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs: wall times "
          "include waiting for the CPU)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--hold", type=float, default=30.0, help="hold of each static pose, s")
    parser.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    args = parser.parse_args()
    compare_with_imucal(args.seeds, args.hold, args.rate)
    time_free(args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
