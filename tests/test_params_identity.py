"""One parameter file, one unit: calibrate, allan and thermal refuse another unit's file (exit 4,
untouched) unless --replace, and every section records the capture (path, SHA-256) and unit it came from."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mocks.chamber import ChamberSweep, chamber_sweep, cubic_rate_unit
from mocks.rig import Static, sequence_segments, simulate
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture_h5 import H5CaptureWriter
from station.common.files import sha256_file
from station.errors import InputFileError
from station.export.params.file import (
    ParamsFile,
    UnitMismatchError,
    merge_sections,
    open_for_unit,
    unit_conflict,
)


def _h5(path: Path, recording) -> Path:
    writer = H5CaptureWriter(path, device=recording.truth.device_info(recording.rate_hz), with_step=True)
    writer.write(recording.samples(), step=recording.step)
    writer.close()
    return path


@pytest.fixture(scope="module")
def units(tmp_path_factory):
    """Two units' twelve-position captures and a still record of the first."""
    folder = tmp_path_factory.mktemp("units")
    a, b = UnitTruth.random(41), UnitTruth.random(42)
    assert a.serial != b.serial
    poses = sequence_segments("twelve-position", True, hold_s=6.0)
    return {
        "a": _h5(folder / "a.h5", simulate(a, poses, rate_hz=100.0, seed=1)),
        "b": _h5(folder / "b.h5", simulate(b, poses, rate_hz=100.0, seed=2)),
        "a_still": _h5(folder / "a-still.h5", simulate(a, [Static("+z", 1800.0)], rate_hz=50.0, seed=3)),
        "serial_a": a.serial, "serial_b": b.serial,
    }


def test_unit_conflict_rules() -> None:
    assert unit_conflict({"serial": "A"}, {"serial": "A", "model": "m"}) is None
    assert unit_conflict({"serial": "A"}, {"serial": "B"}) == "A vs B"
    assert unit_conflict({"serial": "A", "model": "m1"}, {"serial": "A", "model": "m2"}) \
        == "A (model m1) vs A (model m2)"
    assert unit_conflict({}, {"serial": "B"}) is None  # a file that never knew its unit
    assert unit_conflict({"serial": "A"}, {}) is None  # a capture that does not say (a bare CSV)


def test_library_refuses_another_unit_and_leaves_the_file(tmp_path) -> None:
    path = tmp_path / "unit.yaml"
    merge_sections(path, {"serial": "SN-1", "model": "m"}, {"noise": {"accel": {"N": [1e-3, 1e-3, 1e-3]}}})
    before = path.read_bytes()
    with pytest.raises(UnitMismatchError) as info:
        merge_sections(path, {"serial": "SN-2"}, {"noise": {"gyro": {"N": [1e-4, 1e-4, 1e-4]}}})
    message = str(info.value)
    assert "SN-1" in message and "SN-2" in message and str(path) in message and "--replace" in message
    assert info.value.exit_code == 4
    assert path.read_bytes() == before
    # a TUI names its own way of saying so
    with pytest.raises(UnitMismatchError, match="press r"):
        open_for_unit(path, {"serial": "SN-2"}, option="press r")
    params = merge_sections(path, {"serial": "SN-2"}, {"noise": {"gyro": {"N": [1e-4] * 3}}}, replace=True)
    assert params.device == {"serial": "SN-2"}
    assert ParamsFile.load(path).noise == {"gyro": {"N": [1e-4] * 3}}


def test_sources_are_checked_on_read(tmp_path) -> None:
    path = tmp_path / "unit.yaml"
    merge_sections(path, {"serial": "SN-1"}, {"noise": {"accel": {"N": [1e-3] * 3}}})
    data = yaml.safe_load(path.read_text())
    assert set(data["sources"]["noise"]) == {"serial", "written"}  # no capture file: none recorded
    data["sources"]["noise"]["serial"] = [1, 2]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(InputFileError, match=r"sources\.noise\.serial.*must be text"):
        ParamsFile.load(path)


def test_calibrate_allan_and_thermal_refuse_another_units_file(units, tmp_path, capsys) -> None:
    params = tmp_path / "unit.yaml"
    assert cli.main(["calibrate", str(units["a"]), "--method", "turntable", "-o", str(params)]) == 0
    assert cli.main(["allan", str(units["a_still"]), "-o", str(params), "--force"]) == 0
    capsys.readouterr()
    data = yaml.safe_load(params.read_text())
    # sections from two captures say which: path and checksum, and the unit
    for section, capture in (("accel", units["a"]), ("gyro", units["a"]), ("noise", units["a_still"])):
        source = data["sources"][section]
        assert source["capture"] == str(capture) and source["sha256"] == sha256_file(capture)
        assert source["serial"] == units["serial_a"]
    before = params.read_bytes()
    for argv in (["calibrate", str(units["b"]), "--method", "turntable"],
                 ["allan", str(units["b"])],
                 ["thermal", str(units["b"])]):
        code = cli.main([*argv, "-o", str(params)])
        err = capsys.readouterr().err
        assert code == 4, argv
        assert units["serial_a"] in err and units["serial_b"] in err and str(params) in err, err
        assert "--replace" in err and "Traceback" not in err
        assert params.read_bytes() == before, argv
    assert cli.main(["calibrate", str(units["b"]), "--method", "turntable", "-o", str(params),
                     "--replace"]) == 0
    data = yaml.safe_load(params.read_text())
    assert data["device"]["serial"] == units["serial_b"]
    assert "noise" not in data and set(data["sources"]) == {"accel", "gyro"}
    assert data["sources"]["accel"]["sha256"] == sha256_file(units["b"])


def test_thermal_refuses_before_fitting(tmp_path, capsys) -> None:
    unit = cubic_rate_unit(7)
    sweep = chamber_sweep(unit, ChamberSweep(low_degc=10.0, high_degc=30.0, start_degc=20.0,
                                             ramp_degc_per_min=4.0, soak_s=60.0), rate_hz=2.0, seed=1)
    capture = _h5(tmp_path / "sweep.h5", sweep.recording)
    params = tmp_path / "other.yaml"
    merge_sections(params, {"serial": "SOMEONE-ELSE"}, {"noise": {"accel": {"N": [1e-3] * 3}}})
    before = params.read_bytes()
    assert cli.main(["thermal", str(capture), "-o", str(params)]) == 4
    err = capsys.readouterr().err
    assert "SOMEONE-ELSE" in err and unit.serial in err and params.read_bytes() == before
