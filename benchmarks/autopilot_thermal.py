"""Thermal calibration from a flight controller's log: PX4's and ArduPilot's own scripts beside ours.

A simulated board of three IMUs with known thermal truths (``mocks.autopilot_sweep``: instance 0 a
cubic in T, 1 a cubic with strong dT terms, 2 a cubic with a mild dT term) is logged through a chamber
programme, -20 -> 60 -> -20 degC at 3 degC/min with 5 min soaks, 10 Hz, as a PX4 ULog and as an
ArduPilot DataFlash log of the same samples (``imu-station simulate --scenario chamber --log-format
...``). Five ways of compensating are fitted on it:

(a) PX4's ``process_sensor_caldata.py`` on the ULog: its ``TC_*`` through PX4's formula;
(b) ``imu-station thermal LOG --instance k`` then ``export -f px4 --instance k``: our ``TC_*`` through
    PX4's formula;
(c) ArduPilot's ``tempcal_IMU.py`` on the .bin: its ``INS_TCALn_*`` through ArduPilot's formula;
(d) ours exported with ``export -f ardupilot``: our ``INS_TCALn_*`` through ArduPilot's formula;
(e) our full model (dT terms, segments) through ``imu-station apply``.

The formulas are PX4's ``offset = X0 + X1 d + X2 d^2 + X3 d^3, d = clip(T, TMIN, TMAX) - TREF`` with
the block matched to the sensor by ``TC_An_ID == device_id``, and ArduPilot's ``raw - P(clamp(T) - 35)
+ P(clamp(T_cal) - 35)``, ``P(x) = (c1 x + c2 x^2 + c3 x^3) 1e-6`` (the README beside the scripts),
evaluated by the export modules' own functions (``station.export.autopilot.px4.px4_offsets``,
``ardupilot.ardupilot_offsets``), never by the scripts' code, which runs only as separate processes.

Each is scored on a separate validation sweep of the same IMUs: -15 -> 55 -> -15 degC at 1.5 degC/min
with 10 min soaks, noise-free (so the figures measure the models, not the noise). The residual bias
variation is the true thermal bias (``mocks.truth`` eq. (3) at the true T and dT) minus what the
method subtracts, per IMU and axis: its standard deviation and its peak-to-peak over the sweep
(constants do not count: the autopilots' offsets and the accel's gravity carry them), gyro in deg/h,
accel in mg. The table gives medians over the boards x 3 instances x 3 axes, then per instance.

The peers run with this interpreter when it has their dependencies (pyulog, pymavlink, scipy,
matplotlib), with ``MPLBACKEND=Agg`` and ArduPilot's ``--no-graph``; their wall times are printed
beside ours (thermal + both exports, all three instances, each command a fresh process as theirs
are) with the machine's load.

Five boards (seeds 1..5) by default: the medians are over boards, instances and axes, so that one
board's luck does not decide between methods whose models are the same cubic.

Run: ``.venv/bin/python benchmarks/autopilot_thermal.py [--peers DIR] [--seeds N] [--keep DIR]``
(about 3.5 minutes on 2 cores for 5 boards, 40 s a board, most of it ArduPilot's script).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mocks.autopilot_sweep import board_imus, board_sweep, log_sweep, write_board_log
from mocks.chamber import scenario_sweep
from protocols.units import STANDARD_GRAVITY
from station.export.autopilot.ardupilot import ardupilot_offsets
from station.export.autopilot.px4 import px4_offsets

ROOT = Path(__file__).resolve().parents[1]
PEERS = ROOT.parent / "shared" / "peers" / "autopilot-thermal"
PX4_SCRIPT, ARDUPILOT_SCRIPT = "process_sensor_caldata.py", "tempcal_IMU.py"
PEER_MODULES = {"px4": ("pyulog", "numpy", "scipy", "matplotlib"),
                "ardupilot": ("pymavlink", "numpy", "scipy", "matplotlib")}
VALIDATION = {"t_min": -15.0, "t_max": 55.0, "rate_c_per_min": 1.5, "soak_s": 600.0}
RATE_HZ = 10.0
DEG_H = 180.0 / np.pi * 3600.0  # rad/s -> deg/h
MG = 1e3 / STANDARD_GRAVITY  # m/s^2 -> mg
ARDUPILOT_DEFAULT_CALTEMP = -300.0  # INS_ACCn_CALTEMP's default: never calibrated
METHODS = {
    "none": "no compensation",
    "a": "(a) PX4 script, TC_* via PX4 formula",
    "b": "(b) ours as PX4 TC_*, PX4 formula",
    "c": "(c) ArduPilot script, INS_TCAL via AP formula",
    "d": "(d) ours as ArduPilot INS_TCAL, AP formula",
    "e": "(e) ours, full model via apply",
}


def missing_modules(kind: str) -> list[str]:
    """The peer ``kind``'s dependencies this interpreter cannot import."""
    return [m for m in PEER_MODULES[kind] if importlib.util.find_spec(m) is None]


def run(cmd: list[str], cwd: Path, env: dict[str, str] | None = None) -> float:
    """Run ``cmd`` to completion; its wall time in s. A failure stops the benchmark with its output."""
    start = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}):\n{done.stdout[-2000:]}\n"
                         f"{done.stderr[-2000:]}")
    return elapsed


def station(*args: str) -> list[str]:
    """An ``imu-station`` command line run by this interpreter."""
    return [sys.executable, "-m", "station", *args]


def read_qgc_params(path: Path) -> dict[str, float]:
    """A QGroundControl ``.params`` file (``vehicle<TAB>component<TAB>NAME<TAB>VALUE<TAB>TYPE``, ``#``)."""
    out = {}
    for line in path.read_text().splitlines():
        parts = line.split("\t")
        if line.startswith("#") or len(parts) < 4:
            continue
        out[parts[2]] = float(parts[3])
    return out


def read_ardupilot_params(path: Path) -> dict[str, float]:
    """An ArduPilot parameter file: ``NAME,VALUE`` or ``NAME VALUE`` lines, ``#`` comments."""
    out = {}
    for line in path.read_text().splitlines():
        parts = line.replace(",", " ").split()
        if line.startswith("#") or len(parts) < 2:
            continue
        out[parts[0]] = float(parts[1])
    return out


def px4_block(values: dict[str, float], letter: str, device: int) -> int | None:
    """The TC_{letter}n block PX4 applies to ``device`` (matched by id, as PX4 does), or None."""
    for n in range(4):
        if values.get(f"TC_{letter}{n}_ID") == device:
            return n
    return None


def px4_subtracted(values: dict[str, float], accel_id: int, gyro_id: int,
                   temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What PX4 subtracts from the raw accel and gyro with these TC_* parameters (enabled, as the user
    sets TC_A_ENABLE / TC_G_ENABLE); zero for a sensor no block names."""
    values = {**values, "TC_A_ENABLE": 1.0, "TC_G_ENABLE": 1.0}
    out = []
    for k, (letter, dev) in enumerate((("A", accel_id), ("G", gyro_id))):
        n = px4_block(values, letter, dev)
        out.append(np.zeros((len(temp), 3)) if n is None else px4_offsets(values, n, temp)[k])
    return out[0], out[1]


def ardupilot_subtracted(values: dict[str, float], instance: int,
                         temp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What ArduPilot subtracts with these INS_TCALn_* parameters (CALTEMP at its default where the
    file has none, as on a board whose offsets were never calibrated)."""
    n = instance + 1
    values = {f"INS_ACC{n}_CALTEMP": ARDUPILOT_DEFAULT_CALTEMP,
              f"INS_GYR{n}_CALTEMP": ARDUPILOT_DEFAULT_CALTEMP, **values}
    return ardupilot_offsets(values, instance, temp)


def residual_stats(truth: np.ndarray, subtracted: np.ndarray, unit: float) -> tuple[np.ndarray, np.ndarray]:
    """Per axis std and peak-to-peak of ``truth - subtracted`` (the bias left), in the unit's scale."""
    left = (truth - subtracted) * unit
    return left.std(axis=0), np.ptp(left, axis=0)


Stats = dict[str, dict[str, list[tuple[np.ndarray, np.ndarray]]]]  # method -> sensor -> per IMU (std, p2p)


def one_board(seed: int, work: Path, peers: Path, times: dict[str, list[float]],
              skipped: dict[str, str]) -> Stats:
    """One simulated board: its training logs, the peers' and our fits, scored on its validation sweep.
    Wall times are appended to ``times``; a peer that cannot run is named in ``skipped``."""
    work.mkdir(parents=True, exist_ok=True)
    train_ulg, train_bin = work / "train.ulg", work / "train.bin"
    simulate = ["simulate", "--scenario", "chamber", "--seed", str(seed), "--log-format"]
    times["simulate"].append(run(station(*simulate, "ulog", "-o", str(train_ulg)), work))
    run(station(*simulate, "dataflash", "-o", str(train_bin)), work)
    imus = board_imus(seed)

    peer_env = {**os.environ, "MPLBACKEND": "Agg"}
    for kind, script, cmd in (("px4", PX4_SCRIPT, [str(train_ulg)]),
                              ("ardupilot", ARDUPILOT_SCRIPT, ["--no-graph", "--outfile", "tcal.parm",
                                                               str(train_bin)])):
        missing = missing_modules(kind)
        if not (peers / script).exists():
            skipped[kind] = f"{peers / script} not found"
        elif missing:
            skipped[kind] = f"{sys.executable} lacks {', '.join(missing)}"
        else:
            times[kind].append(run([sys.executable, str(peers / script), *cmd], work, peer_env))

    ours_thermal = ours_export = 0.0
    for imu in imus:
        i = str(imu.instance)
        ours_thermal += run(station("thermal", str(train_ulg), "--instance", i, "-o", f"board{i}.yaml"), work)
        ids = ["--device-id", str(imu.accel_id), "--gyro-device-id", str(imu.gyro_id)]
        for fmt, out in (("px4", f"ours{i}.params"), ("ardupilot", f"ours{i}.param")):
            command = station("export", f"board{i}.yaml", "-f", fmt, "--instance", i, "-o", out, *ids)
            ours_export += run(command, work)
    times["ours thermal"].append(ours_thermal)
    times["ours export"].append(ours_export)

    # the validation sweep: the same IMUs (noise-free), another programme, another seed
    val_imus = board_imus(seed, noise=False)
    val_runs = board_sweep(val_imus, scenario_sweep(**VALIDATION), rate_hz=RATE_HZ, seed=seed + 100,
                           temp_noise_degc=0.0)
    val_ulg = work / "validation.ulg"
    write_board_log(val_ulg, "ulog", val_imus, val_runs, RATE_HZ, seed + 100)
    start = time.perf_counter()
    for imu in val_imus:
        i = str(imu.instance)
        run(station("apply", f"board{i}.yaml", str(val_ulg), "--instance", i, "-o", f"applied{i}.csv"), work)
    times["ours apply"].append(time.perf_counter() - start)

    from station.acquisition.autopilot_log import open_log
    from station.acquisition.capture import read_capture

    log = open_log(val_ulg)
    px4_peer = read_qgc_params(work / "train.ulg.params") if "px4" not in skipped else None
    ap_peer = read_ardupilot_params(work / "tcal.parm") if "ardupilot" not in skipped else None
    stats: Stats = {m: {"gyro": [], "accel": []} for m in METHODS}
    for imu, run_ in zip(imus, val_runs, strict=True):
        k = imu.instance
        raw = log.capture(k)
        temp = raw.temp if raw.temp is not None else run_.recording.temp
        applied = read_capture(work / f"applied{k}.csv")
        ours_px4 = read_qgc_params(work / f"ours{k}.params")
        ours_ap = read_ardupilot_params(work / f"ours{k}.param")
        zero = np.zeros((len(temp), 3))
        subtracted = {
            "none": (zero, zero),
            "a": px4_subtracted(px4_peer, imu.accel_id, imu.gyro_id, temp) if px4_peer else None,
            "b": px4_subtracted(ours_px4, imu.accel_id, imu.gyro_id, temp),
            "c": ardupilot_subtracted(ap_peer, k, temp) if ap_peer else None,
            "d": ardupilot_subtracted(ours_ap, k, temp),
            "e": (raw.acc - applied.acc, raw.gyro - applied.gyro),
        }
        for method, pair in subtracted.items():
            if pair is None:
                continue
            stats[method]["accel"].append(residual_stats(run_.thermal_accel, pair[0], MG))
            stats[method]["gyro"].append(residual_stats(run_.thermal_gyro, pair[1], DEG_H))
    return stats


def main(argv: list[str] | None = None) -> int:
    """Make the logs, run the peers and ours, score on the validation sweeps, print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peers", type=Path, default=PEERS, help=f"the peers' folder (default: {PEERS})")
    parser.add_argument("--seeds", type=int, default=5, help="boards simulated (seeds 1..N; default 5)")
    parser.add_argument("--keep", type=Path, help="work in this folder and keep its files")
    args = parser.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="autopilot-thermal-"))
    load = [os.getloadavg()[0]]
    times: dict[str, list[float]] = {k: [] for k in ("simulate", "px4", "ardupilot", "ours thermal",
                                                     "ours export", "ours apply")}
    skipped: dict[str, str] = {}
    boards = [one_board(seed, work / f"seed{seed}", args.peers, times, skipped)
              for seed in range(1, args.seeds + 1)]
    load.append(os.getloadavg()[0])
    kinds = [imu.kind for imu in board_imus(1)]
    n_train = int(log_sweep().duration_s * RATE_HZ)

    def values(method: str, sensor: str, which: int, instance: int | None = None) -> np.ndarray:
        """std (which 0) or p2p (1) of every board, instance (or the one given) and axis."""
        return np.array([b[method][sensor][k][which] for b in boards for k in range(len(kinds))
                         if instance is None or k == instance])

    ulg = work / "seed1" / "train.ulg"
    print(f"{args.seeds} boards (seeds 1..{args.seeds}), each {len(kinds)} IMUs x {n_train} samples at "
          f"{RATE_HZ:g} Hz ({ulg.stat().st_size / 1e6:.1f} MB ULog, "
          f"{(work / 'seed1' / 'train.bin').stat().st_size / 1e6:.1f} MB DataFlash); validation: "
          f"{VALIDATION['t_min']:g} -> {VALIDATION['t_max']:g} degC and back at "
          f"{VALIDATION['rate_c_per_min']:g} degC/min, {VALIDATION['soak_s']:g} s soaks, noise-free")
    print(f"residual bias variation on the validation sweeps, median over {args.seeds} boards x "
          f"{len(kinds)} instances x 3 axes:")
    print(f"  {'method':46s} {'gyro std':>10s} {'gyro p2p':>10s} {'accel std':>10s} {'accel p2p':>10s}")
    print(f"  {'':46s} {'deg/h':>10s} {'deg/h':>10s} {'mg':>10s} {'mg':>10s}")
    for method, label in METHODS.items():
        if not boards[0][method]["gyro"]:
            print(f"  {label:46s} skipped: {skipped.get('px4' if method == 'a' else 'ardupilot', '')}")
            continue
        cells = [np.median(values(method, sensor, which)) for sensor in ("gyro", "accel") for which in (0, 1)]
        print(f"  {label:46s}" + "".join(f" {c:10.3g}" for c in cells))
    print(f"per instance: std, gyro deg/h | accel mg, median over {args.seeds} boards x 3 axes:")
    print("  " + f"{'method':46s}" + "".join(f" {f'{k} {kind}':>20s}" for k, kind in enumerate(kinds)))
    for method, label in METHODS.items():
        if not boards[0][method]["gyro"]:
            continue
        cells = [f"{np.median(values(method, 'gyro', 0, k)):8.3g} | "
                 f"{np.median(values(method, 'accel', 0, k)):7.3g}" for k in range(len(kinds))]
        print(f"  {label:46s}" + "".join(f" {c:>20s}" for c in cells))
    for theirs, ours in (("a", "b"), ("c", "d")):
        if boards[0][theirs]["gyro"]:
            ratio = [np.median(values(ours, s, 0)) / np.median(values(theirs, s, 0))
                     for s in ("gyro", "accel")]
            print(f"{METHODS[ours]} / {METHODS[theirs]}: gyro std x{ratio[0]:.3f}, accel std x{ratio[1]:.3f}")
    for kind, reason in skipped.items():
        print(f"{kind} peer skipped: {reason}")

    def wall(key: str) -> str:
        return f"{np.median(times[key]):.1f} s" if times[key] else "not run"

    print(f"wall times, median over boards: PX4 script {wall('px4')}, ArduPilot script {wall('ardupilot')}; "
          f"ours {wall('ours thermal')} thermal (3 instances, 3 processes) + {wall('ours export')} export "
          f"(6 files) + {wall('ours apply')} apply on the validation sweep; simulate {wall('simulate')} "
          "a log")
    print(f"load average {load[0]:.2f} at the start, {load[1]:.2f} at the end, on {os.cpu_count()} cores; "
          f"python {sys.version.split()[0]} ({sys.executable})")
    print(f"files in {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
