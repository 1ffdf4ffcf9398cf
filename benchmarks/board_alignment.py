"""Several IMUs on one board: how well ``imu-station calibrate`` recovers each IMU's rotation relative to
the first, against the injected truth and against its own 1-sigma.

Boards of three MEMS IMUs (``UnitTruth.random``, each its own seed) mounted at 0.3/-0.2/0.5, 1.5/-2/3 and
-2.5/1/-4 deg about x/y/z (``mocks.board``), moved together:

- turntable: the twelve-position sequence with the six rotations, 5 s a pose, 200 Hz, one capture CSV
  per IMU (``NAME.csv``, ``NAME.imu<k>.csv`` with their instance lines), ``calibrate ... --method
  turntable``;
- hand-held: 24 random attitudes held 4 s after 15 s still, the second IMU at 250 Hz and the others at
  200 Hz, one PX4 ULog, ``calibrate LOG`` without ``--instance``.

The truth is the rotation between the IMUs' own axes (their accelerometers' lower-triangular frames,
``mocks.board.true_relative_rotation``). Printed: the median and worst error (deg) over boards x 2
rotations, the median 1-sigma (deg), and the error over the 1-sigma per axis (its standard deviation
near 1 when the 1-sigma is right; the largest |z|).

    python benchmarks/board_alignment.py --boards 12
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np

from mocks.board import mounted, rotation_xyz, simulate_board, true_relative_rotation, write_board_ulog
from mocks.rig import handheld_session, sequence_segments
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.engines.calibration.imu_alignment import rotation_vector
from station.export.params.file import ParamsFile
from station.export.params.imus import board_entries

MOUNTS_DEG = ([0.3, -0.2, 0.5], [1.5, -2.0, 3.0], [-2.5, 1.0, -4.0])
DEVICE_IDS = (2490378, 2228234, 3473418)


def _board(seed: int) -> list[UnitTruth]:
    return [mounted(UnitTruth.random(seed * 10 + k), rotation_xyz(m)) for k, m in enumerate(MOUNTS_DEG)]


def _calibrate(mode: str, seed: int, folder: Path, truths: list[UnitTruth]) -> Path:
    params = folder / "board.yaml"
    if mode == "turntable":
        recordings = simulate_board(truths, sequence_segments("twelve-position", rotations=True, hold_s=5.0),
                                    seed=seed)
        paths = []
        for k, rec in enumerate(recordings):
            capture = rec.to_capture()
            capture.device = {"serial": "SIM-BOARD", "rate_hz": rec.rate_hz, "instance": k}
            path = folder / ("board.csv" if k == 0 else f"board.imu{k}.csv")
            write_csv(path, capture)
            if "# instance:" not in path.read_text()[:400]:
                path.write_text(f"# instance: {k}\n" + path.read_text())
            paths.append(str(path))
        args = ["calibrate", *paths, "--method", "turntable", "-o", str(params)]
    else:
        segments = handheld_session(n_poses=24, seed=seed, hold_s=4.0, initial_still_s=15.0)
        recordings = simulate_board(truths, segments, rates_hz=[200.0, 250.0, 200.0], seed=seed)
        log = write_board_ulog(folder / "board.ulg", recordings, DEVICE_IDS)
        args = ["calibrate", str(log), "-o", str(params)]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = cli.main(args)
    if code != 0:
        raise SystemExit(f"{mode} board {seed}: calibrate exited {code}")
    return params


def measure(mode: str, boards: int) -> dict[str, float]:
    """Errors and z-scores over ``boards`` simulated boards of ``mode`` (turntable or handheld)."""
    errors, sigmas, z = [], [], []
    for seed in range(boards):
        truths = _board(seed)
        with tempfile.TemporaryDirectory() as tmp:
            params = _calibrate(mode, seed, Path(tmp), truths)
            for entry in board_entries(ParamsFile.load(params))[1:]:
                assert entry.rotation_sigma is not None
                truth = true_relative_rotation(truths[0], truths[entry.instance])
                error = rotation_vector(entry.rotation_to_first @ truth)
                errors.append(np.degrees(np.linalg.norm(error)))
                sigmas.append(np.degrees(entry.rotation_sigma))
                z.append(error / entry.rotation_sigma)
    zs = np.array(z).ravel()
    return {"rotations": len(errors), "median_deg": float(np.median(errors)),
            "worst_deg": float(np.max(errors)), "sigma_deg": float(np.median(sigmas)),
            "z_std": float(zs.std()), "z_max": float(np.abs(zs).max())}


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--boards", type=int, default=12)
    args = parser.parse_args()
    print("method     rotations  median error  worst error  median 1-sigma  std(err/sigma)  max |err/sigma|")
    for mode in ("turntable", "handheld"):
        m = measure(mode, args.boards)
        print(f"{mode:<10} {m['rotations']:>9}  {m['median_deg']:>10.4f} deg {m['worst_deg']:>8.4f} deg "
              f"{m['sigma_deg']:>11.4f} deg {m['z_std']:>15.2f} {m['z_max']:>16.2f}")


if __name__ == "__main__":
    main()
