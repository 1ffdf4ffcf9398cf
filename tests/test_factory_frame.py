"""Factory runs of a board that streams its own frames (``protocol: frame:FILE.yaml``): the plan names
the description (checked with the plan, before any port opens), ``run``/``run-many --protocol``
choose it, and a whole run goes through a simulated unit streaming those frames on a pty, turned by
the simulated table, into a calibrated, recorded PASS."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from frame_helpers import SPEC_EXAMPLE

from station.acquisition.capture import read_capture
from station.cli import main
from station.errors import InputFileError, StationError
from station.factory.plan import SCHEMA, load_plan, with_protocol
from station.factory.records import RecordStore

SEQUENCE = """\
name: six-and-three-turns
hold_s: 1
settle_s: 0.5
rotation_rate_dps: 180
steps: [+x, -x, +y, -y, +z, -z, rot+x, rot+y, rot+z]
"""


def plan_text(device: str) -> str:
    return f"""\
schema: {SCHEMA}
name: frame-line
sequence: {{file: seq.yaml}}
device: {device}
run: {{timeout_s: 150, step_timeout_s: 20, max_attempts: 2}}
limits:
  accel.bias:         {{max_abs: 80, unit: mg}}
  accel.scale_error:  {{max_abs: 5, unit: "%"}}
  accel.residual_rms: {{max: 0.02, unit: m/s^2}}
  gyro.bias:          {{max_abs: 3, unit: deg/s}}
  gyro.scale_error:   {{max_abs: 5, unit: "%"}}
  link.lost_fraction: {{max: 0.001}}
export: [json]
"""


@pytest.fixture
def work(tmp_path: Path) -> Path:
    """A folder with the sequence, the spec's example description (200 Hz) and a plan naming it."""
    (tmp_path / "seq.yaml").write_text(SEQUENCE)
    (tmp_path / "acme.yaml").write_text(yaml.safe_dump(SPEC_EXAMPLE, sort_keys=False))
    (tmp_path / "plan.yaml").write_text(plan_text("{protocol: frame:acme.yaml}"))
    return tmp_path


def test_a_plan_names_a_description_beside_it_and_takes_its_rate(work: Path) -> None:
    plan = load_plan(work / "plan.yaml")
    assert plan.protocol == f"frame:{(work / 'acme.yaml').resolve()}"
    assert plan.rate_hz == SPEC_EXAMPLE["rate_hz"] and not plan.asks_serial
    native = load_plan(_plan(work, "{rate_hz: 100}"))
    assert native.protocol == "native" and native.asks_serial
    chosen = with_protocol(native, f"frame:{work / 'acme.yaml'}")
    assert chosen.protocol == plan.protocol and chosen.rate_hz == 200
    assert with_protocol(native, "frame:witmotion").protocol.endswith("witmotion.yaml")  # a shipped one


def _plan(work: Path, device: str) -> Path:
    path = work / "other.yaml"
    path.write_text(plan_text(device))
    return path


@pytest.mark.parametrize(("device", "line", "words"), [
    ("{protocol: xsens}", 4, "native protocol"),
    ("{protocol: frame:missing.yaml}", 4, "missing.yaml"),
    ("{protocol: frame:acme.yaml, rate_hz: 100}", 4, "'rate_hz' is 100 but the frame description gives"),
    ("{protocol: frame:broken.yaml}", 4, "broken.yaml, line 5: key 'fields'"),
])
def test_a_plan_with_a_wrong_protocol_is_refused_naming_its_line(work: Path, device: str, line: int,
                                                                 words: str) -> None:
    (work / "broken.yaml").write_text("schema: imu-station/frame/1\nname: b\nsync: [0xAA]\nlength: 4\n"
                                      "fields: []\n")
    path = _plan(work, device)
    with pytest.raises(InputFileError) as info:
        load_plan(path)
    assert str(info.value).startswith(f"{path}, line {line}"), str(info.value)
    assert words in str(info.value)


def test_refused_before_any_port_opens(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # Ports that do not exist: opening one would be a device error (exit 3), not a usage error.
    ports = ["--port", "/dev/nonexistent-unit", "--table-port", "/dev/nonexistent-table"]
    db = ["--db", str(work / "line.sqlite")]
    assert main(["run", "--plan", str(work / "plan.yaml"), *ports, "--serial", "auto", *db]) == 4
    assert "cannot be asked its serial number: give --serial SN" in capsys.readouterr().err
    broken = _plan(work, "{protocol: frame:nowhere.yaml}")
    assert main(["run", "--plan", str(broken), *ports, "--serial", "B-1", *db]) == 4
    assert "nowhere.yaml" in capsys.readouterr().err
    with pytest.raises(SystemExit) as parse_error:  # argparse refuses the option itself
        main(["run", "--plan", str(work / "plan.yaml"), "--protocol", "frame:nowhere.yaml", *ports,
              "--serial", "B-1", *db])
    assert parse_error.value.code == 4 and "nowhere.yaml: does not exist" in capsys.readouterr().err
    assert main(["run-many", "--plan", str(work / "plan.yaml"), *ports, *db]) == 4
    assert "give one --serial per --port" in capsys.readouterr().err
    assert not (work / "line.sqlite").exists()


def test_the_python_api_refuses_a_run_it_cannot_name(work: Path) -> None:
    from station.factory.run import RunRequest
    from station.factory.unit import run_unit

    plan = load_plan(work / "plan.yaml")
    with pytest.raises(StationError, match="give --serial SN"):
        run_unit(RunRequest(plan=plan, port="/dev/nonexistent-unit", table_port="/dev/nonexistent-table"))


def test_a_whole_run_of_a_frame_described_unit(work: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The simulated unit streams the description's frames (nothing native on the line); its clock
    # runs 3x real time. The station asks it nothing, reads its frames, and calibrates from them.
    code = main(["run", "--plan", str(work / "plan.yaml"), "--simulate", "--seed", "31", "--speed", "3",
                 "--serial", "B-0031", "--db", str(work / "line.sqlite"), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err[-3000:]
    record = json.loads(out)
    assert record["outcome"] == "PASS" and record["serial"] == "B-0031"
    assert record["device"]["protocol"] == "frame:acme-imu-v2"  # the description's name, not its file
    assert record["device"]["rate_hz"] == 200
    with RecordStore.open(work / "line.sqlite") as store:
        (stored,) = store.query()
    m = stored.measurements()
    assert m["device.serial"].value == "B-0031" and m["device.serial"].outcome == "UNSET"
    assert m["sequence.steps_accepted"].value == 9
    assert m["link.lost_fraction"].value == 0.0
    capture = read_capture(Path(stored.files_dir) / "capture.csv")
    assert [label for label, _ in capture.segments()] == ["+x", "-x", "+y", "-y", "+z", "-z", "rot+x",
                                                            "rot+y", "rot+z"]
    assert abs(1.0 / float(sorted(capture.t[1:] - capture.t[:-1])[len(capture) // 2]) - 200.0) < 1.0


def test_run_many_gives_each_unit_the_protocol_chosen(work: Path, capsys: pytest.CaptureFixture[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    # A native plan, the protocol chosen on the command line relative to the working folder: every
    # child process (started by run-many) reads the unit through the same description.
    monkeypatch.chdir(work)
    _plan(work, "{rate_hz: 100}")
    code = main(["run-many", "--plan", "other.yaml", "--protocol", "frame:acme.yaml", "--simulate", "1",
                 "--seed", "32", "--speed", "3", "--db", "many.sqlite", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err[-3000:]
    (unit,) = json.loads(out)["units"]
    assert unit["outcome"] == "PASS"
    assert unit["record"]["device"] == {"port": unit["record"]["device"]["port"], "serial": "SIM-000032",
                                        "protocol": "frame:acme-imu-v2", "rate_hz": 200}
