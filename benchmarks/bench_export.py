"""Speed of the exported C ``imu_calib_apply`` against the station's own ``apply_calibration``.

The peer is ``station.engines.shared.correction.apply_calibration`` (numpy, float64, vectorised over the
whole batch), which ``imu-station apply`` runs. The exported C is compiled with ``gcc -O2`` and
driven one sample at a time, as firmware calls it. Both correct the same samples with a
three-segment thermal model holding every term. Medians of repeats; the machine is shared.

    .venv/bin/python benchmarks/bench_export.py [--samples N] [--repeats R]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from station.engines.shared.correction import apply_calibration
from station.engines.shared.sensor_model import SensorCalibration
from station.engines.thermal.model import DtempFilter, ThermalBias, ThermalModel, ThermalSegment
from station.export.firmware.blob import parse_blob
from station.export.firmware.c_source import write_c_export
from station.export.params.file import ParamsFile

DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "imu_calib.h"

int main(int argc, char **argv)
{
    size_t n = (size_t)atol(argv[1]), i;
    int r, repeats = atoi(argv[2]);
    float *in = (float *)malloc(n * 8 * sizeof(float)), out[6], sink = 0.0f;
    FILE *f = fopen(argv[3], "rb");
    if (in == NULL || f == NULL || fread(in, sizeof(float), n * 8, f) != n * 8) return 2;
    fclose(f);
    for (r = 0; r < repeats; ++r) {
        struct timespec a, b;
        clock_gettime(CLOCK_MONOTONIC, &a);
        for (i = 0; i < n; ++i) {
            const float *row = in + 8 * i;
            imu_calib_apply(&imu_calib_unit, row[0], row[1], row + 2, row + 5, out, out + 3);
            sink += out[0] + out[4];
        }
        clock_gettime(CLOCK_MONOTONIC, &b);
        printf("%.9f\n", (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec));
    }
    fprintf(stderr, "checksum %g\n", (double)sink);
    return 0;
}
"""


def unit_params() -> ParamsFile:
    rng = np.random.default_rng(0)
    params = ParamsFile(device={"serial": "BENCH-1"})
    off_diagonal = 1 - np.eye(3)
    acc_s, gyr_s = rng.normal(0, 2e-3, (3, 3)) * off_diagonal, rng.normal(0, 3e-3, (3, 3)) * off_diagonal
    params.accel = SensorCalibration.from_parts(1 + rng.normal(0, 0.01, 3), acc_s, rng.normal(0, 0.1, 3))
    params.gyro = SensorCalibration.from_parts(1 + rng.normal(0, 0.005, 3), gyr_s, rng.normal(0, 0.01, 3))
    scale = np.array([3e-7, 2e-5, 1e-3, 1e-3, 5e-3, 1e-4, 1e-2])

    def triad() -> ThermalBias:
        edges = [-10.0, 15.0, 40.0, 60.0]
        return ThermalBias([ThermalSegment(lo, hi, rng.normal(0, 1, (3, 7)) * scale)
                            for lo, hi in zip(edges[:-1], edges[1:], strict=True)], -0.5, 0.5)

    params.thermal = ThermalModel(25.0, DtempFilter("ema", 10.0), triad(), triad())
    return params


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    params = unit_params()
    rng = np.random.default_rng(1)
    n = args.samples
    rows = np.empty((n, 8), dtype=np.float32)
    rows[:, 0] = rng.uniform(-20, 70, n)
    rows[:, 1] = rng.uniform(-1, 1, n)
    rows[:, 2:] = rng.normal(0, 5, (n, 6))
    r64 = rows.astype(np.float64)

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        t0 = time.perf_counter()
        write_c_export(params, work, "bench", 0)
        export_s = time.perf_counter() - t0
        parse_blob((work / "imu_calib.bin").read_bytes())
        (work / "driver.c").write_text(DRIVER)
        rows.tofile(work / "in.f32")
        subprocess.run(["gcc", "-std=c99", "-O2", "-D_POSIX_C_SOURCE=199309L", "-I.", "imu_calib.c",
                        "driver.c", "-lm", "-o", "driver"], cwd=work, check=True)
        out = subprocess.run(["./driver", str(n), str(args.repeats), "in.f32"], cwd=work, check=True,
                             capture_output=True, text=True).stdout
        c_times = [float(x) for x in out.split()]

    np_times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        apply_calibration(r64[:, 2:5], r64[:, 5:8], r64[:, 0], r64[:, 1], params.accel, params.gyro,
                          params.thermal)
        np_times.append(time.perf_counter() - t0)

    c_med, np_med = statistics.median(c_times), statistics.median(np_times)
    print(f"samples: {n}, repeats: {args.repeats} (medians), 3-segment thermal model, all 7 terms")
    print(f"export (render h/c/bin): {export_s * 1e3:.1f} ms")
    print(f"C imu_calib_apply, gcc -O2, one sample per call: {c_med / n * 1e9:7.1f} ns/sample "
          f"({n / c_med / 1e6:.2f} M samples/s)")
    print(f"numpy apply_calibration, float64 batch (peer):   {np_med / n * 1e9:7.1f} ns/sample "
          f"({n / np_med / 1e6:.2f} M samples/s)")
    print(f"ratio numpy / C: {np_med / c_med:.2f}x")


if __name__ == "__main__":
    main()
