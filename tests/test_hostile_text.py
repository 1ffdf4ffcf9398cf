"""Nothing from a unit, a plan, a frame description, an instrument or a file name reaches the terminal raw
(issue 32, item 2): every command that prints such data is given the audit's hostile strings (a screen
clear, a terminal title, U+202E, a C1 CSI, Rich markup that fails to parse, a hyperlink to a local
file, a spoofed PASS) and its output, written as to a terminal (``FORCE_COLOR``: Rich styles it and
would emit any hyperlink), holds none of them as a terminal would act on them, and shows them as text.

And the smaller points of item 7: a capture CSV of one endless line, NaN temperatures, hostile frame
descriptions, ``frame guess`` on a constant stream.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from export_params import make_params
from frame_helpers import DATA, SPEC_EXAMPLE
from text_helpers import C1, CLEAR, CONTROL, LINK, RLO, TITLE, raw_attacks, without_styles

from mocks.device import SimDevice
from mocks.instruments.scpi_supply import ScpiSupply, SupplyOutputs
from mocks.instruments.serving import ByteServer
from mocks.pty_server import PtyServer
from mocks.truth import UnitTruth
from station import cli
from station.acquisition import capture_csv
from station.common.text import printable

HEADER = "t,ax,ay,az,gx,gy,gz,temp\n"
CONTROLS_TEXT = f"{CLEAR}{TITLE}{RLO}{C1}"


@pytest.fixture
def terminal(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> Iterator[object]:
    """Run ``imu-station ARGV`` here with Rich writing as to a terminal (styles, live progress);
    returns the exit code and everything written."""
    monkeypatch.setenv("FORCE_COLOR", "1")
    monkeypatch.setenv("COLUMNS", "400")
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)  # progress lines drawn, as on a terminal

    def run(*argv: str) -> tuple[int, str]:
        capsys.readouterr()
        code = cli.main(list(argv))
        out, err = capsys.readouterr()
        return code, out + err

    yield run


def assert_inert(text: str, *shown: str) -> None:
    """No hostile sequence as a terminal takes it, no control character but Rich's own styling, and
    each of ``shown`` (the hostile text as the station escapes it) present as text."""
    assert not raw_attacks(text), repr(text[-3000:])
    plain = without_styles(text)
    assert not CONTROL.search(plain), repr(plain[-3000:])
    flat = " ".join(plain.split())
    for expected in shown:
        assert " ".join(expected.split()) in flat, (expected, plain[-3000:])


def hostile_folder(tmp_path: Path) -> Path:
    """A folder whose path spells ``[link=file:/etc/passwd]x[/`` (a file in it starts ``link]...``):
    a file name cannot hold ``/``, a path can."""
    folder = tmp_path / "[link=file:" / "etc" / "passwd]x["
    folder.mkdir(parents=True)
    return folder


def hostile_file(tmp_path: Path, suffix: str) -> Path:
    """A file name with every control attack, the hyperlink, a spoofed PASS and a tag left open."""
    return hostile_folder(tmp_path) / f"link]{CONTROLS_TEXT}[reverse]PASS[bold]{suffix}"


def small_capture(path: Path, rows: int = 400, temp: float = 25.0) -> Path:
    t = np.arange(rows) / 100.0
    with path.open("w", encoding="utf-8") as fh:
        fh.write(HEADER)
        for k in t:
            fh.write(f"{k:.2f},0.01,-0.02,9.81,0.001,-0.002,0.003,{temp}\n")
    return path


# ---- item 2: every command that prints what it was given -------------------------------------------------
def test_a_usage_error_escapes_the_argument_it_repeats(capsys: pytest.CaptureFixture[str]) -> None:
    argument = f"--nonsense{CONTROLS_TEXT}"
    with pytest.raises(SystemExit) as ended:
        cli.main(["allan", "x.csv", argument])
    assert ended.value.code == 4
    err = capsys.readouterr().err
    assert "unrecognized arguments" in err
    assert_inert(err, printable(argument))




def test_capture_escapes_the_units_markup_and_the_file_name(tmp_path: Path, terminal) -> None:
    truth = dataclasses.replace(UnitTruth.random(5), serial=f"SN{LINK}[/]", model="[reverse]PASS[/]",
                                firmware=f"1.0{CONTROLS_TEXT}")
    out = hostile_file(tmp_path, ".csv")
    with PtyServer(SimDevice(truth, seed=5, rate_hz=100), block_s=0.02) as server:
        code, text = terminal("capture", "--port", server.port_path, "--duration", "0.5", "-o", str(out))
    assert code == 0, text
    assert_inert(text, printable(truth.serial), printable(truth.model), printable(truth.firmware),
                 printable(out, 4096))


def test_frame_check_escapes_the_descriptions_name_and_the_file_name(tmp_path: Path, terminal) -> None:
    doc = yaml.safe_load((Path(cli.__file__).parent / "frames" / "mpu6050_dump.yaml").read_text())
    doc["name"] = f"{LINK}[reverse]PASS[/]"  # printable, so a valid name: it is markup that must not render
    desc = tmp_path / "board.yaml"
    desc.write_text(yaml.safe_dump(doc), encoding="utf-8")
    raw = hostile_file(tmp_path, ".bin")
    raw.write_bytes((DATA / "mpu6050_dump.bin").read_bytes())
    code, text = terminal("frame", "check", str(desc), "--file", str(raw))
    assert code == 0, text
    assert_inert(text, doc["name"], printable(raw, 4096))


def test_frame_guess_escapes_the_file_name_in_its_yaml(tmp_path: Path, terminal) -> None:
    raw = hostile_file(tmp_path, ".bin")
    raw.write_bytes((DATA / "mpu6050_dump.bin").read_bytes())
    code, text = terminal("frame", "guess", str(raw))
    assert code == 0, text
    assert_inert(text, printable(raw, 4096))


def test_frame_descriptions_refusals_escape_and_cut_what_the_file_holds(tmp_path: Path, terminal) -> None:
    cases = {"name": f"n{CONTROLS_TEXT}{LINK}", "schema": f"x{CONTROLS_TEXT}", "colour": 1}
    for key, value in cases.items():
        path = hostile_file(tmp_path / key, ".yaml")
        doc = {**SPEC_EXAMPLE, key: value}
        if key == "colour":  # an unknown key: the key itself is echoed
            doc = {**SPEC_EXAMPLE, f"k{CONTROLS_TEXT}": 1}
        path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
        code, text = terminal("frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin"))
        assert code == 4, text
        assert_inert(text, printable(path, 4096))


@pytest.mark.parametrize("command", ["calibrate", "allan", "thermal"])
def test_engine_commands_escape_the_file_name_in_their_errors(tmp_path: Path, terminal, command: str) -> None:
    bad = hostile_file(tmp_path, ".csv")
    bad.write_text("t,ax\n1,2\n", encoding="utf-8")  # lacks columns: refused naming the file
    argv = [command, str(bad)] + (["-o", str(tmp_path / "p.yaml")] if command != "allan" else [])
    code, text = terminal(*argv)
    assert code == 4, text
    assert_inert(text, printable(bad, 4096))


def test_apply_escapes_its_file_names_in_progress_and_summary(tmp_path: Path, terminal) -> None:
    params = tmp_path / "unit.yaml"
    make_params(seed=1, thermal=False).save(params)
    capture = small_capture(hostile_file(tmp_path, ".csv"))
    out = capture.with_name(capture.name + "-out.csv")
    code, text = terminal("apply", str(params), str(capture), "-o", str(out))
    assert code == 0, text
    assert_inert(text, printable(out, 4096))


def test_instrument_escapes_what_the_instrument_replies(terminal) -> None:
    identity = f"ACME,PSU{CLEAR}{TITLE}{C1}{LINK}[reverse]PASS[/],1"  # the emulator speaks latin-1: no U+202E
    server = ByteServer(ScpiSupply(SupplyOutputs(), identity=identity), "tcp").start()
    try:
        code, text = terminal("instrument", f"scpi://{server.address}")
    finally:
        server.stop()
    assert code == 0, text
    assert_inert(text, printable(identity))


def test_plan_errors_escape_and_cut_a_limit_key(tmp_path: Path, terminal) -> None:
    key = f"gyro.bias{CONTROLS_TEXT}{LINK}" + "x" * 60_000
    plan = hostile_file(tmp_path, ".yaml")
    # a key above 1024 characters is an explicit one (?), its JSON string a YAML one
    plan.write_text(f"schema: imu-station/plan/1\nname: p\nsequence: {{name: six-position}}\n"
                    f"limits:\n  ? {json.dumps(key)}\n  : {{max_abs: 1}}\n", encoding="utf-8")
    code, text = terminal("run", "--plan", str(plan), "--simulate", "--serial", "auto", "--db",
                          str(tmp_path / "r.sqlite"))
    assert code == 4, text
    assert_inert(text, printable(plan, 4096), "unknown quantity")
    assert len(text) < 10_000  # the 60,000-character key is cut, not echoed


def test_a_whole_run_shows_a_hostile_serial_station_and_plan_name_as_text(tmp_path: Path, terminal) -> None:
    plan = tmp_path / "plan.yaml"
    name = f"line{LINK}{CONTROLS_TEXT}[reverse]PASS[/]"
    plan.write_text(f"schema: imu-station/plan/1\nname: {json.dumps(name)}\n"
                    "sequence: {name: six-position}\n", encoding="utf-8")
    serial, station = f"SN{CONTROLS_TEXT}[/]", f"st[/]{CONTROLS_TEXT}{LINK}"
    code, text = terminal("run", "--plan", str(plan), "--simulate", "--speed", "10", "--serial", serial,
                          "--station", station, "--db", str(tmp_path / "r.sqlite"), "--files",
                          str(tmp_path / "files"))
    assert code == 0, text
    assert_inert(text, printable(serial), "outcome PASS")
    code, text = terminal("records", "--db", str(tmp_path / "r.sqlite"))
    assert code == 0, text
    assert_inert(text, printable(station)[:20], printable(name)[:20])


# ---- item 7: the capture CSV's bound, NaN refusals -------------------------------------------------------


def test_a_capture_csv_of_one_endless_line_is_refused_naming_the_line(tmp_path: Path, terminal) -> None:
    path = tmp_path / "endless.csv"
    with path.open("w", encoding="utf-8") as fh:
        fh.write(HEADER + "0.0,1,2,3,4,5,6,7\n")
        fh.write("1" * (4 * capture_csv.MAX_LINE_CHARS))  # no end in sight
    for argv in (["allan", str(path)], ["thermal", str(path), "-o", str(tmp_path / "p.yaml")],
                 ["calibrate", str(path), "-o", str(tmp_path / "p.yaml")]):
        code, text = terminal(*argv)
        assert code == 4, text
        assert f"{path}, line 3: line is longer than {capture_csv.MAX_LINE_CHARS} characters" in text, text


def test_an_endless_line_costs_the_bound_not_its_length(tmp_path: Path) -> None:
    path = tmp_path / "endless.csv"
    with path.open("w", encoding="utf-8") as fh:
        fh.write(HEADER)
        for _ in range(50):  # 50 MB in one line
            fh.write("9" * 1_000_000)
    import tracemalloc

    # a file this long goes to the compiled parse first: its one-time load (numba, tens of MB of Python
    # objects) is not what the line costs
    with pytest.raises(Exception, match="line 2: line is longer"):
        list(capture_csv.iter_csv_chunks(path))
    tracemalloc.start()
    with pytest.raises(Exception, match="line 2: line is longer"):
        list(capture_csv.iter_csv_chunks(path))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 2 * capture_csv._BATCH * capture_csv.MAX_LINE_CHARS < 10_000_000, peak


def test_rows_of_ordinary_length_read_across_the_character_bound(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(capture_csv, "CHUNK_CHARS", 5_000)  # chunks end by characters, not rows
    path = small_capture(tmp_path / "c.csv", rows=3000)
    chunks = list(capture_csv.iter_csv_chunks(path))
    assert len(chunks) > 3 and sum(len(c) for c in chunks) == 3000
    assert np.all(np.diff(np.concatenate([c.t for c in chunks])) > 0)


def test_thermal_refuses_a_nan_temperature_naming_line_and_column(tmp_path: Path, terminal) -> None:
    path = small_capture(tmp_path / "sweep.csv")
    lines = path.read_text().splitlines(keepends=True)
    lines[7] = lines[7].rsplit(",", 1)[0] + ",nan\n"
    path.write_text("".join(lines))
    code, text = terminal("thermal", str(path), "-o", str(tmp_path / "p.yaml"))
    assert code == 4, text
    assert f"{path}, line 8, column 'temp': value nan is not a finite number" in text, text


def test_apply_refuses_a_nan_row_its_thermal_section_would_use(tmp_path: Path, terminal) -> None:
    params = tmp_path / "unit.yaml"
    make_params(seed=1).save(params)
    path = small_capture(tmp_path / "in.csv")
    lines = path.read_text().splitlines(keepends=True)
    lines[12] = lines[12].rsplit(",", 1)[0] + ",nan\n"
    path.write_text("".join(lines))
    code, text = terminal("apply", str(params), str(path), "-o", str(tmp_path / "out.csv"))
    assert code == 4, text
    assert f"{path}, line 13, column 'temp': value nan is not a finite number" in text, text
    assert not (tmp_path / "out.csv").exists()


# ---- item 7: frame descriptions and frame guess ----------------------------------------------------------


def _description(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "board.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_key_given_twice_is_refused_at_its_second_line(tmp_path: Path, terminal) -> None:
    text = yaml.safe_dump(SPEC_EXAMPLE, sort_keys=False)
    path = _description(tmp_path, text + "length: 99\n")
    code, out = terminal("frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin"))
    assert code == 4
    line = len(text.splitlines()) + 1
    first = next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith("length:"))
    assert f"{path}, line {line}, column 'length': key given twice (first on line {first})" in out, out


@pytest.mark.parametrize("rate", [1e-300, 0.01, 200_000, 1e300])
def test_an_absurd_rate_is_refused(tmp_path: Path, terminal, rate: float) -> None:
    doc = {**SPEC_EXAMPLE, "rate_hz": rate}
    path = _description(tmp_path, yaml.safe_dump(doc))
    code, out = terminal("frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin"))
    assert code == 4 and "key 'rate_hz'" in out and "0.1 to 100000 Hz" in out, out


def test_a_huge_name_is_not_echoed_whole(tmp_path: Path, terminal) -> None:
    path = _description(tmp_path, yaml.safe_dump({**SPEC_EXAMPLE, "name": "N" * 60_000}))
    code, out = terminal("frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin"))
    assert code == 4 and "give a printable name of up to 64 characters" in out, out[:500]
    assert len(out) < 1000


@pytest.mark.parametrize(("raw", "says"), [(bytes(8192), "every byte is 0x00: the stream is constant"),
                                           (bytes(range(32)) * 256, "repeat exactly every 32 bytes")])
def test_frame_guess_on_data_that_never_varies(tmp_path: Path, terminal, raw: bytes, says: str) -> None:
    path = tmp_path / "raw.bin"
    path.write_bytes(raw)
    code, out = terminal("frame", "guess", str(path))
    assert code == 4 and says in out and "no byte holds its value" not in out, out
