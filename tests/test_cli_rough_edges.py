"""The command line's rough edges, each as an operator met it: an export onto its own input, a
capture from a silent port, a mistyped command, the ports of the machine, shell completion, and
a trend plot that leaves measurements out."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from export_params import make_params
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo
from test_factory_records import make_record

from drivers.ports import describe_port, list_serial_ports
from station.cli import main
from station.factory.records import Measurement, RecordStore


def _cli(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "station.cli", *argv], capture_output=True, text=True,
                          timeout=120, cwd=cwd)


def test_export_refuses_to_overwrite_its_own_input(tmp_path, capsys) -> None:
    params = tmp_path / "imu_calib.yaml"
    make_params(seed=3).save(params)
    before = params.read_bytes()
    for output in (params, tmp_path):  # the file itself, or the folder its default name lands in
        assert main(["export", str(params), "-f", "yaml", "-o", str(output)]) == 4
        err = capsys.readouterr().err
        assert "would overwrite the parameter file" in err and str(params) in err
        assert params.read_bytes() == before
    assert main(["export", str(params), "-f", "yaml", "-o", str(tmp_path / "out.yaml")]) == 0


def test_a_silent_port_leaves_no_file_and_says_so(tmp_path) -> None:
    done = _cli("capture", "--port", "loop://", "--duration", "1", "-o", "silent.csv", cwd=tmp_path)
    assert done.returncode == 3
    assert "captured no sample: silent.csv was not written" in done.stdout
    assert "wrote 0 samples" not in done.stdout
    assert not (tmp_path / "silent.csv").exists()


@pytest.mark.parametrize(("argv", "suggestion"), [
    (["calibrat", "x.csv"], "did you mean 'calibrate'?"),
    (["run_many"], "did you mean 'run-many'?"),
    (["export", "u.yaml", "-f", "pxx4", "-o", "x"], "did you mean 'px4'?"),
])
def test_a_mistyped_choice_gets_did_you_mean(argv, suggestion, capsys) -> None:
    with pytest.raises(SystemExit) as usage:
        main(argv)
    assert usage.value.code == 4
    assert suggestion in capsys.readouterr().err


def test_nothing_close_gets_no_suggestion(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["zzzz"])
    assert "did you mean" not in capsys.readouterr().err


def test_ports_lists_what_pyserial_sees() -> None:
    done = _cli("ports", "--json")
    assert done.returncode == 0
    listed = json.loads(done.stdout)
    assert [p["device"] for p in listed] == sorted(p.device for p in list_ports.comports())
    assert [p.as_dict() for p in list_serial_ports()] == listed
    text = _cli("ports")
    assert text.returncode == 0
    assert all(p["device"] in text.stdout for p in listed) or "no serial port found" in text.stdout


def test_a_usb_port_is_described_with_everything_known() -> None:
    info = ListPortInfo("/dev/ttyUSB0", skip_link_detection=True)
    info.description, info.hwid = "FT232R USB UART", "USB VID:PID=0403:6001 SER=A10K LOCATION=1-1.2"
    info.vid, info.pid, info.serial_number = 0x0403, 0x6001, "A10K"
    info.manufacturer, info.product, info.location = "FTDI", "FT232R USB UART", "1-1.2"
    port = describe_port(info)
    assert port.usb_id == "0403:6001"
    assert port.line() == "/dev/ttyUSB0         FT232R USB UART  (FTDI, SN A10K, USB 0403:6001, at 1-1.2)"
    bare = ListPortInfo("/dev/ttyS0", skip_link_detection=True)  # pyserial's "n/a" everywhere
    assert describe_port(bare).as_dict() == {
        "device": "/dev/ttyS0", "description": None, "hwid": None, "vid": None, "pid": None,
        "serial_number": None, "manufacturer": None, "product": None, "location": None, "usb_id": None}


@pytest.mark.parametrize(("words", "expected"), [
    ("imu-station cal", "calibrate"),
    ("imu-station export u.yaml --format p", "px4"),
    ("imu-station calibrate x.csv --me", "--method"),
])
def test_bash_completion_completes_commands_options_and_choices(words, expected, tmp_path) -> None:
    script = tmp_path / "imu-station.bash"
    done = _cli("completion", "bash")
    assert done.returncode == 0
    script.write_text(done.stdout)
    line = words.split()
    shell = (f"source {script}; COMP_WORDS=({words}); COMP_CWORD={len(line) - 1}; "
             f"_shtab_imu_station; printf '%s\\n' \"${{COMPREPLY[@]}}\"")
    got = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, timeout=30, check=True)
    assert got.stdout.split() == [expected]


def test_zsh_completion_names_every_command() -> None:
    done = _cli("completion", "zsh")
    assert done.returncode == 0 and done.stdout.startswith("#compdef imu-station")
    for command in ("calibrate", "run-many", "ports", "completion"):
        assert command in done.stdout


def test_records_plot_says_which_measurements_it_left_out(tmp_path, capsys) -> None:
    db = tmp_path / "line.sqlite"
    with RecordStore.open(str(db)) as store:
        for i, bias in enumerate((0.01, 0.02, 0.7)):
            record = make_record(f"U{i}", f"2026-11-2{i}T08:00:00.000000Z", tmp_path / f"r{i}", bias=bias)
            record.phases[1].measurements.append(Measurement("station.operator", "anna"))
            store.save(record)
    plot = tmp_path / "trend.png"
    assert main(["records", "--db", str(db), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "1 measurement(s) plotted" in out
    left = out[out.index("left out:"):]
    assert "gyro.residual_rms (no limits)" in left and "station.operator (not a number)" in left
    assert "device.serial (not a number)" in left
    assert main(["records", "--db", str(db), "--plot", str(plot), "--measurement", "gyro.residual_rms",
                 "--measurement", "no.such"]) == 0
    out = capsys.readouterr().out
    assert "no.such (in no record)" in out and "gyro.residual_rms (" not in out
