"""Every capture names its unit (issue 31): the capture CSV's ``# key: value`` metadata lines are written
by every CSV writer and read into ``Capture.device``; a capture that names no unit is refused by a
parameter file that names one unless ``--serial`` or ``--replace`` says what to do; a capture CSV whose
last line was cut by a power loss is read without it, with a warning."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_mag_acquisition import make_mag_samples, make_samples

from mocks import register_sim_url
from mocks.rig import sequence_segments, simulate
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture import Capture, read_capture
from station.acquisition.capture_csv import CsvCaptureWriter, read_csv, write_csv
from station.acquisition.port_capture import capture_to_file
from station.errors import InputFileError, InputFileWarning
from station.export.params.file import UnitMismatchError, merge_sections, name_unit, open_for_unit


def _metadata(path: Path) -> dict[str, str]:
    out = {}
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        key, _, value = line[1:].partition(":")
        out[key.strip()] = value.strip()
    return out


@pytest.fixture(scope="module")
def units(tmp_path_factory):
    """Two units' turntable captures as CSV (with metadata, as the station writes them) and one bare."""
    folder = tmp_path_factory.mktemp("units")
    a, b = UnitTruth.random(51), UnitTruth.random(52)
    poses = sequence_segments("twelve-position", True, hold_s=6.0)
    out = {"serial_a": a.serial, "serial_b": b.serial}
    for name, truth, seed in (("a", a, 1), ("b", b, 2)):
        write_csv(folder / f"{name}.csv", simulate(truth, poses, rate_hz=100.0, seed=seed).to_capture())
        out[name] = folder / f"{name}.csv"
    # the same capture of unit A as a CSV from elsewhere: no metadata lines
    bare = folder / "a-bare.csv"
    bare.write_text("".join(line for line in out["a"].read_text().splitlines(keepends=True)
                            if not line.startswith("#")))
    out["bare"] = bare
    return out


def test_write_csv_names_the_unit_and_read_csv_reads_it(units) -> None:
    meta = _metadata(units["a"])
    assert list(meta)[:6] == ["serial", "model", "firmware", "protocol", "rate_hz", "created"]
    assert meta["serial"] == units["serial_a"] and meta["rate_hz"] == "100.0"
    assert meta["created"].endswith("Z")
    cap = read_csv(units["a"])
    assert cap.device["serial"] == units["serial_a"] and cap.device["rate_hz"] == 100
    assert "protocol" not in cap.device  # written empty: unknown
    assert read_csv(units["bare"]).device == {}


def test_a_live_csv_capture_names_the_unit_and_protocol(tmp_path) -> None:
    register_sim_url()
    path = tmp_path / "live.csv"
    result = capture_to_file("sim://?seed=5&rate=200", path, duration_s=0.2, err=io.StringIO())
    assert result.error is None
    meta = _metadata(path)
    cap = read_capture(path)
    assert meta["serial"] and cap.device["serial"] == meta["serial"] and cap.device["protocol"] == "native"
    assert cap.device["rate_hz"] == 200 and len(cap) == 40


def test_metadata_survive_a_field_that_comes_late_and_stay_one_line(tmp_path) -> None:
    path = tmp_path / "late.csv"
    w = CsvCaptureWriter(path, device={"serial": "SN-1\n0,1,2,3,4,5,6", "model": "m"}, protocol="xsens")
    w.write(make_samples(3))
    w.write(make_mag_samples(2, first_seq=3))  # the file is rewritten with mx, my, mz
    w.close()
    cap = read_csv(path)
    assert cap.device["serial"] == "SN-1\\x0a0,1,2,3,4,5,6" and cap.device["protocol"] == "xsens"
    assert len(cap) == 5 and cap.mag is not None
    assert path.read_text().count("#") == 6


def test_metadata_lines_shift_the_line_numbers_of_errors(tmp_path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("# serial: X\n# note without a colon\nt,ax,ay,az,gx,gy,gz\n0,1,2,3,4,5,6\n"
                    "0.1,1,2,x,4,5,6\n0.2,1,2,3,4,5,6\n")
    with pytest.raises(InputFileError, match=r"line 5, column 'az'"):
        read_csv(path)
    path.write_text("# serial: X\nt,ax,ay,az,gx,gy\n")
    with pytest.raises(InputFileError, match=r"line 2, column 'gz'"):
        read_csv(path)


def test_csv_into_another_units_file_is_refused(units, tmp_path, capsys) -> None:
    """The issue's case: unit A's CSV into unit B's file exited 0 and left B's serial over A's matrices."""
    params = tmp_path / "unit2.yaml"
    assert cli.main(["calibrate", str(units["b"]), "--method", "turntable", "-o", str(params)]) == 0
    capsys.readouterr()
    before = params.read_bytes()
    assert cli.main(["calibrate", str(units["a"]), "--method", "turntable", "-o", str(params)]) == 4
    err = capsys.readouterr().err
    assert units["serial_a"] in err and units["serial_b"] in err and params.read_bytes() == before


def test_a_capture_naming_no_unit_needs_serial_or_replace(units, tmp_path, capsys) -> None:
    params = tmp_path / "unit.yaml"
    assert cli.main(["calibrate", str(units["a"]), "--method", "turntable", "-o", str(params)]) == 0
    capsys.readouterr()
    before = params.read_bytes()
    for argv in (["calibrate", str(units["bare"]), "--method", "turntable"], ["allan", str(units["bare"])],
                 ["thermal", str(units["bare"])]):
        assert cli.main([*argv, "-o", str(params)]) == 4, argv
        err = capsys.readouterr().err
        assert f"--serial {units['serial_a']}" in err and "--replace" in err and "name no unit" in err, err
        assert params.read_bytes() == before
    # the operator's --serial must not contradict what the capture says
    assert cli.main(["calibrate", str(units["b"]), "--method", "turntable", "-o", str(params),
                     "--serial", units["serial_a"]]) == 4
    assert "--serial" in capsys.readouterr().err and params.read_bytes() == before
    assert cli.main(["calibrate", str(units["bare"]), "--method", "turntable", "-o", str(params),
                     "--serial", units["serial_a"]]) == 0
    data = yaml.safe_load(params.read_text())
    assert data["device"]["serial"] == data["sources"]["accel"]["serial"] == units["serial_a"]
    assert cli.main(["calibrate", str(units["bare"]), "--method", "turntable", "-o", str(params),
                     "--replace"]) == 0
    assert yaml.safe_load(params.read_text())["device"] == {}
    # a file that names no unit takes a capture that names none, as before
    fresh = tmp_path / "fresh.yaml"
    assert cli.main(["calibrate", str(units["bare"]), "--method", "turntable", "-o", str(fresh)]) == 0


def test_library_rules_for_a_unit_not_named(tmp_path) -> None:
    path = tmp_path / "unit.yaml"
    merge_sections(path, {"serial": "SN-1"}, {"noise": {"accel": {"N": [1e-3] * 3}}})
    with pytest.raises(UnitMismatchError, match="--serial SN-1"):
        open_for_unit(path, {"model": "m"})
    with pytest.raises(UnitMismatchError) as info:  # a TUI's own key, and no --serial to offer
        merge_sections(path, {}, {"noise": {"gyro": {"N": [1e-4] * 3}}}, option="press r")
    assert "press r" in str(info.value) and "--serial" not in str(info.value)
    assert open_for_unit(path, None, unit_pending=True).device == {"serial": "SN-1"}  # to be recorded
    with pytest.raises(UnitMismatchError):
        open_for_unit(path, {"serial": "SN-2"}, unit_pending=True)
    assert name_unit({"model": "m"}, "SN-1") == {"model": "m", "serial": "SN-1"}
    assert name_unit({"serial": "SN-1"}, None) == {"serial": "SN-1"}
    with pytest.raises(UnitMismatchError, match="--serial SN-2, but the capture names unit SN-1"):
        name_unit({"serial": "SN-1"}, "SN-2")


def _rows(n: int) -> str:
    return "".join(f"{i * 0.01:.2f},0,0,9.81,0,0,0\n" for i in range(n))


def test_a_last_line_cut_by_a_power_loss_is_dropped_with_a_warning(tmp_path) -> None:
    path = tmp_path / "cut.csv"
    path.write_text("# serial: SN-1\nt,ax,ay,az,gx,gy,gz\n" + _rows(5) + "0.05,0,0,9.8")
    with pytest.warns(InputFileWarning, match=r"cut\.csv, line 8: the last line is cut short"):
        cap = read_csv(path)
    assert len(cap) == 5 and cap.device == {"serial": "SN-1"}
    # a last line without its line end that is whole is a row
    path.write_text("t,ax,ay,az,gx,gy,gz\n" + _rows(5) + "0.05,0,0,9.8,0,0,0")
    assert len(read_csv(path)) == 6
    # a bad line elsewhere is still refused, with its line
    path.write_text("t,ax,ay,az,gx,gy,gz\n" + _rows(2) + "0.02,0,0,9.8\n" + _rows(5)[-14 * 2:])
    with pytest.raises(InputFileError, match=r"line 4"):
        read_csv(path)
    # and so is a cut line that has its line end (not what a cut write leaves)
    path.write_text("t,ax,ay,az,gx,gy,gz\n" + _rows(5) + "0.05,0,0,9.8\n")
    with pytest.raises(InputFileError, match=r"line 7"):
        read_csv(path)


def test_the_cli_prints_the_cut_line_as_one_warning(units, tmp_path, capsys) -> None:
    cut = tmp_path / "cut.csv"
    text = units["a"].read_text()
    cut.write_text(text[: text.rindex("\n") - 40])  # the power went mid-row
    assert cli.main(["calibrate", str(cut), "--method", "turntable", "--json"]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "cut short" in line]
    assert len(lines) == 1 and lines[0].startswith("imu-station calibrate: warning: "), err


def test_apply_keeps_the_unit_of_its_input(units, tmp_path) -> None:
    params = tmp_path / "unit.yaml"
    assert cli.main(["calibrate", str(units["a"]), "--method", "turntable", "-o", str(params)]) == 0
    out = tmp_path / "corrected.csv"
    assert cli.main(["apply", str(params), str(units["a"]), "-o", str(out)]) == 0
    assert read_csv(out).device["serial"] == units["serial_a"]


def test_a_capture_without_device_writes_empty_values(tmp_path) -> None:
    path = tmp_path / "plain.csv"
    write_csv(path, Capture(t=np.arange(3) * 0.01, acc=np.zeros((3, 3)), gyro=np.zeros((3, 3))))
    meta = _metadata(path)
    assert meta["serial"] == "" and meta["protocol"] == "" and read_csv(path).device.keys() == {"created"}
