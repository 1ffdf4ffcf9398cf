"""Thermal compensation: this engine beside the way PX4 and ArduPilot fit it, on the same sweeps.

Each scenario simulates a unit in the chamber (mocks/chamber.py), fits on one sweep and
scores on another sweep of the same unit at a different ramp speed: the error of the
compensated bias against the injected thermal truth, as RMS and worst of 10 s means, in %
of the bias variation, per axis (constant removed: tilt hides it in one pose).

The peers, written from their sources:

- PX4 (``TemperatureCalibration*``, ``TC_*`` parameters): offset = X0 + X1 t + X2 t^2 + X3 t^3,
  t = T - TREF, TREF the middle of the range, least squares over the samples recorded while
  the temperature rises, T clamped to [TMIN, TMAX].
- ArduPilot (``AP_InertialSensor_tempcal.cpp``): the same cubic over means of at least 100
  samples taken each time the low-passed temperature has risen by 0.5 degC, t = T - 35 degC,
  heating only (each warm-up learnt afresh), T clamped to [TMIN, TMAX]; the constant is
  dropped (the offsets of the normal calibration carry it), which the scoring's constant
  removal makes equivalent.

Run: ``.venv/bin/python benchmarks/thermal.py`` (about a minute). Fit times are medians of 3.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from mocks.chamber import ChamberSweep, chamber_sweep, cubic_rate_unit
from mocks.truth import ThermalTruth, UnitTruth
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.fit import ThermalSweep, fit_thermal
from station.engines.thermal.model import estimate_dtemp

RATE_HZ = 10.0
ARDUPILOT_TREF = 35.0


@dataclass
class Cubic:
    """A per-axis cubic in T - t_ref with a constant, T clamped: what PX4 and ArduPilot store."""

    coeffs: np.ndarray  # (3 axes, 4) highest power first, as numpy.polyval takes them
    t_ref: float
    t_min: float
    t_max: float

    def evaluate(self, temp: np.ndarray) -> np.ndarray:
        t = np.clip(temp, self.t_min, self.t_max) - self.t_ref
        return np.column_stack([np.polyval(c, t) for c in self.coeffs])


def px4_fit(temp: np.ndarray, dtemp: np.ndarray, bias: np.ndarray) -> Cubic:
    rising = dtemp > 0
    t_min, t_max = float(temp[rising].min()), float(temp[rising].max())
    t_ref = 0.5 * (t_min + t_max)
    coeffs = np.array([np.polyfit(temp[rising] - t_ref, bias[rising, j], 3) for j in range(3)])
    return Cubic(coeffs, t_ref, t_min, t_max)


def ardupilot_fit(temp: np.ndarray, dtemp: np.ndarray, bias: np.ndarray) -> Cubic:
    """Bins of >= 100 samples closed each time the filtered temperature rose 0.5 degC."""
    rising = np.flatnonzero(dtemp > 0)
    xs, ys = [], []
    start, last_temp = 0, temp[rising[0]]
    for k, i in enumerate(rising):
        if temp[i] < last_temp - 0.5:  # a new warm-up (after a cooling leg) starts learning afresh
            start, last_temp = k, temp[i]
        if k - start + 1 >= 100 and temp[i] - last_temp >= 0.5:
            sel = rising[start : k + 1]
            xs.append(0.5 * (temp[i] + last_temp))
            ys.append(bias[sel].mean(axis=0))
            start, last_temp = k + 1, temp[i]
    x, y = np.array(xs), np.array(ys)
    coeffs = np.array([np.polyfit(x - ARDUPILOT_TREF, y[:, j], 3) for j in range(3)])
    return Cubic(coeffs, ARDUPILOT_TREF, float(x.min()), float(x.max()))


def score(model_bias: np.ndarray, truth: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    err = truth - model_bias
    err -= err.mean(axis=0)
    n = int(10 * rate_hz)
    means = err[: len(err) // n * n].reshape(-1, n, 3).mean(axis=1)
    variation = np.ptp(truth, axis=0)
    return 100 * np.sqrt(np.mean(means**2, axis=0)) / variation, 100 * np.max(
        np.abs(means), axis=0
    ) / variation


def median_time(fn, repeats: int = 3) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), out


def kinked(temp: np.ndarray, dtemp: np.ndarray) -> np.ndarray:
    knee = np.maximum(temp - 20.0, 0.0)
    return np.column_stack([2e-3 * knee, -1.5e-3 * knee, 2.5e-3 * knee])


def scenarios() -> list[tuple[str, UnitTruth, ChamberSweep, list[float], dict]]:
    sweep = ChamberSweep(low_degc=-10.0, high_degc=50.0, start_degc=20.0, ramp_degc_per_min=3.0, soak_s=300.0)
    cubic = cubic_rate_unit(11)
    flat = UnitTruth.random(8)
    flat = replace(
        flat,
        accel=replace(flat.accel, thermal=ThermalTruth()),
        gyro=replace(flat.gyro, thermal=ThermalTruth()),
    )
    warmup = ChamberSweep(
        low_degc=20.0,
        high_degc=20.0,
        start_degc=20.0,
        ramp_degc_per_min=1.0,
        soak_s=2400.0,
        self_heating_degc=25.0,
        self_heating_tau_s=600.0,
    )
    return [
        ("cubic + dT, chamber 3 degC/min", cubic, sweep, [1.5, 5.0], {}),
        (
            "cubic + dT, six poses",
            cubic_rate_unit(21),
            replace(sweep, poses=("+x", "-x", "+y", "-y", "+z", "-z"), pose_hold_s=40.0),
            [1.5],
            {},
        ),
        ("slope kink at 20 degC", flat, sweep, [1.5], {"accel_bias": kinked}),
        ("power-on self-heating only", cubic, warmup, [], {}),
    ]


def main() -> None:
    print(__doc__.split("\n\n")[0])
    print(
        f"sample rate {RATE_HZ:g} Hz; figures: % of the bias variation (RMS / worst 10 s mean), "
        "per axis x y z\n"
    )
    for name, truth, sweep, other_speeds, extra in scenarios():
        cal = {
            "accel_cal": SensorCalibration(truth.accel.matrix, truth.accel.bias),
            "gyro_cal": SensorCalibration(truth.gyro.matrix, truth.gyro.bias),
        }
        run = chamber_sweep(truth, sweep, rate_hz=RATE_HZ, seed=1, **extra)
        r = run.recording
        data = ThermalSweep(r.t, r.temp, r.acc, r.gyro, r.step, **cal)
        t_ours, fit = median_time(lambda data=data: fit_thermal(data))
        # The peers filter T lightly; their dT only decides "rising", so any smooth estimate serves.
        # They get the exact bias (the true specific force removed) of the still samples: an advantage.
        rising = estimate_dtemp(r.t, r.temp, fit.model.dtemp_filter)
        still = np.asarray(r.step) != ""
        raw = {
            "accel": r.acc - r.true_specific_force @ truth.accel.matrix.T - truth.accel.bias,
            "gyro": r.gyro - truth.gyro.bias,
        }
        peers = {}
        for triad in ("accel", "gyro"):
            args = (r.temp[still], rising[still], raw[triad][still])
            t_px4, px4 = median_time(lambda a=args: px4_fit(*a))
            t_ap, ap = median_time(lambda a=args: ardupilot_fit(*a))
            peers[triad] = (px4, ap, t_px4, t_ap)
        print(
            f"== {name}: fit on {r.t[-1] / 60:.0f} min, {len(r.t)} samples; this engine chose "
            f"{len(fit.model.accel.segments)} accel / {len(fit.model.gyro.segments)} gyro segment(s), "
            f"tau {fit.model.dtemp_filter.tau_s:g} s, accel terms "
            f"{['+'.join(a.terms) for a in fit.triads['accel'].axes]}"
        )
        print(
            f"   fit time: this engine {t_ours:.2f} s (terms x segments x tau by 5-fold CV), "
            f"PX4 {peers['accel'][2] + peers['gyro'][2]:.4f} s, "
            f"ArduPilot {peers['accel'][3] + peers['gyro'][3]:.4f} s "
            f"(ratio engine/PX4 {t_ours / (peers['accel'][2] + peers['gyro'][2]):.0f}x)"
        )
        tests = [("same sweep", run)] + [
            (
                f"other sweep {s:g} degC/min",
                chamber_sweep(truth, replace(sweep, ramp_degc_per_min=s), rate_hz=RATE_HZ, seed=7, **extra),
            )
            for s in other_speeds
        ]
        if not other_speeds:
            tests.append(
                (
                    "another warm-up",
                    chamber_sweep(
                        truth, replace(sweep, self_heating_tau_s=400.0), rate_hz=RATE_HZ, seed=7, **extra
                    ),
                )
            )
        for label, test in tests:
            tr = test.recording
            dtemp = estimate_dtemp(tr.t, tr.temp, fit.model.dtemp_filter)
            for triad, truth_bias in (("accel", test.thermal_accel), ("gyro", test.thermal_gyro)):
                if np.all(np.ptp(truth_bias, axis=0) == 0):
                    continue  # this unit has no thermal bias on that triad
                ours = getattr(fit.model, triad).evaluate(tr.temp, dtemp, fit.model.reference_temp)
                px4, ap, _, _ = peers[triad]
                rows = [
                    ("this engine", score(ours, truth_bias, RATE_HZ)),
                    ("PX4 cubic", score(px4.evaluate(tr.temp), truth_bias, RATE_HZ)),
                    ("ArduPilot cubic", score(ap.evaluate(tr.temp), truth_bias, RATE_HZ)),
                ]
                base = rows[0][1][0]
                for who, (rms, worst) in rows:
                    ratio = (
                        ""
                        if who == "this engine"
                        else f"  RMS ratio to engine {np.round(rms / np.maximum(base, 1e-9), 1)}"
                    )
                    print(
                        f"   {label:<26} {triad:<5} {who:<16} RMS {np.round(rms, 2)}  "
                        f"worst {np.round(worst, 1)}"
                        + ratio
                    )
        print()


if __name__ == "__main__":
    main()
