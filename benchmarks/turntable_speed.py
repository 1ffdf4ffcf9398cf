"""Turntable method speed: a twelve-position session with the six rotations, 1 kHz, 10 minutes.

    .venv/bin/python benchmarks/turntable_speed.py [--repeats 5] [--minutes 10]

A simulated unit (``UnitTruth.random(3)``) is moved through the built-in twelve-position sequence and the
six 360 deg turns at 90 deg/s, the holds lengthened until the session lasts ``--minutes``, sampled at
1 kHz, and written as a station capture file (.h5). Timed, medians of ``--repeats``:

- the engine alone (``calibrate_turntable`` on the arrays in memory), wall and CPU;
- the whole process ``imu-station calibrate FILE --method turntable -o params.yaml`` (start-up, reading,
  fit, writing), the target being under 1 s;
- beside them, imucal's ``FerrarisCalibration`` (the peer of ``benchmarks/calibration.py``) on the six
  axis-aligned holds and the x, y, z turns of the same session, the part of it imucal's method takes.

The parameter errors against the simulated truth are printed for the station (accuracy is what
``benchmarks/calibration.py`` compares; here they show the fast path did not cost any).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from process_timing import installed_env, run_process  # noqa: E402
from timing import median_wall_cpu  # noqa: E402

from mocks.rig import sequence_segments, simulate  # noqa: E402
from mocks.truth import UnitTruth  # noqa: E402

RATE = 1000.0
IMUCAL_REGIONS = (("+x", "x_p"), ("-x", "x_a"), ("+y", "y_p"), ("-y", "y_a"), ("+z", "z_p"), ("-z", "z_a"),
                  ("rot+x", "x_rot"), ("rot+y", "y_rot"), ("rot+z", "z_rot"))


def session(minutes: float):
    """The twelve-position session lasting ``minutes``, and its truth."""
    truth = UnitTruth.random(3)
    # the moves and turns take what one-second holds leave (the simulator adds its own settling)
    short = simulate(truth, sequence_segments("twelve-position", True, hold_s=1.0), rate_hz=10.0)
    fixed = len(short.t) / 10.0 - 12.0
    hold_s = (minutes * 60.0 - fixed) / 12.0
    rec = simulate(truth, sequence_segments("twelve-position", True, hold_s=hold_s), rate_hz=RATE, seed=3)
    return rec, truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--minutes", type=float, default=10.0)
    args = parser.parse_args()

    from station.acquisition.capture_h5 import H5CaptureWriter
    from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable

    rec, truth = session(args.minutes)
    capture = rec.to_capture()
    print(f"session: twelve positions and six turns, {len(capture):,} samples at {RATE:g} Hz "
          f"({len(capture) / RATE / 60:.1f} min)")
    data = TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step, RATE)
    settings = TurntableSettings(gravity=truth.gravity)
    engine_wall, engine_cpu, report = median_wall_cpu(lambda: calibrate_turntable(data, settings),
                                                      args.repeats)
    errors = [float(np.abs(np.asarray(est) - ref).max()) for est, ref in (
        (report.accel.matrix, truth.accel.matrix), (report.accel.bias, truth.accel.bias),
        (report.gyro.matrix, truth.gyro.matrix), (report.gyro.bias, truth.gyro.bias))]

    with tempfile.TemporaryDirectory(prefix="turntable-bench-") as tmp:
        path = Path(tmp) / "twelve.h5"
        writer = H5CaptureWriter(path, device={"serial": "bench-twelve", "rate_hz": RATE}, with_step=True)
        writer.write(rec.samples(), step=capture.step)
        writer.close()
        cmd = [str(Path(sys.executable).with_name("imu-station")), "calibrate", str(path), "--method",
               "turntable", "--gravity", repr(truth.gravity), "-o", str(Path(tmp) / "params.yaml"),
               "--replace"]
        env = installed_env()
        run_process(cmd, env=env)  # compiled modules cached first
        runs = [run_process(cmd, env=env) for _ in range(args.repeats)]
    process_wall = statistics.median(r.wall for r in runs)
    process_cpu = statistics.median(r.cpu for r in runs)

    imucal_wall = imucal_time(rec, capture.step, truth.gravity, args.repeats)
    print(f"median of {args.repeats}:")
    print(f"  station engine (calibrate_turntable, in memory): {engine_wall:.3f} s wall, "
          f"{engine_cpu:.3f} s CPU")
    print(f"  imu-station calibrate --method turntable, whole process: {process_wall:.3f} s wall, "
          f"{process_cpu:.3f} s CPU (walls {' '.join(format(r.wall, '.2f') for r in runs)}; "
          "target under 1 s)")
    if imucal_wall is not None:
        print(f"  imucal FerrarisCalibration, six holds and three turns of it, in memory: "
              f"{imucal_wall:.3f} s "
              f"(engine ratio station / imucal {engine_wall / imucal_wall:.2f})")
    print("station errors against the truth: accel matrix {:.2e}, accel bias {:.2e} m/s^2, "
          "gyro matrix {:.2e}, gyro bias {:.2e} rad/s".format(*errors))


def imucal_time(rec, step: np.ndarray, gravity: float, repeats: int) -> float | None:
    """imucal's Ferraris calibration on its nine regions of the session, median wall seconds."""
    try:
        from imucal import FerrarisCalibration
        from imucal.ferraris_calibration import FerrarisSignalRegions
    except ImportError:
        print("  imucal: skipped (not installed)")
        return None
    regions = {}
    for label, name in IMUCAL_REGIONS:
        rows = step == label
        regions[f"acc_{name}"] = rec.acc[rows]
        regions[f"gyr_{name}"] = np.degrees(rec.gyro[rows])
    signals = FerrarisSignalRegions(**regions)
    wall, _, _ = median_wall_cpu(
        lambda: FerrarisCalibration(grav=gravity).compute(signals, RATE, "m/s^2", "deg/s"), repeats)
    return wall


if __name__ == "__main__":
    main()
