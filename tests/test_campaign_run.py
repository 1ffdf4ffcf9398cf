"""A simulated chamber campaign end to end through the CLI (real ptys and sockets), and the same
campaign killed with SIGKILL at many points and resumed each time: one record, no step twice, every
capture taken before a kill kept byte for byte, results as an uninterrupted run's."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocks.truth import UnitTruth
from station.export.params.file import ParamsFile
from station.factory.campaign import campaign_steps
from station.factory.plan import load_plan
from station.factory.records import RecordStore

PLAN = """schema: imu-station/plan/1
name: test-campaign
sequence: {name: six-position, rotations: true, hold_s: 0.5, rotation_rate_dps: 180, settle_s: 0.3}
device: {rate_hz: 100}
engine: {method: turntable, gravity: 9.80665}
run: {timeout_s: 400, step_timeout_s: 30, max_attempts: 2}
export: [json]
instruments:
  chamber: {url: "votsch://192.0.2.1", min_c: -40, max_c: 85, max_gradient: 5}
  table: {url: "acutrol://192.0.2.2:5000?axes=3", max_rate_dps: 400, max_accel_dps2: 400, mount: +z}
  supply: {url: "scpi://192.0.2.3", max_v: 12, max_a: 1, volts: 5, amps: 0.5}
campaign:
  soaks_c: [18, 28, 38]
  ramp_c_per_min: 5
  end_c: 28
  settle: {rate_c_per_min: 0.5, hold_s: 40, timeout_s: 7200}
  soak: {sequence: true, power_cycles: 3, turn_on_s: 1, off_s: 0.5, still_s: 1}
  ramp: {record: true, rate_hz: 10}
  simulate: {speed: 20, wait_speed: 300}
"""
WAIT_S = 120.0  # wall seconds any one condition may take on a loaded machine


def _env() -> dict[str, str]:
    env = {**os.environ, "IMU_STATION_ID": "test-station", "COLUMNS": "160"}
    env.pop("IMU_STATION_DB", None)
    return env


class Station:
    """One ``imu-station run`` process, its stderr read line by line in a thread."""

    def __init__(self, argv: list[str], cwd: Path):
        self.proc = subprocess.Popen([sys.executable, "-m", "station.cli", *argv], cwd=cwd, env=_env(),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line)

    def said(self, words: str) -> bool:
        return any(words in line for line in list(self.lines))

    def wait_for(self, condition: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + WAIT_S
        while not condition():
            assert self.proc.poll() is None, f"the station ended before {what}: {''.join(self.lines)[-3000:]}"
            assert time.monotonic() < deadline, f"no {what} in {WAIT_S:g} s: {''.join(self.lines)[-3000:]}"
            time.sleep(0.02)  # polling the condition (files, journal, log), not waiting blind

    def kill(self) -> None:
        assert self.proc.poll() is None, "the station ended before it was killed"
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(30)
        self._reader.join(10)

    def finish(self) -> tuple[int, str]:
        out, _ = self.proc.communicate(timeout=WAIT_S * 2)
        self._reader.join(10)
        return self.proc.returncode, out


def _run_dir(root: Path) -> Path | None:
    found = list((root / "files").glob("SIM-*/*/journal.jsonl"))
    return found[0].parent if found else None


def _journal(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "journal.jsonl").read_bytes().splitlines()
            if line.endswith(b"}")]


def _steps(folder: Path | None) -> list[str]:
    if folder is None or not (folder / "journal.jsonl").exists():
        return []
    return [e["step"] for e in _journal(folder) if e["type"] == "step"]


def _size(folder: Path | None, name: str) -> int:
    path = folder / name if folder is not None else None
    return path.stat().st_size if path is not None and path.exists() else 0


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _start(root: Path) -> Station:
    return Station(["run", "--plan", "plan.yaml", "--simulate", "--serial", "auto", "--files", "files",
                    "--db", "records.sqlite"], root)


def _resume(root: Path, folder: Path) -> Station:
    return Station(["run", "--resume", str(folder), "--simulate", "--files", "files", "--db",
                    "records.sqlite"], root)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The campaign run whole, once."""
    root = tmp_path_factory.mktemp("whole")
    (root / "plan.yaml").write_text(PLAN)
    code, out = _start(root).finish()
    assert code == 0, out
    folder = _run_dir(root)
    assert folder is not None
    return folder


def test_campaign_runs_whole(uninterrupted: Path) -> None:
    folder = uninterrupted
    plan = load_plan(folder.parents[2] / "plan.yaml")
    assert plan.campaign is not None
    ids = [s.id for s in campaign_steps(plan.campaign)]
    assert _steps(folder) == ids
    record = json.loads((folder / "record.json").read_text())
    assert record["outcome"] == "PASS"
    assert [p["name"] for p in record["phases"]] == ["instruments", "connect", *ids, "calibrate", "export"]
    for step in ids:  # every step's capture attached with its SHA-256, as the journal has it
        assert (folder / f"{step}.csv").is_file()
    journal = {f["path"]: f["sha256"] for e in _journal(folder) for f in e.get("files", [])}
    attached = {a["path"]: a["sha256"] for p in record["phases"] for a in p["attachments"]}
    assert {k: attached[k] for k in journal} == journal and len(journal) == len(ids)
    params = yaml.safe_load((folder / "params.yaml").read_text())
    assert {"accel", "gyro", "thermal", "characterisation"} <= set(params)
    block = params["characterisation"]["across_temperature"]
    assert [t["soak_c"] for t in block["turn_on"]] == [18.0, 28.0, 38.0]
    assert params["characterisation"]["turn_ons"] == 3
    # the settled unit at each soak within the chamber's band of its setpoint (the plant's air settles at it)
    np.testing.assert_allclose(block["unit_c"], [18, 28, 38], atol=1.5)
    hysteresis = block["hysteresis"]
    assert hysteresis["bins"] >= 5 and hysteresis["t_min"] < 20 and hysteresis["t_max"] > 36
    with RecordStore.open(folder.parents[2] / "records.sqlite") as store:
        (stored,) = store.query()
    assert stored.run_id == record["run_id"] and stored.verify() == []


def test_campaign_recovers_the_scale_factor_across_temperature(uninterrupted: Path) -> None:
    """Against the simulated unit's truth (seed 0, intrinsics moving with T): each soak's scale factor,
    the slope through the soaks (numpy.polyfit on both sides) and the fit's value at T_ref."""
    truth = UnitTruth.random(0, "mems", thermal_intrinsics=True)
    record = json.loads((uninterrupted / "record.json").read_text())
    values = {m["name"]: m["value"] for p in record["phases"] for m in p["measurements"]}
    params = yaml.safe_load((uninterrupted / "params.yaml").read_text())
    temps = np.array([values[f"soak-{i}.temperature_c"] for i in (1, 2, 3)])
    for triad in ("accel", "gyro"):
        sensor = getattr(truth, triad)
        assert np.ptp(sensor.scale_at(temps) - 1, axis=0).max() > 1e-3  # the truth moves: a real check
        measured = np.array([[values[f"soak-{i}.{triad}.scale_error.{a}"] for a in "xyz"] for i in (1, 2, 3)])
        np.testing.assert_allclose(measured, sensor.scale_at(temps) - 1, atol=3e-4)
        slope, true_slope = np.polyfit(temps, measured, 1)[0], np.polyfit(temps, sensor.scale_at(temps), 1)[0]
        np.testing.assert_allclose(slope, true_slope, rtol=0.15, atol=1e-5)  # 1/degC
        t_ref = params[triad]["reference_temp"]
        np.testing.assert_allclose(params[triad]["scale"], sensor.scale_at(np.array([t_ref]))[0], atol=3e-4)


def test_killed_at_many_points_resumes_to_one_record(uninterrupted: Path, tmp_path: Path) -> None:
    (tmp_path / "plan.yaml").write_text(PLAN)
    folder: list[Path] = []

    def run_dir() -> Path | None:
        if not folder:
            found = _run_dir(tmp_path)
            if found is not None:
                folder.append(found)
        return folder[0] if folder else None

    def has(step: str) -> Callable[[], bool]:
        return lambda: step in _steps(run_dir())

    def growing(name: str, size: int) -> Callable[[], bool]:
        return lambda: _size(run_dir(), name) > size

    # (what, when to kill); each kill is followed by a resume that the next point kills in turn
    points: list[tuple[str, Callable[[], bool]]] = [
        ("mid ramp-1 capture", growing("ramp-1.csv", 2000)),
        ("mid soak-1 sequence capture", growing("soak-1.sequence.csv", 20000)),
        ("during soak-1 turn-on-2", has("soak-1.turn-on-1")),
        ("during the restore of a resume", lambda: False),  # killed on the resumed station's log line
        ("after soak-1 still", has("soak-1.still")),
        ("mid ramp-2 capture (and a torn journal line)", growing("ramp-2.csv", 2000)),
        ("mid soak-2 sequence capture", growing("soak-2.sequence.csv", 20000)),
        ("between soak-2 turn-ons", has("soak-2.turn-on-2")),
        ("during ramp-end", has("soak-3.still")),
        ("during the calibration", lambda: False),  # killed on the station's 'phase calibrate' line
    ]
    kept: dict[str, str] = {}
    station = _start(tmp_path)
    for what, condition in points:
        if what.startswith("during the restore"):
            station.wait_for(lambda s=station: s.said("resume: the chamber back"), what)  # type: ignore[misc]
        elif what.startswith("during the calibration"):
            station.wait_for(lambda s=station: s.said("phase calibrate"), what)  # type: ignore[misc]
        else:
            station.wait_for(condition, what)
        before = set(_steps(run_dir()))
        station.kill()
        here = run_dir()
        assert here is not None
        for entry in _journal(here):
            for f in entry.get("files", []):
                kept.setdefault(f["path"], f["sha256"])
        assert set(_steps(here)) >= before
        if "torn" in what:
            with open(here / "journal.jsonl", "ab") as journal:
                journal.write(b'{"seq": 99, "type": "step", "step": "soak-2.sequ')
        station = _resume(tmp_path, here)
    code, out = station.finish()
    assert code == 0, "".join(station.lines)[-3000:]
    here = run_dir()
    assert here is not None

    # one record, in the database and beside the files
    with RecordStore.open(tmp_path / "records.sqlite") as store:
        (stored,) = store.query()
    record = json.loads((here / "record.json").read_text())
    assert stored.run_id == record["run_id"] == _journal(here)[0]["run_id"] and record["outcome"] == "PASS"
    # no step twice, in the journal or the record; the same steps and phases as the uninterrupted run
    steps = _steps(here)
    assert steps == _steps(uninterrupted)
    names = [p["name"] for p in record["phases"]]
    assert len(names) == len(set(names))
    assert names == [p["name"] for p in json.loads((uninterrupted / "record.json").read_text())["phases"]]
    assert [e["type"] for e in _journal(here)].count("end") == 1
    # every capture journaled before a kill is there, byte for byte; the cut ones kept aside
    for path, sha in kept.items():
        assert _sha(here / path) == sha, path
    assert stored.verify() == []
    aside = sorted(p.name for p in (here / "interrupted").iterdir())
    assert any(n.startswith("soak-1.sequence.") for n in aside)
    assert any(n.startswith("ramp-2.") for n in aside)
    assert (here / "journal.torn").read_bytes().startswith(b'{"seq": 99')
    notes = [n for p in record["phases"] for n in p["notes"]]
    assert any(n.startswith("resumed at") for n in notes) and any("restored" in n for n in notes)

    # the parameters: as the uninterrupted run's, within their 1-sigma (same unit, other noise)
    a = yaml.safe_load((here / "params.yaml").read_text())
    b = yaml.safe_load((uninterrupted / "params.yaml").read_text())
    for triad in ("accel", "gyro"):
        for key in ("bias", "scale"):
            sigma = np.hypot(a[triad]["stddev"][key], b[triad]["stddev"][key])
            diff = np.abs(np.subtract(a[triad][key], b[triad][key]))
            assert np.all(diff <= 6 * sigma + 1e-9), (triad, key, diff, sigma)


def test_campaign_turn_on_and_thermal_bias_against_truth(uninterrupted: Path) -> None:
    """The pooled turn-on repeatability against the simulated unit's turn-on sigma (3 power-ups at 3 soaks:
    s^2/sigma^2 ~ chi2(6)/6, within 0.09..4 at 99.9 %, so sigma within 0.3..2 times), and the thermal bias
    model's change from the first to the last soak against the truth's, within what the power-ups between
    the ramps allow (4 sqrt(2) turn-on sigma)."""
    truth = UnitTruth.random(0, "mems", thermal_intrinsics=True)
    params = ParamsFile.load(uninterrupted / "params.yaml")
    record = json.loads((uninterrupted / "record.json").read_text())
    values = {m["name"]: m["value"] for p in record["phases"] for m in p["measurements"]}
    temps = np.array([values["soak-1.temperature_c"], values["soak-3.temperature_c"]])
    character = params.other["characterisation"]
    thermal = params.thermal
    assert thermal is not None
    for triad in ("accel", "gyro"):
        sensor = getattr(truth, triad)
        ratio = np.asarray(character[f"{triad}_bias_repeatability"]) / sensor.turn_on_sigma
        assert np.all((ratio > 0.3) & (ratio < 2.0)), (triad, ratio)
        model = getattr(thermal, triad).evaluate(temps, np.zeros(2), thermal.reference_temp)
        true = sensor.thermal.bias(temps, np.zeros(2))
        change, true_change = model[1] - model[0], true[1] - true[0]
        assert np.all(np.abs(change - true_change) <= 4 * np.sqrt(2) * sensor.turn_on_sigma), \
            (triad, change, true_change)
    calibrate = next(p for p in record["phases"] if p["name"] == "calibrate")
    assert any(n.startswith("thermal bias (T and dT terms) fitted on the ramp records")
               for n in calibrate["notes"])
