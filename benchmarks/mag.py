"""Magnetometer calibration: the joint fit (ellipsoid and alignment with the dip constraint) against
plain ellipsoid fits, in one run.

Fit time on 20,000 samples (100 Hz, a simulated hand-held session, accelerometer calibrated first)
against the plain algebraic ellipsoid (a linear least-squares quadric, eq. (6) of
station.engines.magnetometer.fit, the fit Magneto, magcal and the ground stations build on) and the
station's own plain geometric fit (symmetric C, magnitude residual only: what the joint fit does
without a gravity reference), and Magneto's fit (Li & Griffiths' ellipsoid-specific least squares,
written in tests/mag_helpers.py). Then the accuracy of all four, median over seeds, on full-sphere
sessions, on desk-bound sessions (z axis within 45 deg of up) and near-level desk sessions (20
deg), and of the joint fit without an accel section: the raw accelerometer taken as it is (its
bias and misalignment tilt the down direction), and with its intrinsics estimated from the still
poses (``MagSettings(estimate_accel=True)``, what ``calibrate --method mag`` does when PARAMS has no
accel section); both measured in the accelerometer's lower-triangular frame, the one
``calibrate --method free`` reports. Against the issue's targets: full sphere hard iron 0.05 uT,
shape 0.2 %, alignment 0.1 deg; desk 0.4 uT, 1 %, 0.2 deg. A plain fit cannot see the alignment:
its error is the unit's 1-2 deg rotation.

Run: ``.venv/bin/python benchmarks/mag.py [--seeds N] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

from mag_helpers import calibrated_acc, errors, lower_frame, magneto  # noqa: E402
from timing import median_wall_cpu  # noqa: E402

from mocks.mag_sessions import mag_capture  # noqa: E402
from station.engines.magnetometer.calibration import MagCapture, MagSettings, calibrate_mag  # noqa: E402
from station.engines.magnetometer.fit import ellipsoid_fit  # noqa: E402

SAMPLES = 20_000
TARGETS = {"full": (0.05, 0.2, 0.1), "desk": (0.4, 1.0, 0.2), "desk-20": (0.4, 1.0, 0.2)}
SESSIONS = {"full": ("sphere", {"n_poses": 50}), "desk": ("desk", {"n_poses": 37}),
            "desk-20": ("desk", {"n_poses": 37, "max_tilt_deg": 20.0})}


def session(name: str, seed: int) -> tuple[MagCapture, np.ndarray, object]:
    """The first SAMPLES samples of a simulated session, the accelerometer corrected with the truth;
    the raw accelerometer; the truth."""
    kind, options = SESSIONS[name]
    cap, truth = mag_capture(kind, seed, **options)
    n = min(SAMPLES, len(cap.t))
    acc = calibrated_acc(cap.acc, truth)
    return MagCapture(cap.t[:n], cap.mag[:n], acc[:n], cap.gyro[:n]), cap.acc[:n], truth


RAW = ("joint, raw acc as it is", "joint, raw acc estimated")


def fits(data: MagCapture, raw_acc: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(matrix, bias) of the joint fit (calibrated accelerometer; raw, as it is and estimated), the
    plain geometric fit and the algebraic ellipsoid."""
    joint = calibrate_mag(data)
    raw_data = MagCapture(data.t, data.mag, raw_acc, data.gyro)
    raw = calibrate_mag(raw_data)
    estimated = calibrate_mag(raw_data, MagSettings(estimate_accel=True))
    plain = calibrate_mag(data, MagSettings(joint=False))
    algebraic = ellipsoid_fit(data.mag)
    out = {"joint (dip constraint)": (joint.matrix, joint.bias),
           RAW[0]: (raw.matrix, raw.bias), RAW[1]: (estimated.matrix, estimated.bias),
           "plain geometric ellipsoid": (plain.matrix, plain.bias)}
    if algebraic is not None:
        out["plain algebraic ellipsoid"] = (np.linalg.inv(algebraic.correction), algebraic.bias)
    hard, correction = magneto(data.mag, 50.0)
    out["Magneto (Li & Griffiths)"] = (np.linalg.inv(correction), hard)
    return out


def main() -> None:
    """Print the timing and the accuracy table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    data, raw_acc, _ = session("full", 0)
    raw_data = MagCapture(data.t, data.mag, raw_acc, data.gyro)
    print(f"fit time on {len(data.t)} samples (median of {args.repeats}, wall / CPU):")
    joint_wall, joint_cpu, _ = median_wall_cpu(lambda: calibrate_mag(data), args.repeats)
    est_wall, est_cpu, _ = median_wall_cpu(lambda: calibrate_mag(raw_data, MagSettings(estimate_accel=True)),
                                           args.repeats)
    plain_wall, plain_cpu, _ = median_wall_cpu(lambda: calibrate_mag(data, MagSettings(joint=False)),
                                               args.repeats)
    alg_wall, alg_cpu, _ = median_wall_cpu(lambda: ellipsoid_fit(data.mag), args.repeats)
    mag_wall, mag_cpu, _ = median_wall_cpu(lambda: magneto(data.mag, 50.0), args.repeats)
    print(f"  joint fit (checks, start, robust pass, disturbances, final fit, 1-sigma): "
          f"{joint_wall * 1e3:7.1f} / {joint_cpu * 1e3:7.1f} ms")
    print(f"  joint fit, raw accelerometer estimated from the still poses:            "
          f"{est_wall * 1e3:7.1f} / {est_cpu * 1e3:7.1f} ms")
    print(f"  plain geometric ellipsoid (the same pipeline, no gravity):               "
          f"{plain_wall * 1e3:7.1f} / {plain_cpu * 1e3:7.1f} ms")
    print(f"  plain algebraic ellipsoid (one linear least squares):                   "
          f"{alg_wall * 1e3:7.1f} / {alg_cpu * 1e3:7.1f} ms")
    print(f"  Magneto (Li & Griffiths' ellipsoid-specific fit, tests/mag_helpers.py):  "
          f"{mag_wall * 1e3:7.1f} / {mag_cpu * 1e3:7.1f} ms")
    print(f"  ratio joint / algebraic: {joint_cpu / alg_cpu:.0f}x CPU; joint / plain geometric: "
          f"{joint_cpu / plain_cpu:.2f}x CPU; raw accelerometer estimated / calibrated: "
          f"{est_cpu / joint_cpu:.2f}x CPU")

    print(f"\naccuracy, median over {args.seeds} seeds (hard iron uT, shape %, alignment deg); target in []")
    for name in SESSIONS:
        results: dict[str, list[dict[str, float]]] = {}
        cover = []
        for seed in range(args.seeds):
            d, raw_acc, truth = session(name, seed)
            cover.append(calibrate_mag(d).coverage.share)
            for fit, (matrix, bias) in fits(d, raw_acc).items():
                frame = lower_frame(truth) if fit in RAW else None
                results.setdefault(fit, []).append(errors(matrix, bias, truth, frame))
        hard, shape, align = TARGETS[name]
        print(f"{name} (coverage {statistics.median(cover):.0%}), "
              f"target [{hard} uT, {shape} %, {align} deg]:")
        for fit, errs in results.items():
            med = {k: statistics.median(e[k] for e in errs) for k in ("hard_ut", "shape_pct", "align_deg")}
            ok = med["hard_ut"] < hard and med["shape_pct"] < shape and med["align_deg"] < align
            print(f"  {fit:28s} {med['hard_ut']:8.3f} uT {med['shape_pct']:8.3f} % "
                  f"{med['align_deg']:8.3f} deg  {'within' if ok else 'MISSES'} target")


if __name__ == "__main__":
    main()
