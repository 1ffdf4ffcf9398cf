"""What the model selection costs, and whether it still chooses the same models (issue 30).

In one run:

1. ``imu-station allan`` on the first ADIS16405 still recording (10,000 s at 100 Hz, 1 M samples, six
   axes; ../shared/data/adis16405-smac, converted once to a capture CSV in a temporary folder, never
   copied into the project): the whole process's wall and CPU time (the child's user + system time),
   median of ``--repeats`` runs, against the target of 3 s wall;
2. the command's pipeline in this process on both ADIS16405 records (integrate, curve, identify_noise):
   the CPU of the model choice (``choose_model``) per axis, against the target of 1 s an axis;
3. the models chosen there and on simulated units (an exact curve, filtered white noise, white noise with
   a Gauss-Markov bias, and filtered white noise with a random walk, a Gauss-Markov process and a
   sinusoid; each axis's selection forced with ``select_model`` as well as ``identify_noise``'s choice),
   compared with the reference of ``benchmarks/allan_model_reference.json``: the same terms, and every
   parameter within its reference 1-sigma (within 1e-6 relative where it has none).

    .venv/bin/python benchmarks/allan_model.py [--repeats 3] [--cold] [--write-reference FILE]

``--write-reference`` writes the models of this run (and the commit they came from) instead of comparing.
The machine's load (``os.getloadavg``) is printed with the times.
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the command runs (station/cli.py)

import numpy as np  # noqa: E402
from scipy.signal import lfilter  # noqa: E402

from mocks.truth import FLICKER_FLOOR, GM_ADEV_PEAK, NoiseGenerator, NoiseSpec  # noqa: E402
from station.acquisition.capture_csv import write_csv  # noqa: E402
from station.acquisition.capture_data import Capture  # noqa: E402
from station.engines.allan import model as allan_model  # noqa: E402
from station.engines.allan.deviation import allan_curve, confidence_interval, integrate_rates  # noqa: E402
from station.engines.allan.estimates import Estimate, GaussMarkov, NoiseModel  # noqa: E402
from station.engines.allan.fit import identify_noise  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "adis16405-smac"
RECORDS = ("adis_16405_imu2.csv.gz", "adis_16405_imu3.csv.gz")
AXES = ("gx", "gy", "gz", "ax", "ay", "az")
RATE = 100.0
G = 9.80665
REFERENCE = Path(__file__).with_name("allan_model_reference.json")
TARGET_WALL_S = 3.0
TARGET_CPU_AXIS_S = 1.0
NO_SD_REL = 1e-6


def read_record(path: Path) -> np.ndarray:
    """gyro deg/s and accel g columns to rad/s and m/s^2 (gx gy gz ax ay az)."""
    with gzip.open(path, "rt") as f:
        v = np.loadtxt(f, delimiter=",", skiprows=1)
    return np.column_stack([np.radians(v[:, :3]), v[:, 3:] * G])


def as_capture_csv(rates: np.ndarray, path: Path) -> None:
    """The record as the station's capture CSV (t at 100 Hz; acc m/s^2, gyro rad/s)."""
    t = np.arange(len(rates)) / RATE
    write_csv(path, Capture(t=t, acc=rates[:, 3:], gyro=rates[:, :3]))


def time_command(csv: Path, repeats: int, env: dict[str, str] | None = None
                 ) -> tuple[list[float], list[float]]:
    """Wall and CPU (user + system of the child) of ``imu-station allan CSV --json``, per run."""
    exe = Path(sys.executable).with_name("imu-station")
    walls, cpus = [], []
    for _ in range(repeats):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        done = subprocess.run([str(exe), "allan", str(csv), "--json"], capture_output=True, text=True,
                              env=env)
        walls.append(time.perf_counter() - start)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        if done.returncode != 0:
            raise SystemExit(f"imu-station allan failed ({done.returncode}): {done.stderr[-2000:]}")
    return walls, cpus


def _est(e: Estimate | None) -> list[float | None] | None:
    return None if e is None else [float(e.value), None if e.stddev is None else float(e.stddev)]


def model_dict(m: NoiseModel) -> dict[str, Any]:
    """A model's terms, every parameter with its 1-sigma, and how it was judged."""
    return {"describe": m.describe(), "method": m.method, "terms": {k: _est(v) for k, v in m.terms.items()},
            "filter_s": _est(m.filter_s),
            "gauss_markov": [[_est(g.sigma), _est(g.tau_c)] for g in m.gauss_markov],
            "sinusoids": [[_est(s.amplitude), _est(s.freq_hz)] for s in m.sinusoids],
            "valid_tau": list(m.valid_tau), "outside": m.outside, "points": m.points, "chi2": m.chi2,
            "parameters": m.parameters, "combinations": m.combinations}


def _timed_choose(per_axis: list[float]) -> Callable[..., None]:
    inner = allan_model.choose_model

    def wrapper(*args: Any, **kwargs: Any) -> None:
        start = time.process_time()
        try:
            inner(*args, **kwargs)
        finally:
            per_axis.append(time.process_time() - start)

    return wrapper


def chosen(curve: Any, phase: np.ndarray, per_axis: list[float]) -> list[NoiseModel]:
    """identify_noise's model per axis, the CPU of each axis's choose_model appended to ``per_axis``."""
    inner = allan_model.choose_model
    allan_model.choose_model = _timed_choose(per_axis)  # type: ignore[assignment]
    try:
        _, noise = identify_noise(curve, phase)
    finally:
        allan_model.choose_model = inner  # type: ignore[assignment]
    return [a.noise_model for a in noise if a.noise_model is not None]


def adis_models(per_axis: list[float], records: dict[str, np.ndarray]) -> dict[str, Any]:
    """Both records through the command's pipeline."""
    out = {}
    for name, rates in records.items():
        phase = integrate_rates(rates, RATE)
        models = chosen(allan_curve(phase, RATE, AXES), phase, per_axis)
        for axis, m in zip(AXES, models, strict=True):
            out[f"{name[11:15]} {axis}"] = model_dict(m)
    return out


def _forced(curve: Any, key: str, out: dict[str, Any], per_axis: list[float]) -> None:
    """select_model on every axis of ``curve`` (the selection forced, whatever the IEEE fit)."""
    for j, axis in enumerate(curve.axes):
        start = time.process_time()
        m = allan_model.select_model(curve.tau, curve.adev[:, j], curve.edf[:, j], curve.ci_low[:, j],
                                     curve.ci_high[:, j], curve.rate_hz)
        per_axis.append(time.process_time() - start)
        out[f"{key} {axis} select"] = model_dict(m)


def simulated_models(per_axis: list[float]) -> dict[str, Any]:
    """Simulated units (seeded): the selection's models on each."""
    out: dict[str, Any] = {}
    # an exact curve of N through a filter, K, two processes (tests/test_allan_model.py)
    tau = np.concatenate([np.arange(1, 10) / 100.0, np.geomspace(0.1, 1e5, 61)])
    truth = NoiseModel(terms={"N": Estimate(7e-4, None), "K": Estimate(5e-6, None)},
                       gauss_markov=[GaussMarkov(Estimate(2e-4, None), Estimate(3.0, None)),
                                     GaussMarkov(Estimate(3e-4, None), Estimate(200.0, None))],
                       filter_s=Estimate(0.03, None), dt_s=0.01)
    adev = np.sqrt(truth.avar(tau))
    edf = np.maximum(1e6 / tau, 50.0)
    lo, hi = confidence_interval(adev, edf)
    out["exact select"] = model_dict(allan_model.select_model(tau, adev, edf, lo, hi, 100.0))
    # white noise through a digital filter, 1 h at 100 Hz
    rng = np.random.default_rng(3)
    y = lfilter([0.5], [1.0, -0.5], rng.standard_normal(360_000) * 1e-3 * 10.0)
    phase = integrate_rates(y, 100.0)
    _forced(allan_curve(phase, 100.0, ("gx",)), "filtered", out, per_axis)
    # white noise and a Gauss-Markov bias (sigma 5e-4, 300 s), 10 h at 10 Hz
    spec = NoiseSpec(N=[7e-4] * 3, B=[5e-4 * GM_ADEV_PEAK / FLICKER_FLOOR] * 3, b_corr_time_s=300.0)
    y = NoiseGenerator(spec, 10.0, np.random.SeedSequence(1)).next(360_000)
    phase = integrate_rates(y, 10.0)
    curve = allan_curve(phase, 10.0, ("gx", "gy", "gz"))
    refined, noise = identify_noise(curve, phase)
    for a in noise:
        assert a.noise_model is not None
        out[f"gm {a.axis}"] = model_dict(a.noise_model)
    _forced(refined, "gm", out, per_axis)
    # filtered white noise + a random walk + a process of 30 s + a 7 Hz sinusoid, 2 h at 100 Hz
    n = 720_000
    rng = np.random.default_rng(11)
    cols = []
    for k in range(3):
        white = lfilter([0.4], [1.0, -0.6], rng.standard_normal(n) * 1e-3 * 10.0)
        a = math.exp(-0.01 / 30.0)
        gm = lfilter([math.sqrt(1 - a * a) * 3e-4], [1.0, -a], rng.standard_normal(n))
        walk = np.cumsum(rng.standard_normal(n)) * 2e-5 * math.sqrt(0.01)
        sine = (1.0 + k) * 1e-3 * np.sin(2 * math.pi * 7.0 * np.arange(n) / 100.0 + k)
        cols.append(white + gm + walk + sine)
    phase = integrate_rates(np.column_stack(cols), 100.0)
    curve = allan_curve(phase, 100.0, ("gx", "gy", "gz"))
    refined, noise = identify_noise(curve, phase)
    for a in noise:
        assert a.noise_model is not None
        out[f"rich {a.axis}"] = model_dict(a.noise_model)
    _forced(refined, "rich", out, per_axis)
    return out


def _params(m: dict[str, Any]) -> list[tuple[str, list[float | None] | None]]:
    ps: list[tuple[str, list[float | None] | None]] = [(k, v) for k, v in m["terms"].items()]
    ps.append(("T_f", m["filter_s"]))
    for i, g in enumerate(m["gauss_markov"]):
        ps += [(f"GM{i + 1} sigma", g[0]), (f"GM{i + 1} tau_c", g[1])]
    for i, s in enumerate(m["sinusoids"]):
        ps += [(f"S{i + 1} A", s[0]), (f"S{i + 1} f", s[1])]
    return ps


def compare(ref: dict[str, Any], new: dict[str, Any]) -> tuple[int, list[str]]:
    """How many models match (same terms, every parameter within its reference 1-sigma) and what differs;
    also the largest difference in units of 1-sigma and relative."""
    matched, notes, worst_sd, worst_rel = 0, [], 0.0, 0.0
    for key, r in ref.items():
        m = new.get(key)
        if m is None:
            notes.append(f"{key}: missing")
            continue
        # the label marks a term fitted but not reported since the reference was written: the same model
        same_terms = m["describe"].replace(" (modelled, not resolved)", "") == r["describe"]
        if not same_terms or m["outside"] != r["outside"] or m["points"] != r["points"]:
            notes.append(f"{key}: {m['describe']} ({m['outside']}/{m['points']} outside), reference "
                         f"{r['describe']} ({r['outside']}/{r['points']})")
            continue
        ok = m["valid_tau"] == r["valid_tau"] and m["combinations"] == r["combinations"]
        if not ok:
            notes.append(f"{key}: valid_tau {m['valid_tau']} or combinations {m['combinations']} differ")
        for (name, e_ref), (_, e_new) in zip(_params(r), _params(m), strict=True):
            if e_ref is None or e_new is None:
                if (e_ref is None) != (e_new is None):
                    ok = False
                    notes.append(f"{key} {name}: present in one only")
                continue
            v_ref, sd_ref = e_ref
            v_new = e_new[0]
            assert v_ref is not None and v_new is not None
            diff = abs(v_new - v_ref)
            rel = diff / abs(v_ref) if v_ref else diff
            worst_rel = max(worst_rel, rel)
            if sd_ref:
                worst_sd = max(worst_sd, diff / sd_ref)
            within = diff <= sd_ref if sd_ref else rel <= NO_SD_REL
            if not within:
                ok = False
                notes.append(f"{key} {name}: {v_new:.6g} against {v_ref:.6g} +- {sd_ref}")
        matched += ok
    notes.append(f"largest difference: {worst_sd:.2g} of the reference 1-sigma, {worst_rel:.2g} relative")
    return matched, notes


def main() -> None:
    """Time, choose, compare."""
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="runs of the whole command (median)")
    parser.add_argument("--write-reference", type=Path, metavar="FILE")
    parser.add_argument("--cold", action="store_true",
                        help="also one run with an empty numba cache (as the first run after installing)")
    args = parser.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} is not there: the ADIS16405 records are needed")
    records = {name: read_record(DATA / name) for name in RECORDS}
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "adis_16405_imu2.csv"
        as_capture_csv(records[RECORDS[0]], csv)
        if args.cold:
            with tempfile.TemporaryDirectory() as cache:
                cold_wall, cold_cpu = time_command(csv, 1, {**os.environ, "NUMBA_CACHE_DIR": cache})
            print(f"imu-station allan with an empty numba cache (compiling the Allan kernel and the model "
                  f"selection's solve): {cold_wall[0]:.2f} s wall, {cold_cpu[0]:.2f} s CPU "
                  f"(load {os.getloadavg()[0]:.2f})")
        load_before = os.getloadavg()
        walls, cpus = time_command(csv, args.repeats)
    print(f"imu-station allan, {RECORDS[0]} (1,000,000 samples, six axes), whole process, median of "
          f"{args.repeats}: {statistics.median(walls):.2f} s wall, {statistics.median(cpus):.2f} s CPU "
          f"(walls {', '.join(f'{w:.2f}' for w in walls)}; load {load_before[0]:.2f} before, "
          f"{os.getloadavg()[0]:.2f} after)")
    print(f"  against the target of {TARGET_WALL_S:g} s wall: {statistics.median(walls) / TARGET_WALL_S:.2f}")
    adis_axis: list[float] = []
    models = adis_models(adis_axis, records)
    med = statistics.median(adis_axis)
    print(f"model choice (choose_model), CPU per axis over both records' 12 axes: median {med:.3f} s, "
          f"largest {max(adis_axis):.3f} s, total {sum(adis_axis):.2f} s (load {os.getloadavg()[0]:.2f})")
    print(f"  against the target of {TARGET_CPU_AXIS_S:g} s an axis: largest "
          f"{max(adis_axis) / TARGET_CPU_AXIS_S:.2f}, median {med / TARGET_CPU_AXIS_S:.2f}")
    sim_axis: list[float] = []
    models.update(simulated_models(sim_axis))
    print(f"select_model on the simulated units' {len(sim_axis)} axes: CPU median "
          f"{statistics.median(sim_axis):.3f} s, largest {max(sim_axis):.3f} s")
    if args.write_reference:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
        doc = {"commit": commit.strip(),
               "note": "models chosen by benchmarks/allan_model.py at this commit (before issue 30's change)",
               "models": models}
        args.write_reference.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {len(models)} models to {args.write_reference}")
        return
    ref = json.loads(REFERENCE.read_text())
    matched, notes = compare(ref["models"], models)
    print(f"models against the reference (commit {ref['commit'][:12]}): {matched} of {len(ref['models'])} "
          f"the same terms with every parameter within its 1-sigma")
    for note in notes:
        print(f"  {note}")


if __name__ == "__main__":
    main()
