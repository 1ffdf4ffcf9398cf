"""The calibrate command's printed report as plain text: the table formatter, the phase line, and the
free method's whole run on imu_tk's Xsens session printing every parameter without loading rich."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_cli_startup import _loaded

from station.common.table import format_table
from station.console.phase_line import CLEAR, PhaseLine


def test_table_columns_aligned_under_a_rule() -> None:
    text = format_table("title", ("name", "value"), [["a", "1.5"], ["longer", "-22"]], (False, True))
    assert text.splitlines() == ["title",
                                 "name    value",
                                 "------  -----",
                                 "a         1.5",
                                 "longer    -22"]
    assert format_table("", ("k",), []).splitlines() == ["k", "-"]
    with pytest.raises(ValueError, match="a row of 1 cells in a table of 2 columns"):
        format_table("t", ("a", "b"), [["x"]])


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_phase_line_on_a_terminal_only_and_erased() -> None:
    tty = _Terminal()
    with PhaseLine(tty) as phase:
        phase.show("reading a\x1b[2Jb.csv")
        phase.show("calibrating")
    assert tty.getvalue() == f"{CLEAR}reading a\\x1b[2Jb.csv ...{CLEAR}calibrating ...{CLEAR}"
    pipe = io.StringIO()
    with PhaseLine(pipe) as phase:
        phase.show("reading")
    assert pipe.getvalue() == ""


def test_free_report_printed_without_rich(tmp_path) -> None:
    from station.acquisition.capture import Capture
    from station.acquisition.capture_csv import write_csv

    folder = Path(__file__).parent / "data" / "xsens-imu_tk"
    acc, gyro = (np.loadtxt(folder / f"xsens_{name}.txt.gz") for name in ("acc", "gyro"))
    csv = tmp_path / "xsens.csv"
    write_csv(csv, Capture(acc[:, 0], acc[:, 1:], gyro[:, 1:]))
    params = tmp_path / "params.yaml"
    argv = ["calibrate", str(csv), "--method", "free", "--imu-tk", "--gravity", "9.81744", "--convention",
            "upper", "--initial-still", "50", "-o", str(params)]
    modules, shown = _loaded(argv, every=True)
    assert not {m for m in modules if m == "rich" or m.startswith("rich.")}
    written = yaml.safe_load(params.read_text())
    lines = shown.splitlines()
    assert lines[0] == "free calibration, g = 9.817440 m/s^2"
    # every parameter the file holds is printed, to 7 digits, with its 1-sigma
    for sensor in ("accel", "gyro"):
        section = written[sensor]
        row = next(line for line in lines[lines.index(next(t for t in lines if t.startswith(f"{sensor}: "))):]
                   if line.startswith("scale K"))
        for value, sd in zip(section["scale"], section["stddev"]["scale"], strict=True):
            assert f"{value:.7g} ± {sd:.2g}" in row
        bias = next(line for line in lines[lines.index(row):] if line.startswith("bias b"))
        for value in section["bias"]:
            assert f"{value:.7g}" in bias
    assert any(line.startswith("6 *") for line in lines)  # the chosen threshold multiplier marked
    assert "per-pose residuals" in lines and sum(line.startswith("static ") for line in lines) == 38
    assert lines[-1] == f"{params}: accel and gyro sections written"
