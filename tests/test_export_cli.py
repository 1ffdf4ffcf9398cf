"""``imu-station export`` through ``station.cli.main``: every format written, read back, reported;
bad input refused with a message naming what to fix."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from export_params import make_params

from station.cli import main
from station.export.firmware.blob import parse_blob
from station.export.params.file import ParamsFile


@pytest.fixture
def unit_file(tmp_path: Path) -> Path:
    path = tmp_path / "unit.yaml"
    make_params(seed=7).save(path)
    return path


def test_c_export_writes_three_files_atomically(unit_file: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "fw"
    assert main(["export", str(unit_file), "--format", "c", "-o", str(out), "--station-id", "line-2"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["imu_calib.bin", "imu_calib.c", "imu_calib.h"]
    back = parse_blob((out / "imu_calib.bin").read_bytes())
    params = ParamsFile.load(unit_file)
    assert back.station_id == "line-2" and back.serial == "SN-0042"
    assert np.allclose(back.accel.bias, params.accel.bias, rtol=1e-6)
    assert "#define IMU_CALIB_STATION_ID \"line-2\"" in (out / "imu_calib.h").read_text()
    assert "wrote" in capsys.readouterr().out


def test_source_date_epoch_makes_exports_reproducible(unit_file: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1795000000")
    for name in ("a", "b"):
        argv = ["export", str(unit_file), "-f", "c", "-o", str(tmp_path / name), "--station-id", "s"]
        assert main(argv) == 0
    for name in ("imu_calib.h", "imu_calib.c", "imu_calib.bin"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert parse_blob((tmp_path / "a" / "imu_calib.bin").read_bytes()).exported_utc == 1795000000


@pytest.mark.parametrize("fmt", ["json", "yaml"])
def test_document_formats_read_back_as_the_parameter_file(fmt: str, unit_file: Path, tmp_path: Path) -> None:
    out = tmp_path / f"exported.{fmt}"  # not onto unit.yaml itself: export refuses that
    assert main(["export", str(unit_file), "-f", fmt, "-o", str(out), "--station-id", "s"]) == 0
    text = out.read_text()
    doc = json.loads(text) if fmt == "json" else yaml.safe_load(text)
    assert doc["export"]["station_id"] == "s"
    back = ParamsFile.from_dict(doc, out)
    params = ParamsFile.load(unit_file)
    assert np.array_equal(back.gyro.matrix, params.gyro.matrix)
    assert np.array_equal(back.thermal.accel.segments[2].coeffs, params.thermal.accel.segments[2].coeffs)


def test_bin_into_a_directory_gets_the_default_name(unit_file: Path, tmp_path: Path, capsys) -> None:
    argv = ["export", str(unit_file), "-f", "bin", "-o", str(tmp_path), "--station-id", "assembly-line-12"]
    assert main(argv) == 0
    back = parse_blob((tmp_path / "imu_calib.bin").read_bytes())
    assert back.serial == "SN-0042" and back.station_id == "assembly-line-1"
    assert "station id is cut to 15 bytes" in capsys.readouterr().out


@pytest.mark.parametrize(("fmt", "first"), [("px4", "CAL_ACC1_ID"), ("ardupilot", "INS_ACC2_ID")])
def test_autopilot_formats_report_limitations_in_json(fmt: str, first: str, unit_file: Path, tmp_path: Path,
                                                      capsys) -> None:
    out = tmp_path / "unit.params"
    argv = ["export", str(unit_file), "-f", fmt, "-o", str(out), "--device-id", "0x140109", "--instance", "1",
            "--json"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["files"] == [str(out)] and report["target"] == fmt
    assert report["parameters"][first] == 0x140109
    whats = {(lim["triad"], lim["what"]) for lim in report["limitations"]}
    assert {("accel", "misalignment"), ("gyro", "scale and misalignment"), ("accel", "dT terms"),
            ("gyro", "thermal model as one cubic")} <= whats
    assert len(report["pose_errors"]["accel"]["at_reference"]) == 6
    assert first in out.read_text()


def test_text_report_names_the_losses_and_plots_them(unit_file: Path, tmp_path: Path, capsys) -> None:
    png = tmp_path / "loss.png"
    argv = ["export", str(unit_file), "-f", "px4", "-o", str(tmp_path / "u.params"), "--plot", str(png)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "what px4 cannot hold" in text and "misalignment" in text and "no --device-id" in text
    assert f"wrote {png}" in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


@pytest.mark.parametrize(("argv", "message"), [
    (["-f", "c", "-o", "{tmp}/x"], "does not exist"),
    (["-f", "px4", "-o", "{tmp}/x", "--instance", "9"], "--instance"),
])
def test_missing_file_and_bad_instance(argv: list[str], message: str, tmp_path: Path, unit_file: Path,
                                       capsys) -> None:
    params = str(tmp_path / "absent.yaml") if message == "does not exist" else str(unit_file)
    assert main(["export", params, *[a.format(tmp=tmp_path) for a in argv]]) == 4
    assert message in capsys.readouterr().err


def test_empty_parameter_file_and_file_as_directory(tmp_path: Path, unit_file: Path, capsys) -> None:
    empty = tmp_path / "empty.yaml"
    ParamsFile().save(empty)
    assert main(["export", str(empty), "-f", "bin", "-o", str(tmp_path / "x.bin")]) == 4
    assert "nothing to export" in capsys.readouterr().err
    a_file = tmp_path / "file"
    a_file.write_text("")
    assert main(["export", str(unit_file), "-f", "c", "-o", str(a_file)]) == 4
    assert "is a file" in capsys.readouterr().err


def test_bad_device_id_is_a_usage_error(unit_file: Path, tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["export", str(unit_file), "-f", "px4", "-o", str(tmp_path / "u"), "--device-id", "-3"])
    assert exc.value.code == 4
    assert "outside" in capsys.readouterr().err
