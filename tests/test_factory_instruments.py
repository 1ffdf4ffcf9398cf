"""A factory run with the plan's lab instruments (issue 26), on the simulated bench: the supply set and
switched on, the chamber soaked until the unit's own temperature settles, the instruments' identities
and every command in the record, and the instruments left as ``on_abort`` says when the run is cut
short. The instruments are the emulators of their real protocols on loopback sockets, coupled to the
simulated unit (``mocks.instruments.bench``), reached through the same drivers as real ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from station import cli
from station.factory.records import RecordStore

PLAN = """\
schema: imu-station/plan/1
name: soaked-line
sequence: {name: six-position, rotations: true, hold_s: 1, settle_s: 0.5}
device: {rate_hz: 100}
run: {timeout_s: 600, step_timeout_s: 60}
instruments:
  chamber: {url: "votsch://chamber.lab", min_c: -40, max_c: 85, max_gradient: 5, soak_c: 26,
            settle_rate_c_per_min: 0.3, settle_s: 60, settle_timeout_s: 300}
  supply: {url: "scpi://supply.lab", max_v: 12, max_a: 1, volts: 5, amps: 0.5}
  on_abort: {chamber: "setpoint:23", supply: "off"}
"""


def _run(tmp_path: Path, seed: int, *extra: str) -> int:
    """``imu-station run`` of the plan in ``tmp_path`` on the simulated unit and bench, 20x real time."""
    return cli.main(["run", "--plan", str(tmp_path / "plan.yaml"), "--simulate", "--seed", str(seed),
                     "--speed", "20", "--serial", "auto", "--db", str(tmp_path / "line.sqlite"), *extra])


def _record(db: Path) -> tuple[dict, Path]:
    with RecordStore.open(db) as store:
        (record,) = store.query()
    files = Path(record.files_dir)
    return json.loads((files / "record.json").read_text()), files


def test_a_run_soaks_the_unit_and_records_its_instruments(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "plan.yaml").write_text(PLAN)
    db = tmp_path / "line.sqlite"
    code = _run(tmp_path, 41)
    err = capsys.readouterr().err
    assert code == 0, err[-3000:]
    record, files = _record(db)
    phases = {p["name"]: p for p in record["phases"]}
    assert list(phases)[:3] == ["instruments", "connect", "soak"]
    measured = {m["name"]: m for p in record["phases"] for m in p["measurements"]}
    # The emulators answer as their instruments do: simserv's information, the SCPI *IDN?.
    assert "SIMSERV" in measured["instrument.chamber"]["value"]
    assert measured["instrument.supply"]["value"] and measured["instrument.supply"]["doc"].startswith("scpi://")
    # Settled: the unit's own reading near the soak (it lags the air), its slope within the plan's.
    assert abs(measured["unit.temperature_c"]["value"] - 26.0) < 1.0
    assert abs(measured["unit.temperature_slope"]["value"]) <= 0.3
    transcript = json.loads((files / "instruments.json").read_text())
    commands = [e["command"] for e in transcript["transcript"]]
    assert "VOLT 5.0000" in commands and "OUTP ON" in commands
    assert any(c.startswith("11001\\xb61\\xb61\\xb626.0") for c in commands)  # simserv's setpoint
    assert all(e["t"] > 0 and e["error"] == "" for e in transcript["transcript"])
    assert not transcript["on_abort"]  # a run that ran to its end leaves the instruments as they are
    attached = {a["name"] for a in phases["instruments"]["attachments"]}
    assert "instruments" in attached


def test_a_run_cut_short_leaves_the_instruments_as_on_abort_says(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "plan.yaml").write_text(PLAN)
    db = tmp_path / "line.sqlite"
    code = _run(tmp_path, 42, "--unplug-after", "4")
    capsys.readouterr()
    assert code == 3
    record, files = _record(db)
    assert record["outcome"] == "ERROR"
    transcript = json.loads((files / "instruments.json").read_text())
    notes = transcript["on_abort"]
    assert any(n.startswith("supply ") and n.endswith(": off") for n in notes)
    assert any(n.startswith("chamber ") and n.endswith(": setpoint:23") for n in notes)
    commands = [e["command"] for e in transcript["transcript"]]
    assert commands.index("OUTP OFF") > commands.index("OUTP ON")
    assert any(c.startswith("11001\\xb61\\xb61\\xb623.0") for c in commands)


def test_a_soak_that_does_not_settle_times_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = PLAN.replace("settle_rate_c_per_min: 0.3, settle_s: 60, settle_timeout_s: 300",
                        "settle_rate_c_per_min: 0.0001, settle_s: 60, settle_timeout_s: 3")
    (tmp_path / "plan.yaml").write_text(plan)
    db = tmp_path / "line.sqlite"
    code = _run(tmp_path, 43)
    capsys.readouterr()
    assert code == 5
    record, _ = _record(db)
    assert record["outcome"] == "TIMEOUT" and "did not settle within 3 s" in record["reason"]


def test_twelve_positions_and_turns_run_on_the_plans_rate_table(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    # The plan names a three-axis ACUTROL table (no --table-port): the run places and turns the unit
    # through the table's own protocol, as on a lab's table, and calibrates it within the plan's limits.
    plan = PLAN.split("instruments:")[0].replace("six-position", "twelve-position") + """\
limits:
  accel.bias: {max_abs: 0.5, unit: m/s^2}
  gyro.scale_error: {max_abs: 3, unit: "%"}
instruments:
  table: {url: "acutrol://table.lab:5000?axes=3", max_rate_dps: 200, max_accel_dps2: 400, mount: +z}
  on_abort: {table: stop}
"""
    (tmp_path / "plan.yaml").write_text(plan)
    code = _run(tmp_path, 44)
    err = capsys.readouterr().err
    assert code == 0, err[-3000:]
    record, files = _record(tmp_path / "line.sqlite")
    measured = {m["name"]: m for p in record["phases"] for m in p["measurements"]}
    assert measured["sequence.steps_accepted"]["value"] == 18  # twelve poses and six turns
    assert measured["instrument.table"]["doc"].startswith("acutrol://127.0.0.1:")
    commands = [e["command"] for e in json.loads((files / "instruments.json").read_text())["transcript"]]
    assert any(c.startswith(":D:P 2,") for c in commands) and any(c.startswith(":D:R 1,") for c in commands)
