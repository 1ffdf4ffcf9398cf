"""Every numeric option of every command refuses a value outside its range: exit 4, one line naming
the option and the allowed range, no traceback. The port and protocol options are the same for
every command that opens a unit (station/console/options.py)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from station import cli

# A range as the messages say it: 1..65535, above 0 up to 20, at least 10, in [0, 1], a fraction in [0, 1).
RANGE = re.compile(r"-?[0-9.e+]+\.\.-?[0-9]|above -?[0-9]|at least [0-9]|at most [0-9]|\[0, 1[])]")

# (command and required arguments, option, bad value); {tmp} is a temporary folder.
CASES = [
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--baud", "99999999999"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--baud", "-9600"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--rate", "0"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--rate", "70000"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--duration", "0"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--duration", "inf"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--field", "0"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--field", "nan"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--instances", "256"),
    (["capture", "--port", "/dev/null-imu", "-o", "{tmp}/x.csv"], "--instances", "0,-1"),
    (["tui"], "--hold", "0"),
    (["tui"], "--hold", "1e9"),
    (["tui"], "--rotation-rate", "-90"),
    (["tui"], "--rotation-rate", "5000"),
    (["tui"], "--allan-minutes", "0"),
    (["tui"], "--seed", "-1"),
    (["tui"], "--rate", "0"),
    (["tui"], "--rate", "1e6"),
    (["tui"], "--speed", "0"),
    (["tui"], "--speed", "101"),
    (["tui"], "--supply-volts", "-1"),
    (["tui"], "--supply-amps", "1e6"),
    (["tui"], "--supply-max-v", "-5"),
    (["tui"], "--supply-max-a", "nan"),
    (["tui"], "--supply-off", "0"),
    (["tui"], "--table-max-rate", "0"),
    (["tui"], "--table-max-rate", "5000"),
    (["tui"], "--table-accel", "-10"),
    (["tui"], "--table-accel", "1e9"),
    (["demo", "--out", "{tmp}/demo"], "--seconds", "0"),
    (["demo", "--out", "{tmp}/demo"], "--rate", "0"),
    (["demo", "--out", "{tmp}/demo"], "--seed", "-1"),
    (["demo", "--out", "{tmp}/demo"], "--hold", "-1"),
    (["demo", "--out", "{tmp}/demo"], "--speed", "1000"),
    (["simulate"], "--seed", "-1"),
    (["simulate"], "--rate", "0"),
    (["simulate"], "--speed", "0"),
    (["simulate"], "--duration", "-5"),
    (["simulate", "--scenario", "chamber", "--log-format", "ulog", "-o", "{tmp}/x.ulg"], "--rate", "5000"),
    (["simulate", "--scenario", "chamber", "--log-format", "dataflash", "-o", "{tmp}/x.bin"], "--rate", "0"),
    (["calibrate", "{tmp}/absent.csv"], "--gravity", "5"),
    (["calibrate", "{tmp}/absent.csv"], "--latitude", "100"),
    (["calibrate", "{tmp}/absent.csv"], "--height", "1e7"),
    (["calibrate", "{tmp}/absent.csv"], "--initial-still", "0"),
    (["calibrate", "{tmp}/absent.csv"], "--window", "0"),
    (["calibrate", "{tmp}/absent.csv"], "--rate", "-200"),
    (["calibrate", "{tmp}/absent.csv"], "--field", "0"),
    (["calibrate", "{tmp}/absent.csv"], "--field", "nan"),
    (["calibrate", "{tmp}/absent.csv"], "--longitude", "200"),
    (["allan", "{tmp}/absent.csv"], "--horizon", "0"),
    (["allan", "{tmp}/absent.csv"], "--gm-rate", "0"),
    (["allan", "{tmp}/absent.ulg"], "--instance", "-1"),
    (["thermal", "{tmp}/absent.ulg", "-o", "{tmp}/p.yaml"], "--instance", "256"),
    (["calibrate", "{tmp}/absent.bin"], "--instance", "-1"),
    (["apply", "{tmp}/absent.yaml", "{tmp}/absent.ulg", "-o", "{tmp}/x.csv"], "--instance", "1000"),
    (["report", "{tmp}/absent.yaml", "-o", "{tmp}/x.html"], "--instance", "-2"),
    (["instrument", "scpi://127.0.0.1:9"], "--setpoint", "500"),
    (["instrument", "scpi://127.0.0.1:9"], "--gradient", "-1"),
    (["instrument", "scpi://127.0.0.1:9"], "--position", "1e5"),
    (["instrument", "scpi://127.0.0.1:9"], "--rate", "nan"),
    (["instrument", "scpi://127.0.0.1:9"], "--axis", "4"),
    (["instrument", "scpi://127.0.0.1:9"], "--voltage", "-1"),
    (["instrument", "scpi://127.0.0.1:9"], "--current", "1000"),
    (["instrument", "scpi://127.0.0.1:9"], "--min-c", "-300"),
    (["instrument", "scpi://127.0.0.1:9"], "--max-c", "inf"),
    (["instrument", "scpi://127.0.0.1:9"], "--max-rate", "-5"),
    (["instrument", "scpi://127.0.0.1:9"], "--max-v", "2000"),
    (["instrument", "scpi://127.0.0.1:9"], "--max-a", "-0.1"),
    (["characterise", "{tmp}/absent.csv"], "--supply-volts", "-1"),
    (["characterise", "{tmp}/absent.csv"], "--supply-amps", "1e6"),
    (["characterise", "{tmp}/absent.csv"], "--supply-max-v", "-5"),
    (["characterise", "{tmp}/absent.csv"], "--supply-max-a", "nan"),
    (["characterise", "{tmp}/absent.csv"], "--supply-off", "-1"),
    (["characterise", "{tmp}/absent.csv"], "--baud", "-9600"),
    (["characterise", "{tmp}/absent.csv"], "--turn-ons", "2"),
    (["characterise", "{tmp}/absent.csv"], "--still", "0"),
    (["characterise", "{tmp}/absent.csv"], "--hold", "0"),
    (["characterise", "{tmp}/absent.csv"], "--level", "1.5"),
    (["allan", "{tmp}/absent.csv"], "--rate", "0"),
    (["allan", "{tmp}/absent.csv"], "--max-missing", "1"),
    (["allan", "{tmp}/absent.csv"], "--per-decade", "5"),
    (["allan", "{tmp}/absent.csv"], "--per-decade", "100000"),
    (["allan", "{tmp}/absent.csv"], "--inflate", "0.5"),
    (["allan", "{tmp}/absent.csv"], "--inflate", "1001"),
    (["allan", "{tmp}/absent.csv"], "--ekf-rate", "0"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--segments", "0"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--segments", "65"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--max-segments", "0"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--joins", "20,1000"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--reference-temp", "-300"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--tau", "0"),
    (["thermal", "{tmp}/absent.csv", "-o", "{tmp}/p.yaml"], "--gravity", "0.5"),
    (["export", "{tmp}/absent.yaml", "-f", "px4", "-o", "{tmp}/x"], "--device-id", "-3"),
    (["export", "{tmp}/absent.yaml", "-f", "px4", "-o", "{tmp}/x"], "--gyro-device-id", "4294967296"),
    (["export", "{tmp}/absent.yaml", "-f", "px4", "-o", "{tmp}/x"], "--instance", "9"),
    (["export", "{tmp}/absent.yaml", "-f", "ardupilot", "-o", "{tmp}/x"], "--instance", "3"),
    (["export", "{tmp}/absent.yaml", "-f", "c", "-o", "{tmp}/x"], "--instance", "-1"),
    (["export", "{tmp}/absent.yaml", "-f", "ekf2", "-o", "{tmp}/x"], "--inflate", "0.9"),
    (["export", "{tmp}/absent.yaml", "-f", "ekf3", "-o", "{tmp}/x"], "--inflate", "nan"),
    (["export", "{tmp}/absent.yaml", "-f", "ekf2", "-o", "{tmp}/x"], "--ekf-rate", "0"),
    (["export", "{tmp}/absent.yaml", "-f", "ekf3", "-o", "{tmp}/x"], "--ekf-rate", "1e6"),
    (["run", "--plan", "{tmp}/plan.yaml", "--simulate", "--serial", "X"], "--seed", "-1"),
    (["run", "--plan", "{tmp}/plan.yaml", "--simulate", "--serial", "X"], "--unplug-after", "0"),
    (["run", "--plan", "{tmp}/plan.yaml", "--simulate", "--serial", "X"], "--speed", "50"),
    (["run-many", "--plan", "{tmp}/plan.yaml"], "--simulate", "0"),
    (["run-many", "--plan", "{tmp}/plan.yaml"], "--simulate", "65"),
    (["run-many", "--plan", "{tmp}/plan.yaml", "--simulate", "2"], "--seed", "-1"),
    (["run-many", "--plan", "{tmp}/plan.yaml", "--simulate", "2"], "--speed", "0"),
]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    """Exit code and stderr of the CLI, whether argparse exits or the command returns."""
    try:
        code = cli.main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.err


@pytest.mark.parametrize(("base", "option", "value"), CASES,
                         ids=[f"{b[0]} {o} {v}" for b, o, v in CASES])
def test_out_of_range_is_one_line_with_the_range(base: list[str], option: str, value: str, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    argv = [a.format(tmp=tmp_path) for a in base] + [f"{option}={value}"]
    code, err = _run(argv, capsys)
    lines = err.strip().splitlines()
    assert code == 4, err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert option in lines[0] and value in lines[0], lines[0]
    assert RANGE.search(lines[0]), f"no range in: {lines[0]}"
    assert not list(tmp_path.iterdir()), "nothing is written when an option is refused"


def test_every_numeric_option_is_covered() -> None:
    """Each command's int/float options (and those typed by the shared range checks) appear in CASES."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    covered = {(base[0], option) for base, option, _ in CASES}
    missing = []
    for name, command in sub.choices.items():
        for action in command._actions:
            numeric = action.type in (int, float) or getattr(action.type, "__name__", "") in ("int", "float",
                                                                                               "_segments",
                                                                                               "_fraction",
                                                                                               "_joins")
            if numeric and action.option_strings and (name, action.option_strings[-1]) not in covered \
                    and not any((name, o) in covered for o in action.option_strings):
                missing.append(f"{name} {action.option_strings[-1]}")
    assert not missing, f"numeric options without an out-of-range case: {missing}"


@pytest.mark.parametrize("argv", [
    ["capture", "--port", "/dev/null-imu", "--baud", "99999999999", "-o", "x.csv"],
    ["capture", "--port", "/dev/null-imu", "--baud", "-9600", "-o", "x.csv"],
    ["capture", "--port", "/dev/null-imu", "--rate", "0", "-o", "x.csv"],
])
def test_out_of_range_in_a_real_process(argv: list[str], tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "station.cli", *argv], cwd=tmp_path, capture_output=True,
                          text=True, timeout=60)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 4 and len(lines) == 1, proc.stderr
    assert argv[3] in lines[0] and argv[4] in lines[0] and RANGE.search(lines[0]), lines[0]
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("command", [["capture", "--port", "p", "-o", "x.csv"], ["tui"]])
def test_the_same_protocol_option_for_every_command(command: list[str], capsys) -> None:
    parser = cli.build_parser(command[0])
    for protocol in ("native", "auto", "ascii", "ascii:@50", "xsens:hr", "mavlink:SCALED_IMU2"):
        assert parser.parse_args([*command, "--protocol", protocol]).protocol == protocol
    for bad, words in (("nmea", "unknown protocol 'nmea'"), ("native:x", "takes no option"),
                       ("ascii:@0", "must be positive")):
        with pytest.raises(SystemExit) as exc:
            parser.parse_args([*command, "--protocol", bad])
        err = capsys.readouterr().err.strip().splitlines()
        assert exc.value.code == 4 and len(err) == 1 and "--protocol" in err[0] and words in err[0], err


def test_output_has_its_out_alias() -> None:
    for command, dest in ((["capture", "--port", "p"], "output"), (["tui"], "out"),
                          (["demo"], "out"), (["apply", "u.yaml", "in.csv"], "output")):
        parser = cli.build_parser(command[0])
        for flag in ("-o", "--output", "--out"):
            assert str(getattr(parser.parse_args([*command, flag, "f"]), dest)) == "f"


@pytest.mark.parametrize("epoch", ["99999999999999999", "-5", "1e9"])
def test_source_date_epoch_out_of_range(epoch: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """The export date from the environment is range-checked as an option is (it was an OSError)."""
    from station.export.params.file import ParamsFile

    params = tmp_path / "p.yaml"
    ParamsFile().save(params)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", epoch)
    code, err = _run(["export", str(params), "-f", "json", "-o", str(tmp_path / "x.json")], capsys)
    lines = err.strip().splitlines()
    assert code == 4 and len(lines) == 1 and "SOURCE_DATE_EPOCH" in lines[0] and RANGE.search(lines[0]), err
    assert not (tmp_path / "x.json").exists()


@pytest.mark.parametrize(("argv", "words"), [
    (["capture", "--port", "sim://?rate=0", "-o", "{tmp}/x.csv"], "rate"),
    (["capture", "--port", "sim://?seed=-1", "-o", "{tmp}/x.csv"], "seed"),
    (["capture", "--port", "sim://?speed=nan", "-o", "{tmp}/x.csv"], "speed"),
    (["capture", "--port", "sim://?garbage=2", "-o", "{tmp}/x.csv"], "garbage"),
    (["capture", "--port", "/dev/null-imu", "--protocol", "ascii:@1e400", "-o", "{tmp}/x.csv"], "@1e400"),
    (["simulate", "--faults", "stall=0.1,stall_s=-1"], "stall_s"),
    (["simulate", "--faults", "garbage_max=99999999999999999999"], "garbage_max"),
    (["simulate", "--faults", "disconnect_bytes=-5"], "disconnect_after_bytes"),
    (["simulate", "--faults", "disconnect_s=nan"], "disconnect_after_s"),
    (["simulate", "--faults", "seed=-1"], "seed"),
])
def test_numbers_inside_option_values_are_range_checked(argv: list[str], words: str, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """The siblings: numbers inside a sim:// URL, a fault spec or a protocol option (they were
    accepted, or refused with exit 3 once the port failed to open)."""
    code, err = _run([a.format(tmp=tmp_path) for a in argv], capsys)
    lines = err.strip().splitlines()
    assert code == 4 and len(lines) == 1 and words in lines[0] and RANGE.search(lines[0]), err
    assert not list(tmp_path.iterdir())
