"""A unit's own strings (DEVICE_INFO serial, model, firmware) never reach the operator's terminal raw:
a simulated unit whose serial clears the screen and retitles the terminal is shown escaped by
``imu-station capture`` and on the TUI's connect screen; the files the station writes from it
escape it in their own syntax.
"""

from __future__ import annotations

import asyncio
import dataclasses
import io
import json
from pathlib import Path

import pytest
from export_params import make_params
from rich.console import Console
from text_helpers import CLEAR, CONTROL, TITLE
from textual.widgets import Static
from tui_helpers import svg_rows, wait_for

from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from mocks.truth import UnitTruth
from station import cli
from station.common.text import printable
from station.export.params.file import ParamsFile
from station.tui.app import StationApp
from station.tui.config import TuiConfig

HOSTILE = {"serial": f"SN{CLEAR}{TITLE}-1", "model": "[bold red]IMU\u202e9", "firmware": "1.0\r\n\x9b31m"}


def hostile_unit() -> SimDevice:
    truth = dataclasses.replace(UnitTruth.random(5), **HOSTILE)
    return SimDevice(truth, seed=5, rate_hz=100)


def test_printable_escapes_what_a_terminal_would_act_on() -> None:
    assert printable("SN-0042 é µ") == "SN-0042 é µ"
    assert printable(HOSTILE["serial"]) == "SN\\x1b[2J\\x1b[H\\x1b]0;pwned\\x07-1"
    assert printable("a\\x1b") == "a\\\\x1b"  # a backslash the unit sent is not taken for an escape
    assert printable("\u202eabc\u2028") == "\\u202eabc\\u2028"
    assert printable(12.5) == "12.5" and printable(None) == "None"
    assert printable("x" * 500) == "x" * 117 + "..."
    for text in (*HOSTILE.values(), "".join(map(chr, range(0x110)))):
        assert not CONTROL.search(printable(text, max_chars=10_000))


def test_capture_prints_the_units_strings_escaped(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    with PtyServer(hostile_unit(), block_s=0.02) as server:
        code = cli.main(["capture", "--port", server.port_path, "--duration", "0.5",
                         "-o", str(tmp_path / "cap.csv")])
    out, err = capfd.readouterr()
    assert code == 0, err
    assert not CONTROL.search(out + err), repr(out + err)
    assert printable(HOSTILE["serial"]) in err and printable(HOSTILE["model"]) in err
    assert printable(HOSTILE["firmware"]) in err


def test_files_written_from_the_unit_escape_its_strings(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    unit = make_params(seed=1, device=dict(HOSTILE))
    path = tmp_path / "unit.yaml"
    unit.save(path)
    assert not CONTROL.search(path.read_text())
    assert ParamsFile.load(path).device == HOSTILE  # escaped in the file, the same text read back
    for fmt, name in (("c", "c"), ("json", "u.json"), ("px4", "u.params"), ("ardupilot", "u.param")):
        argv = ["export", str(path), "-f", fmt, "-o", str(tmp_path / name), "--station-id", "s"]
        assert cli.main(argv) == 0, capsys.readouterr().err
        assert not CONTROL.search(capsys.readouterr().out)
    for name in ("c/imu_calib.h", "c/imu_calib.c", "u.json", "u.params", "u.param"):
        assert not CONTROL.search((tmp_path / name).read_text()), name
    assert json.loads((tmp_path / "u.json").read_text())["device"] == HOSTILE


def _text_of(widget: Static) -> str:
    console = Console(file=io.StringIO(), width=100, color_system=None, force_terminal=False)
    console.print(widget.content)
    return console.file.getvalue()


def test_tui_connect_screen_shows_the_strings_escaped() -> None:
    with PtyServer(hostile_unit(), block_s=0.02) as server:
        app = StationApp(TuiConfig(port=server.port_path))

        async def run() -> None:
            async with app.run_test(size=(110, 40)) as pilot:
                await wait_for(pilot, lambda: app.session is not None, 20, "the unit's info")
                info = app.screen.query_one("#info", Static)
                await wait_for(pilot, lambda: "serial" in _text_of(info), 5, "the info table")
                text = _text_of(info)
                assert not CONTROL.search(text), repr(text)
                assert printable(HOSTILE["serial"]) in text
                assert printable(HOSTILE["model"]) in text  # shown as text, not taken as Rich markup
                # The widget holds the text before the screen repaints: wait for the repaint.
                await wait_for(pilot, lambda: "SN\\x1b[2J" in "\n".join(svg_rows(app.export_screenshot())),
                               5, "the serial on screen")
                rows = "\n".join(svg_rows(app.export_screenshot()))
                assert not CONTROL.search(rows)
                await pilot.press("q")

        asyncio.run(run())
