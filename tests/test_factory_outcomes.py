"""How a run ends when nobody is there: the factory operator's answers, a table that fails, a step that keeps
failing its checks (exit 2), a run over its time (exit 5)."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest

from drivers.errors import DriverError
from drivers.turntable import Turntable
from mocks.device import SimDevice
from mocks.turntable_sim import TurntableSim
from station.acquisition.operator import Action, Prompt, ScriptedOperator
from station.acquisition.sequences import PoseStep, RotationStep, Sequence
from station.factory.api import FactoryStation, SimulatedUnit
from station.factory.plan import SCHEMA, load_plan
from station.factory.run import FactoryOperator, TableOperator

STEP = PoseStep("+z", 1.0)


def prompt(kind: str, choices: tuple[Action, ...]) -> Prompt:
    return Prompt(kind, f"{kind}?", choices, choices[0], STEP, ("turned +180.0 deg, asked +360",))


def test_factory_answers() -> None:
    events: list[dict] = []
    inner = ScriptedOperator()
    op = FactoryOperator(inner, time.monotonic() + 60, events.append)
    assert op.confirm(prompt("start", (Action.ACCEPT, Action.ABORT))) is Action.ACCEPT
    every = (Action.REDO, Action.SKIP, Action.ACCEPT, Action.ABORT)
    assert op.confirm(prompt("review", every)) is Action.REDO
    # out of attempts: a factory never accepts or skips a failed step
    assert op.confirm(prompt("review", (Action.SKIP, Action.ACCEPT, Action.ABORT))) is Action.ABORT
    assert op.confirm(prompt("timeout", (Action.REDO, Action.SKIP, Action.ABORT))) is Action.ABORT
    op.begin(Sequence("s", (STEP,)))
    op.place(STEP, 0, 1)
    assert [e["event"] for e in events] == ["sequence", "step"]
    assert [e.event for e in inner.transcript] == ["begin", "place"]  # the inner operator sees it all
    assert op.poll() is None and not op.timed_out
    inner.request("skip")
    assert op.poll() is Action.SKIP
    late = FactoryOperator(inner, time.monotonic() - 1)
    assert late.poll() is Action.ABORT and late.timed_out


def test_table_error_is_kept_and_aborts_at_the_next_poll() -> None:
    sim = TurntableSim(SimDevice(seed=2, rate_hz=50)).start()
    table = Turntable(sim.port_path)
    op = TableOperator(table, timeout_s=2.0)
    op.place(PoseStep("+x"), 0, 2)
    assert op.error is None and op.poll() is None
    sim.stop()  # the table's cable is pulled
    op.rotate(RotationStep("rot+x"))
    assert isinstance(op.error, DriverError) and sim.port_path in str(op.error)
    assert op.poll() is Action.ABORT
    op.place(PoseStep("-x"), 1, 2)  # nothing more is sent to a failed table
    table.close()


def write_plan(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "plan.yaml"
    path.write_text(f"schema: {SCHEMA}\nname: outcome\n{body}")
    return path


def test_step_failing_its_checks_twice_aborts_exit_2(tmp_path: Path) -> None:
    """A table with a wrong gear turns 20 % too far: the turn check fails, is retried once, then the run
    aborts. (A table turning short never completes the turn: that is a step timeout, exit 5.)"""
    (tmp_path / "seq.yaml").write_text("name: one-turn\nsettle_s: 0.4\nrotation_rate_dps: 360\n"
                                       "steps: [rot+z]\n")
    plan = load_plan(write_plan(tmp_path, "sequence: {file: seq.yaml}\ndevice: {rate_hz: 50}\n"
                                          "run: {max_attempts: 2, step_timeout_s: 20}\n"))
    with FactoryStation(plan, db=str(tmp_path / "r.sqlite"), station="t") as line:
        record = line.run("GEAR-1", simulate=SimulatedUnit(seed=4, table_turn_error=0.2, speed=3))
        (stored,) = line.history("GEAR-1")
    assert (record.outcome, record.exit_code) == ("ABORTED", 2)
    assert record.reason.startswith("step rot+z: turned +") and "asked +360" in record.reason
    turned = float(re.search(r"turned \+([0-9.]+) deg", record.reason).group(1))
    assert 432 * 0.97 < turned < 432 * 1.03  # 1.2 x 360, seen through the raw gyro (scale 1 +- 1 %, bias)
    sequence = record.phases[-1]
    assert sequence.name == "sequence" and sequence.outcome == "FAIL"
    assert record.measurements()["sequence.attempts"].value == 2
    assert stored.to_dict() == record.to_dict()
    assert (Path(record.files_dir) / "capture.csv").stat().st_size > 0


def test_run_over_its_time_exits_5(tmp_path: Path) -> None:
    plan = load_plan(write_plan(tmp_path, "sequence: {name: six-position, rotations: false, hold_s: 1}\n"
                                          "device: {rate_hz: 50}\nrun: {timeout_s: 3}\n"))
    with FactoryStation(plan, db=str(tmp_path / "r.sqlite"), station="t") as line:
        record = line.run("SLOW-1", simulate=SimulatedUnit(seed=5))
    assert (record.outcome, record.exit_code) == ("TIMEOUT", 5)
    assert "timeout_s (3 s)" in record.reason
    steps = record.phases[-1].notes
    assert steps and "aborted" in steps[-1]
    assert record.verify() == []


def test_no_port_is_a_usage_error(tmp_path: Path) -> None:
    from station.errors import StationError

    plan = load_plan(write_plan(tmp_path, "sequence: six-position\n"))
    with FactoryStation(plan, db=str(tmp_path / "r.sqlite")) as line:
        with pytest.raises(StationError, match="--port"):
            line.run("X")


def test_table_turning_short_times_out_exit_5(tmp_path: Path) -> None:
    """A table that turns half of what it is asked never completes rot+z: step timeout, exit 5."""
    (tmp_path / "seq.yaml").write_text("name: one-turn\nsettle_s: 0.4\nrotation_rate_dps: 360\n"
                                       "steps: [rot+z]\n")
    plan = load_plan(write_plan(tmp_path, "sequence: {file: seq.yaml}\ndevice: {rate_hz: 50}\n"
                                          "run: {step_timeout_s: 4}\n"))
    with FactoryStation(plan, db=str(tmp_path / "r.sqlite"), station="t") as line:
        record = line.run("SHORT-1", simulate=SimulatedUnit(seed=4, table_turn_error=-0.5, speed=3))
    assert (record.outcome, record.exit_code) == ("TIMEOUT", 5)
    assert "rot+z" in record.reason and "turn not completed" in record.reason and "after 4 s" in record.reason


def test_real_ports_and_a_unit_reporting_another_serial_fails(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``run --port --table-port`` on ports served here; the unit on the fixture is not the one named."""
    import dataclasses

    from mocks.pty_server import PtyServer
    from mocks.truth import UnitTruth
    from station import cli

    path = write_plan(tmp_path, "sequence: {name: six-position, rotations: false, hold_s: 0.5}\n"
                                "device: {rate_hz: 50}\nlimits:\n  accel.bias: {max_abs: 100, unit: mg}\n")
    truth = dataclasses.replace(UnitTruth.random(3), serial="OTHER-9")
    with PtyServer(SimDevice(truth, seed=3, rate_hz=50), block_s=0.05) as server, \
            TurntableSim(server.device) as table:
        db = str(tmp_path / "r.sqlite")
        code = cli.main(["run", "--plan", str(path), "--port", server.port_path, "--table-port",
                         table.port_path, "--serial", "WANTED-1", "--db", db, "--json"])
    record = json.loads(capsys.readouterr().out)
    assert code == 1 and record["outcome"] == "FAIL"
    connect = record["phases"][0]
    serial = next(m for m in connect["measurements"] if m["name"] == "device.serial")
    assert (serial["value"], serial["outcome"]) == ("OTHER-9", "FAIL")
    assert "expected WANTED-1" in serial["doc"]
    calibrate = next(p for p in record["phases"] if p["name"] == "calibrate")
    assert all(m["outcome"] == "PASS" for m in calibrate["measurements"] if m["outcome"] != "UNSET")
    assert record["device"]["port"] == server.port_path
    assert record["reason"] == "outside limits: device.serial"


def test_ctrl_c_during_run_many_records_the_unit_aborted(tmp_path: Path) -> None:
    """Ctrl-C reaches run-many and its child (one process group): the unit is recorded ABORTED, exit 2."""
    import os
    import signal
    import subprocess
    import sys

    write_plan(tmp_path, "sequence: {name: six-position, rotations: false, hold_s: 1}\n"
                         "device: {rate_hz: 50}\n")
    argv = ["run-many", "--plan", "plan.yaml", "--simulate", "1", "--db", "r.sqlite", "--json"]
    proc = subprocess.Popen([sys.executable, "-m", "station.cli", *argv], cwd=tmp_path,
                            start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list((tmp_path / "r-files").glob("SIM-000000/*/capture.csv")):
        time.sleep(0.2)  # until the unit's sequence has started
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2, err[-2000:]
    (unit,) = json.loads(out)["units"]
    assert (unit["outcome"], unit["record"]["reason"]) == ("ABORTED", "interrupted (Ctrl-C)")
    from station.factory.records import RecordStore

    with RecordStore.open(tmp_path / "r.sqlite") as store:
        (record,) = store.query()
    assert record.outcome == "ABORTED" and record.verify() == []
    assert (record.phases[-1].name, record.phases[-1].outcome) == ("sequence", "ERROR")
