"""The factory plan: the example loads, every mistake is refused naming its line, exit 4 from the CLI."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import pytest

from station import cli
from station.errors import InputFileError
from station.factory.plan import SCHEMA, load_plan

REPO = Path(__file__).resolve().parents[1]

GOOD = f"""\
schema: {SCHEMA}
name: line-a
sequence: {{name: six-position, hold_s: 1.5, rotation_rate_dps: 180, settle_s: 0.5}}
device: {{rate_hz: 100}}
engine: {{latitude: 45.07, height: 240}}
run: {{timeout_s: 120, step_timeout_s: 10, max_attempts: 3}}
limits:
  accel.bias: {{max_abs: 50, unit: mg}}
  gyro.bias: {{min: -1, max: 2, unit: deg/s}}
  gyro.scale_error: {{max_abs: 2, unit: "%"}}
  link.lost_fraction: {{max: 0.001}}
export: [c, px4]
"""


H = f"schema: {SCHEMA}\nname: a\nsequence: six-position\n"


def write(tmp_path: Path, text: str, name: str = "plan.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_example_plan_loads() -> None:
    plan = load_plan(REPO / "examples" / "plan.yaml")
    assert plan.sequence.labels[:6] == ["+x", "-x", "+y", "-y", "+z", "-z"]
    assert plan.sequence.labels[6:] == ["rot+x", "rot-x", "rot+y", "rot-y", "rot+z", "rot-z"]
    assert plan.export == ("c", "json")
    assert plan.limit("gyro.bias").unit == "deg/s"


def test_good_plan_fields_and_units(tmp_path: Path) -> None:
    plan = load_plan(write(tmp_path, GOOD))
    assert plan.name == "line-a" and plan.rate_hz == 100 and plan.max_attempts == 3
    assert plan.latitude == 45.07 and plan.height == 240 and plan.gravity is None
    assert plan.sequence.steps[0].hold_s == 1.5 and plan.sequence.steps[-1].rate_dps == 180
    bias = plan.limit("accel.bias")
    assert (bias.low, bias.high, bias.unit, bias.line) == (-50, 50, "mg", 8)
    assert bias.si_factor == pytest.approx(9.80665e-3)
    assert plan.limit("gyro.bias").si_factor == pytest.approx(math.pi / 180)
    assert plan.limit("gyro.bias").check(1.5) and not plan.limit("gyro.bias").check(-1.5)
    assert not plan.limit("gyro.bias").check(math.nan)
    assert len(plan.sha256) == 64


def test_sequence_file_relative_to_plan(tmp_path: Path) -> None:
    write(tmp_path, "name: quick\nhold_s: 1\nsteps: [+z, -z, rot+z]\n", "seq.yaml")
    plan = load_plan(write(tmp_path, f"schema: {SCHEMA}\nname: q\nsequence: {{file: seq.yaml}}\n"))
    assert plan.sequence.labels == ["+z", "-z", "rot+z"]


@pytest.mark.parametrize(("text", "line", "words"), [
    (H + "limts: {}\n", 4, "unknown key 'limts'"),
    ("schema: imu-station/plan/9\nname: a\nsequence: six-position\n", 1, "this station reads"),
    (f"schema: {SCHEMA}\nname: a\nsequence: seven-position\n", 3, "unknown sequence"),
    (H + "limits:\n  accel.bias: {max_abs: 1, unit: deg/s}\n",
     5, "not a unit of accel.bias"),
    (H + "limits:\n  accel.bais: {max: 1}\n", 5,
     "unknown quantity 'accel.bais'"),
    (H + "limits:\n  gyro.bias:\n    min: 2\n    max: 1\n", 6,
     "'min' 2.0 is above 'max' 1.0"),
    (H + "export: [c, hex]\n", 4, "unknown export format 'hex'"),
    (H + "run: {timeout_s: -3}\n", 4, "positive number"),
    (H + "device: {rate_hz: 100.5}\n", 4, "whole number"),
    (H + "engine: {method: free}\n", 4, "labelled sequence"),
    (f"schema: {SCHEMA}\nname: a\nsequence:\n  name: six-position\n  hold_s: 0\n", 5, "positive number"),
    (H + "engine: {gravity: 3.7}\n", 4, "9.78..9.84"),
    (f"schema: {SCHEMA}\nname: a: b\nsequence: six-position\n", 2, "not valid YAML"),
])
def test_mistakes_name_the_line(tmp_path: Path, text: str, line: int, words: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(InputFileError) as info:
        load_plan(path)
    assert info.value.line == line, str(info.value)
    assert words in str(info.value)
    assert str(info.value).startswith(f"{path}, line {line}")


def test_missing_plan_file(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match="does not exist"):
        load_plan(tmp_path / "nope.yaml")


def test_cli_plan_error_exits_4_naming_the_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path, H + "limits:\n"
                           "  gyro.bias: {max_abs: 1, unit: furlongs}\n")
    code = cli.main(["run", "--plan", str(path), "--simulate", "--serial", "X1",
                     "--db", str(tmp_path / "r.sqlite")])
    err = capsys.readouterr().err
    assert code == 4
    assert f"{path}, line 5" in err and "furlongs" in err
    assert not (tmp_path / "r.sqlite").exists()  # refused before anything ran


@pytest.mark.parametrize("argv", [
    ["run", "--simulate", "--serial", "X"],  # no --plan
    ["run", "--plan", "p.yaml", "--simulate", "--serial", "X", "--bogus"],
])
def test_cli_usage_error_exits_4(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 4
    assert "error:" in capsys.readouterr().err


def test_cli_port_without_table_exits_4(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["run", "--plan", str(REPO / "examples" / "plan.yaml"), "--port", "/dev/null",
                     "--serial", "X"])
    assert code == 4
    assert "--table-port" in capsys.readouterr().err


def test_help_documents_exit_codes(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["run", "--help"])
    out = capsys.readouterr().out
    for code, word in ((0, "pass"), (1, "fail"), (2, "aborted"), (3, "device or link"), (4, "usage"),
                       (5, "timeout")):
        assert f"  {code}  {word}" in out
