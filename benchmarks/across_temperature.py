"""Calibration across temperature against calibrating at one soak, on simulated units whose bias, scale
factor and misalignment all move with T (``UnitTruth.random(seed, thermal_intrinsics=True)``: scale
50-300 ppm/degC with curvature, misalignment 1-5 urad/degC, the cubic thermal bias, MEMS noise and
16-bit quantization).

Per seed: the twelve-position sequence with its six turns (``--hold`` s per pose, 100 Hz) at each soak
temperature (default -20, 0, 20, 40, 60 degC), each calibrated by the turntable method; then
``fit_across_temperature`` over the soaks, and, for comparison, the calibration of the soak nearest the
check temperature used as it is. At each check temperature between soaks (default 10, 30, 50 degC) the
error against the truth's K(T), S(T) and b + b_T(T) is taken as the largest over the axes (entries for
the misalignment), in ppm of K, urad, mg and deg/h; the table gives the median over the seeds, and for
the fit also the median of the largest |error| / reported 1-sigma.

    .venv/bin/python benchmarks/across_temperature.py [--seeds 5] [--hold 20] [--check 10 30 50]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from mocks.rig import constant, sequence_segments, simulate  # noqa: E402
from mocks.truth import SensorTruth, UnitTruth  # noqa: E402
from protocols.units import STANDARD_GRAVITY  # noqa: E402
from station.engines.calibration.turntable import (  # noqa: E402
    TurntableCapture,
    TurntableSettings,
    calibrate_turntable,
)
from station.engines.thermal.intrinsics import OFF_DIAGONAL  # noqa: E402
from station.engines.thermal.intrinsics_fit import SoakCalibration, fit_across_temperature  # noqa: E402

RATE_HZ = 100.0
ROWS, COLS = np.array(OFF_DIAGONAL).T
# (label, triad, quantity, factor from the error to the printed unit; scale is relative, handled apart)
ROWS_SHOWN = (
    ("accel scale (ppm)", "accel", "scale", 1e6),
    ("accel misalignment (urad)", "accel", "misalignment", 1e6),
    ("accel bias (mg)", "accel", "bias", 1e3 / STANDARD_GRAVITY),
    ("gyro scale (ppm)", "gyro", "scale", 1e6),
    ("gyro misalignment (urad)", "gyro", "misalignment", 1e6),
    ("gyro bias (deg/h)", "gyro", "bias", 3600.0 * 180.0 / np.pi),
)


def truth_at(sensor: SensorTruth, temp: float) -> dict[str, np.ndarray]:
    t = np.array([temp])
    return {"scale": sensor.scale_at(t)[0], "misalignment": sensor.misalignment_at(t)[0][ROWS, COLS],
            "bias": sensor.bias + sensor.thermal.bias(t, np.zeros(1))[0]}


def one_seed(seed: int, soak_temps: list[float], checks: list[float], hold_s: float) -> dict[tuple, tuple]:
    """Per (check temperature, row): the fit's error, its error over 1-sigma, the nearest soak's error."""
    truth = UnitTruth.random(seed, thermal_intrinsics=True)
    segments = sequence_segments("twelve-position", True, hold_s=hold_s)
    soaks = []
    for k, temp in enumerate(soak_temps):
        rec = simulate(truth, segments, rate_hz=RATE_HZ, seed=1000 * seed + k, temperature=constant(temp))
        report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step, rate_hz=RATE_HZ),
                                     TurntableSettings(gravity=truth.gravity))
        soaks.append(SoakCalibration(float(np.mean(rec.temp)), report, f"{temp:g}"))
    result = fit_across_temperature(soaks)
    out = {}
    for temp in checks:
        nearest = min(soaks, key=lambda s: abs(s.temp - temp)).report
        for label, triad, q, factor in ROWS_SHOWN:
            true = truth_at(getattr(truth, triad), temp)[q]
            fit = result.fits[f"{triad}.{q}"]
            err = fit.evaluate([temp])[0] - true
            z = np.abs(err) / fit.stddev([temp])[0]
            cal = getattr(nearest, triad)
            alone = {"scale": cal.scale, "misalignment": cal.misalignment[ROWS, COLS], "bias": cal.bias}[q]
            err_alone = alone - true
            if q == "scale":  # ppm of K
                err, err_alone = err / true, err_alone / true
            out[temp, label] = (np.abs(err).max() * factor, z.max(), np.abs(err_alone).max() * factor)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--hold", type=float, default=20.0, help="seconds per pose (default 20)")
    parser.add_argument("--soaks", type=float, nargs="+", default=[-20.0, 0.0, 20.0, 40.0, 60.0])
    parser.add_argument("--check", type=float, nargs="+", default=[10.0, 30.0, 50.0])
    args = parser.parse_args()
    start = time.perf_counter()
    runs = [one_seed(seed, args.soaks, args.check, args.hold) for seed in range(1, args.seeds + 1)]
    print(f"{args.seeds} simulated units (seeds 1..{args.seeds}), soaks at "
          f"{', '.join(f'{t:g}' for t in args.soaks)} degC, twelve positions + six turns, {args.hold:g} s "
          f"holds, 100 Hz; {time.perf_counter() - start:.1f} s")
    for temp in args.check:
        print(f"\nerror against the truth at {temp:g} degC (median over seeds of the largest over axes or "
              "entries)")
        print(f"{'':<28}{'across temperature':>20}{'|err|/1-sigma':>15}{'nearest soak':>15}{'ratio':>8}")
        for label, *_ in ROWS_SHOWN:
            fit, z, alone = (float(np.median([r[temp, label][i] for r in runs])) for i in range(3))
            print(f"{label:<28}{fit:>20.3g}{z:>15.2f}{alone:>15.3g}{alone / fit:>8.1f}")


if __name__ == "__main__":
    main()
