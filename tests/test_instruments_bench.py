"""A run's instruments as the station uses them: the plan's ``instruments:`` section, the limits
checked before anything is sent, the instruments left as ``on_abort`` says on any way out, the
transcript, description files refused by line, and ``imu-station instrument`` on the emulators
over real TCP sockets and ptys."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from drivers.instruments import Supply, Table
from drivers.instruments.errors import LimitRefused
from mocks.instruments.acutrol import AcutrolEmulator
from mocks.instruments.scpi_supply import ScpiSupply, SupplyOutputs
from mocks.instruments.serving import ByteServer
from station import cli
from station.errors import InputFileError
from station.factory.plan import load_plan
from station.instruments.bench import InstrumentPlan, OnAbort, open_bench
from station.instruments.limits import Limits
from station.instruments.reader import load_description, shipped_descriptions

PLAN_HEAD = "schema: imu-station/plan/1\nname: line-a\nsequence: six-position\n"


def _wait(condition, timeout_s: float = 20.0) -> None:  # noqa: ANN001 - a no-argument predicate
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.01)


@pytest.fixture
def supply():
    outputs = SupplyOutputs()
    emulator = ScpiSupply(outputs)
    with ByteServer(emulator, "tcp") as server:
        yield emulator, outputs, server


@pytest.fixture
def table():
    emulator = AcutrolEmulator()
    with ByteServer(emulator, "tcp") as server:
        yield emulator, server


def test_a_plan_names_its_instruments_with_limits_and_on_abort(tmp_path: Path) -> None:
    path = tmp_path / "plan.yaml"
    path.write_text(PLAN_HEAD + "instruments:\n"
                    "  chamber: {url: 'votsch://10.0.0.5', min_c: -40, max_c: 85, max_gradient: 3}\n"
                    "  table: {url: 'acutrol://10.0.0.7:5000', max_rate_dps: 400}\n"
                    "  supply: {url: 'scpi://10.0.0.9?channel=1', max_v: 12, max_a: 1}\n"
                    "  on_abort: {chamber: 'setpoint:23', supply: 'off'}\n")
    plan = load_plan(path).instruments
    assert plan is not None
    assert plan.urls() == {"chamber": "votsch://10.0.0.5", "table": "acutrol://10.0.0.7:5000",
                           "supply": "scpi://10.0.0.9?channel=1"}
    assert (plan.limits.min_c, plan.limits.max_c, plan.limits.max_gradient) == (-40, 85, 3)
    assert (plan.limits.max_rate_dps, plan.limits.max_v, plan.limits.max_a) == (400, 12, 1)
    assert plan.on_abort == OnAbort(chamber="setpoint:23", table="stop", supply="off")
    assert plan.limits.source == "the plan plan.yaml"


@pytest.mark.parametrize(("section", "line", "words"), [
    ("  chamber: {min_c: -40}\n", 5, "has no 'url'"),
    ("  chamber: {url: 'votsch://h', min_c: 90, max_c: 85}\n", 5, "'min_c' 90 must be below 'max_c' 85"),
    ("  table: {url: 'acutrol://h:1', max_rate: 400}\n", 5, "unknown key 'max_rate'"),
    ("  supply: {url: 'scpi://h', max_v: -1}\n", 5, "'max_v' must be a positive number"),
    ("  on_abort: {table: spin}\n", 5, "on_abort table must be one of stop, home, not 'spin'"),
    ("  table: {url: '10.0.0.7'}\n", 5, "is not an instrument URL"),
])
def test_a_bad_instruments_section_is_refused_by_line(tmp_path: Path, section: str, line: int,
                                                      words: str) -> None:
    path = tmp_path / "plan.yaml"
    path.write_text(PLAN_HEAD + "instruments:\n" + section)
    with pytest.raises(InputFileError) as refused:
        load_plan(path)
    assert f"plan.yaml, line {line}" in str(refused.value) and words in str(refused.value)


def test_a_description_file_is_refused_with_file_line_and_key(tmp_path: Path) -> None:
    mine = tmp_path / "mine.yaml"
    shipped = shipped_descriptions()["espec"].read_text()
    mine.write_text(shipped.replace("TEMP,S{value:.1f}", "TEMP,S{val:.1f}"))
    with pytest.raises(InputFileError) as refused:
        load_description(mine)
    text = str(refused.value)
    assert text.startswith(f"{mine}, line ")
    assert "commands.set_setpoint.send: field {val} is not one of" in text


def test_the_limits_refuse_before_anything_is_sent(supply) -> None:
    emulator, outputs, server = supply
    plan = InstrumentPlan(supply=f"scpi://{server.address}",
                          limits=Limits(max_v=12, max_a=1, source="the plan p"))
    with open_bench(plan) as bench:
        assert isinstance(bench.supply, Supply)
        heard = len(emulator.commands)
        with pytest.raises(LimitRefused, match=r"voltage \(V\) 24 is beyond supply.max_v = 12 of the plan p"):
            bench.supply.set_voltage(24.0)
        assert len(emulator.commands) == heard  # nothing reached the supply
        bench.supply.set_voltage(5.0)  # unanswered: the emulator takes it in its own thread
        _wait(lambda: outputs.channels[0].volts == pytest.approx(5.0))


def test_an_exception_leaves_the_instruments_as_on_abort_says(supply, table) -> None:
    supply_emulator, outputs, supply_server = supply
    table_emulator, table_server = table
    plan = InstrumentPlan(table=f"acutrol://{table_server.address}", supply=f"scpi://{supply_server.address}",
                          on_abort=OnAbort(supply="off"))
    with pytest.raises(RuntimeError, match="the run failed"), open_bench(plan) as bench:
        assert isinstance(bench.table, Table) and isinstance(bench.supply, Supply)
        bench.supply.set_output(True)
        bench.table.turn(60.0)
        _wait(lambda: abs(table_emulator.axes[0].state()[1]) > 30.0)
        raise RuntimeError("the run failed")
    _wait(lambda: abs(table_emulator.axes[0].state()[1]) < 1e-9)  # the table stopped
    _wait(lambda: outputs.channels[0].on is False)  # the supply switched off
    assert any("table" in n and ": stop" in n for n in bench.notes)
    commands = [e.command for e in bench.transcript.entries()]
    assert "OUTP OFF" in commands and any(c.startswith(":D:R 1,0") for c in commands)
    assert all(e.t > 0 and e.duration_s >= 0 for e in bench.transcript.entries())


def test_the_instrument_command_prints_the_state_as_json(supply, capsys: pytest.CaptureFixture[str]) -> None:
    _, outputs, server = supply
    url = f"scpi://{server.address}"
    code = cli.main(["instrument", url, "--voltage", "5", "--current", "0.5", "--output", "on",
                     "--max-v", "12", "--json"])
    state = json.loads(capsys.readouterr().out)
    assert code == 0
    assert state["kind"] == "supply" and state["url"] == url and state["identity"]
    assert state["output"] is True and state["voltage_v"] == pytest.approx(5.0, abs=0.05)
    assert outputs.channels[0].on is True


def test_the_instrument_command_refuses_beyond_a_limit(supply, capsys: pytest.CaptureFixture[str]) -> None:
    emulator, _, server = supply
    code = cli.main(["instrument", f"scpi://{server.address}", "--voltage", "30", "--max-v", "12"])
    err = capsys.readouterr().err
    assert code == 4
    assert "voltage (V) 30 is beyond supply.max_v = 12" in err and "Traceback" not in err
    assert not any(c.startswith("VOLT") for c in emulator.commands)


@pytest.mark.parametrize(("url", "code", "words"), [
    ("nosuch://10.0.0.1", 4, "unknown instrument scheme 'nosuch://'"),
    ("scpi://127.0.0.1:9?colour=red", 4, "unknown option ?colour="),
    ("scpi://127.0.0.1:1", 3, "cannot connect to 127.0.0.1:1"),
    ("sim://chamber", 3, "no simulated chamber runs in this process"),
])
def test_the_instrument_command_names_what_is_wrong(url: str, code: int, words: str,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["instrument", url]) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_settings_of_two_kinds_at_once_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["instrument", "scpi://127.0.0.1:1", "--voltage", "5", "--rate", "10"]) == 4
    assert "one instrument takes one kind" in capsys.readouterr().err
