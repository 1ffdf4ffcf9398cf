"""Unattended runs end to end, through real processes and pseudo-terminals for the units and their tables:
four simulated units at once into one database, a unit outside its limits, a unit unplugged mid-run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_factory_records import private_postgres

from mocks.truth import UnitTruth
from station.acquisition.capture import read_capture
from station.factory.plan import SCHEMA
from station.factory.records import RecordStore, RunRecord, sha256_file
from station.plots.trend import trend_series, write_trend_plot

REPO = Path(__file__).resolve().parents[1]
SEEDS = (21, 22, 23, 24)

# Six poses and one turn per axis: every intrinsic of both triads, in about 30 s per unit.
LINE_PLAN = f"""\
schema: {SCHEMA}
name: test-line
sequence: {{file: seq.yaml}}
device: {{rate_hz: 100}}
run: {{timeout_s: 150, step_timeout_s: 20, max_attempts: 2}}
limits:
  accel.bias:         {{max_abs: 80, unit: mg}}
  accel.scale_error:  {{max_abs: 5, unit: "%"}}
  accel.misalignment: {{max_abs: 2, unit: deg}}
  accel.residual_rms: {{max: 0.02, unit: m/s^2}}
  gyro.bias:          {{max_abs: 3, unit: deg/s}}
  gyro.scale_error:   {{max_abs: 5, unit: "%"}}
  gyro.misalignment:  {{max_abs: 2, unit: deg}}
  link.lost_fraction: {{max: 0.001}}
export: [c, json]
"""
LINE_SEQUENCE = """\
name: six-and-three-turns
hold_s: 1
settle_s: 0.5
rotation_rate_dps: 180
steps: [+x, -x, +y, -y, +z, -z, rot+x, rot+y, rot+z]
"""
# The accelerometer alone, with a bias limit no MEMS unit meets.
TIGHT_PLAN = f"""\
schema: {SCHEMA}
name: tight
sequence: {{name: six-position, rotations: false, hold_s: 1}}
device: {{rate_hz: 100}}
run: {{timeout_s: 120, step_timeout_s: 20}}
limits:
  accel.bias: {{max_abs: 1, unit: mg}}
"""


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "IMU_STATION_ID": "test-station", "COLUMNS": "160"}
    env.pop("IMU_STATION_DB", None)
    return subprocess.run([sys.executable, "-m", "station.cli", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=280)


@pytest.fixture(scope="module")
def line(tmp_path_factory: pytest.TempPathFactory) -> tuple[subprocess.CompletedProcess[str], Path]:
    """``run-many --simulate 4`` into one SQLite database (one process per unit)."""
    work = tmp_path_factory.mktemp("line")
    (work / "seq.yaml").write_text(LINE_SEQUENCE)
    (work / "plan.yaml").write_text(LINE_PLAN)
    # The simulated clocks run 3x real time: the same samples and motion, in a third of the wait.
    done = cli("run-many", "--plan", "plan.yaml", "--simulate", "4", "--seed", str(SEEDS[0]), "--speed", "3",
               "--db", "line.sqlite", "--json", cwd=work)
    return done, work


def test_four_units_concurrently_all_pass(line: tuple[subprocess.CompletedProcess[str], Path]) -> None:
    done, work = line
    assert done.returncode == 0, done.stderr[-3000:]
    out = json.loads(done.stdout)
    assert out["exit_code"] == 0
    assert [u["serial"] for u in out["units"]] == [f"SIM-{s:06d}" for s in SEEDS]
    assert [u["outcome"] for u in out["units"]] == ["PASS"] * 4
    # They ran at once: every run started before any ended.
    records = [RunRecord.from_dict(u["record"]) for u in out["units"]]
    assert max(r.start for r in records) < min(r.end for r in records)
    assert "sim 21" in done.stderr and "PASS" in done.stderr  # the live table on stderr


def test_every_record_present_and_consistent(line: tuple[subprocess.CompletedProcess[str], Path]) -> None:
    done, work = line
    out = json.loads(done.stdout)
    with RecordStore.open(work / "line.sqlite") as store:
        stored = {r.serial: r for r in store.query()}
        counts = store.table_counts()
        per_run = store.rows("SELECT run_id, COUNT(*) FROM measurements GROUP BY run_id")
    assert sorted(stored) == [f"SIM-{s:06d}" for s in SEEDS]
    assert counts["runs"] == 4 and counts["phases"] == 16
    assert len({n for _, n in per_run}) == 1  # the same measurements for every unit
    for unit in out["units"]:
        record = stored[unit["serial"]]
        assert record.to_dict() == unit["record"]  # what was printed is what was stored
        assert record.station == "test-station" and record.exit_code == 0 and record.end > record.start
        assert [p.name for p in record.phases] == ["connect", "sequence", "calibrate", "export"]
        assert all(p.outcome == "PASS" and p.start <= p.end for p in record.phases)
        assert record.plan["sha256"] == sha256_file(work / "plan.yaml")
        names = {a.path for a in record.attachments()}
        assert {"capture.csv", "params.yaml", "imu_calib.json", "c/imu_calib.h", "c/imu_calib.c",
                "c/imu_calib.bin"} <= names
        assert record.verify() == []  # every file on disk, with the recorded SHA-256
        on_disk = json.loads((Path(record.files_dir) / "record.json").read_text())
        assert on_disk == record.to_dict()
        m = record.measurements()
        assert m["sequence.steps_accepted"].value == 9 and m["device.serial"].value == record.serial
        assert all(x.outcome == "PASS" for x in m.values() if x.low is not None or x.high is not None)
        capture = read_capture(Path(record.files_dir) / "capture.csv")
        assert [label for label, _ in capture.segments()] == ["+x", "-x", "+y", "-y", "+z", "-z", "rot+x",
                                                                "rot+y", "rot+z"]
        assert len(capture) == m["capture.samples"].value


def test_trend_plot_of_the_line(line: tuple[subprocess.CompletedProcess[str], Path], tmp_path: Path) -> None:
    _, work = line
    with RecordStore.open(work / "line.sqlite") as store:
        records = store.query()
    series = trend_series(records)
    assert "gyro.bias.z" in series and "device.serial" not in series  # numeric, limited ones
    expected = [r.measurements()["gyro.bias.z"].value for r in records]
    assert series["gyro.bias.z"]["values"].tolist() == expected
    assert (series["gyro.bias.z"]["low"], series["gyro.bias.z"]["high"]) == (-3.0, 3.0)
    plotted = write_trend_plot(tmp_path / "trend.png", records, ["gyro.bias.z", "accel.scale_error.x"])
    assert plotted == ["gyro.bias.z", "accel.scale_error.x"]
    assert (tmp_path / "trend.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("seed", SEEDS)
def test_recovered_parameters_match_each_units_truth(line: tuple[subprocess.CompletedProcess[str], Path],
                                                     seed: int) -> None:
    """Tolerances: accelerometer M 2e-3 and b 6e-3 m/s^2 (1 s holds: ~5 sigma of the bias);
    gyroscope M 4e-3 (one turn per axis) and b 2e-3 rad/s; the units' own errors are ~1e-2."""
    _, work = line
    with RecordStore.open(work / "line.sqlite") as store:
        (record,) = store.query(serial=f"SIM-{seed:06d}")
    params = yaml.safe_load((Path(record.files_dir) / "params.yaml").read_text())
    truth = UnitTruth.random(seed)
    tolerances = {"accel": (2e-3, 6e-3), "gyro": (4e-3, 2e-3)}
    for sensor, (tol_m, tol_b) in tolerances.items():
        true = getattr(truth, sensor)
        matrix, bias = np.array(params[sensor]["matrix"]), np.array(params[sensor]["bias"])
        assert np.abs(matrix - true.matrix).max() < tol_m, sensor
        assert np.abs(bias - true.bias).max() < tol_b, sensor
        assert np.abs(true.matrix - np.eye(3)).max() > 2 * tol_m  # the unit is far from ideal
    m = record.measurements()
    # the record's measurements are the parameter file's values in the limits' units
    assert m["accel.bias.y"].value == pytest.approx(params["accel"]["bias"][1] / 9.80665e-3)
    assert m["gyro.scale_error.z"].value == pytest.approx((params["gyro"]["scale"][2] - 1) * 100)
    assert m["gyro.misalignment.xz"].value == pytest.approx(np.degrees(params["gyro"]["misalignment"][0][2]))


Line = tuple[subprocess.CompletedProcess[str], Path]


def test_records_command_history_export_and_verify(line: Line) -> None:
    _, work = line
    serial = f"SIM-{SEEDS[1]:06d}"
    done = cli("records", "--db", "line.sqlite", "--serial", serial, "--export", "history.json", "--verify",
               cwd=work)
    assert done.returncode == 0, done.stderr
    assert serial in done.stdout and "all intact" in done.stdout
    history = json.loads((work / "history.json").read_text())
    assert history["schema"] == "imu-station/records-export/1"
    assert [r["serial"] for r in history["records"]] == [serial]
    since = cli("records", "--db", "line.sqlite", "--json", "--since", "2000-01-01", cwd=work)
    assert len(json.loads(since.stdout)) == 4
    until = cli("records", "--db", "line.sqlite", "--json", "--until", "2000-01-01", cwd=work)
    assert json.loads(until.stdout) == []
    # an altered capture is found, and --verify says so with exit 1
    capture = Path(history["records"][0]["files_dir"]) / "capture.csv"
    original = capture.read_bytes()
    try:
        capture.write_bytes(original.replace(b"\n", b"\r\n", 1))
        done = cli("records", "--db", "line.sqlite", "--serial", serial, "--verify", cwd=work)
        assert done.returncode == 1 and "SHA-256 differs" in done.stderr
    finally:
        capture.write_bytes(original)


def test_unit_outside_its_limits_exits_1(tmp_path: Path) -> None:
    (tmp_path / "tight.yaml").write_text(TIGHT_PLAN)
    done = cli("run", "--plan", "tight.yaml", "--simulate", "--seed", "8", "--speed", "3", "--serial", "auto",
               "--json", "--db", "r.sqlite", cwd=tmp_path)
    assert done.returncode == 1, done.stderr[-2000:]
    record = json.loads(done.stdout)
    assert record["outcome"] == "FAIL" and record["exit_code"] == 1
    failed = {m["name"]: m for p in record["phases"] for m in p["measurements"] if m["outcome"] == "FAIL"}
    truth = UnitTruth.random(8).accel.bias / 9.80665e-3  # mg
    assert set(failed) == {f"accel.bias.{a}" for a, b in zip("xyz", truth, strict=True) if abs(b) > 1.2}
    for m in failed.values():
        assert (m["low"], m["high"], m["unit"]) == (-1.0, 1.0, "mg") and abs(m["value"]) > 1
    assert "outside limits" in record["reason"]
    assert (Path(record["files_dir"]) / "params.yaml").exists()  # a failed unit's files are kept too
    with RecordStore.open(tmp_path / "r.sqlite") as store:
        assert [r.outcome for r in store.query(serial=record["serial"])] == ["FAIL"]
    assert "outcome FAIL" in done.stderr  # the log


def test_unit_unplugged_mid_run_exits_3_keeping_its_capture(tmp_path: Path) -> None:
    (tmp_path / "tight.yaml").write_text(TIGHT_PLAN)
    done = cli("run", "--plan", "tight.yaml", "--simulate", "--seed", "6", "--unplug-after", "4", "--serial",
               "U-6", "--json", "--db", "r.sqlite", cwd=tmp_path)
    assert done.returncode == 3, done.stderr[-2000:]
    record = RunRecord.from_dict(json.loads(done.stdout))
    assert record.outcome == "ERROR" and "link lost" in record.reason
    assert record.device["port"] in record.reason  # names the port
    sequence = record.phases[-1]
    assert sequence.name == "sequence" and sequence.outcome == "ERROR"
    (attachment,) = sequence.attachments
    path = Path(record.files_dir) / attachment.path
    assert sha256_file(path) == attachment.sha256
    capture = read_capture(path)
    assert 100 <= len(capture) <= 4.5 * 100  # what arrived in the 4 s before the cable was pulled
    assert np.all(np.diff(capture.t) > 0)
    assert "+x" in [label for label, _ in capture.segments()]  # the first step was complete
    with RecordStore.open(tmp_path / "r.sqlite") as store:
        assert [r.outcome for r in store.query(serial="U-6")] == ["ERROR"]


@pytest.fixture(scope="module")
def postgres_url() -> Iterator[str]:
    with private_postgres() as url:
        yield url


def test_example_factory_script_into_postgres(postgres_url: str, tmp_path: Path) -> None:
    """The documented API example: a turntable unit and a manual-fixture unit, records in PostgreSQL."""
    import psycopg

    with psycopg.connect(postgres_url, autocommit=True) as conn:
        conn.execute("CREATE DATABASE example_line")
    url = postgres_url.rsplit("/", 1)[0] + "/example_line"
    quick = TIGHT_PLAN.replace("max_abs: 1,", "max_abs: 80,").replace("hold_s: 1", "hold_s: 0.5")
    (tmp_path / "plan.yaml").write_text(quick.replace("rate_hz: 100", "rate_hz: 50"))
    script = REPO / "examples" / "factory_script.py"
    done = subprocess.run([sys.executable, str(script), "plan.yaml", "--db", url], cwd=tmp_path,
                          capture_output=True, text=True, timeout=200)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "EX-0002: PASS (exit 0), 6 placements asked" in done.stdout
    assert "fixture 3/6: put the unit with +y up" in done.stderr
    with RecordStore.open(url) as store:
        records = store.query()
    assert [(r.serial, r.outcome, r.station) for r in records] == [("EX-0001", "PASS", "example-line"),
                                                                    ("EX-0002", "PASS", "example-line")]
    assert all(r.verify() == [] for r in records)
    assert "table.serial" in records[0].measurements() and "table.serial" not in records[1].measurements()
