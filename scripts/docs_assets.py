"""Regenerate the pictures of the manual in docs/assets/ from the station itself.

TUI screens are textual SVG screenshots of the app driven headless (Pilot) on the simulated unit, as
tests/test_tui_flow.py drives it; plots are the PNGs the commands' own ``--plot`` options draw from
simulated captures. ``python scripts/docs_assets.py [--only NAME ...]`` (a few minutes on two cores).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ASSETS = ROOT / "docs" / "assets"
SIZE = (110, 40)


async def _wait(pilot, condition: Callable[[], object], timeout_s: float, what: str) -> object:
    deadline = time.monotonic() + timeout_s
    while not (value := condition()):
        if time.monotonic() > deadline:
            raise RuntimeError(f"timed out after {timeout_s} s waiting for {what}")
        await pilot.pause(0.1)
    return value


def local_fonts(svg: str) -> str:
    """A textual screenshot drawn with the reader's own monospace font instead of Fira Code from a CDN
    (the manual loads nothing from the network). Each text run keeps its ``textLength``, so columns
    stay put whatever the font's width; the font is set a little larger than textual's 20 px so that a
    box-drawing glyph (DejaVu Sans Mono: 1.164 em from descent to ascent) fills the 24.4 px row and
    the lines of a box join instead of showing a gap at every row."""
    svg = re.sub(r"\s*@font-face \{[^}]*\}", "", svg)
    svg = svg.replace("font-family: Fira Code, monospace;",
                      'font-family: "DejaVu Sans Mono", Menlo, Consolas, "Liberation Mono", monospace;')
    return svg.replace("font-size: 20px;\n        line-height: 24.4px;",
                       "font-size: 21px;\n        line-height: 24.4px;")


def _save(svg: str, name: str) -> None:
    (ASSETS / name).write_text(local_fonts(svg), encoding="utf-8")
    print(f"wrote docs/assets/{name}")


def tui_flow(work: Path) -> None:
    """Connect, live view, the wizard at its third step, the results of the whole run, help."""
    from station.tui.app import StationApp
    from station.tui.config import TuiConfig
    from station.tui.screens.results import ResultsScreen
    from station.tui.screens.wizard import WizardScreen

    config = TuiConfig(simulate=True, seed=1, out=Path("unit.yaml"), hold_s=2.0, rotation_rate_dps=180.0,
                       speed=2.0)
    app = StationApp(config)

    async def drive() -> None:
        async with app.run_test(size=SIZE) as pilot:
            await _wait(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.pause(1.0)
            _save(app.export_screenshot(), "tui-connect.svg")
            await pilot.press("enter")
            await _wait(pilot, lambda: type(app.screen).__name__ == "LiveScreen", 5, "the live view")
            await pilot.pause(2.0)
            _save(app.export_screenshot(), "tui-live.svg")
            await pilot.press("question_mark")
            await pilot.pause(0.5)
            _save(app.export_screenshot(), "tui-help.svg")
            await pilot.press("escape")
            await pilot.press("enter")
            wizard = await _wait(pilot, lambda: isinstance(app.screen, WizardScreen) and app.screen, 5,
                                 "wizard")
            shot = [False]
            while wizard.result is None:
                await _wait(pilot, lambda: wizard.prompt is not None or wizard.result is not None
                            or (not shot[0] and wizard.current == 2), 150, "a prompt or the third step")
                if not shot[0] and wizard.current == 2:
                    await pilot.pause(0.4)
                    _save(app.export_screenshot(), "tui-wizard.svg")
                    shot[0] = True
                if wizard.prompt is not None:
                    await pilot.press("enter")
                    await pilot.pause(0.2)
            await pilot.press("enter")
            results = await _wait(pilot, lambda: isinstance(app.screen, ResultsScreen) and app.screen, 5,
                                  "results")
            await _wait(pilot, lambda: results.report is not None, 60, "the calibration")
            await pilot.pause(0.5)
            _save(app.export_screenshot(), "tui-results.svg")
            await pilot.press("q")

    os.chdir(work)
    asyncio.run(drive())


def tui_allan(work: Path) -> None:
    """The Allan recording screen after some seconds of a still unit at 1 kHz."""
    from station.tui.app import StationApp
    from station.tui.config import TuiConfig
    from station.tui.screens.allan import AllanScreen

    app = StationApp(TuiConfig(simulate=True, seed=1, rate_hz=1000.0, out=work / "noise.yaml", speed=4.0))

    async def drive() -> None:
        async with app.run_test(size=(120, 44)) as pilot:
            await _wait(pilot, lambda: app.session is not None, 30, "the simulated unit")
            await pilot.press("a")
            screen = await _wait(pilot, lambda: isinstance(app.screen, AllanScreen) and app.screen, 5,
                                 "Allan")
            await _wait(pilot, lambda: _recorded(screen) >= 60000, 120, "60 s of samples")
            await pilot.pause(1.5)
            _save(app.export_screenshot(), "tui-allan.svg")
            await pilot.press("q")

    asyncio.run(drive())


def tui_thermal(work: Path) -> None:
    """The temperature-sweep screen while a simulated chamber ramps the unit up and down."""
    from drivers import open_device
    from mocks.device import SimDevice
    from mocks.pty_server import PtyServer
    from mocks.rig import ramp
    from station.tui.app import StationApp
    from station.tui.config import TuiConfig
    from station.tui.screens.thermal import ThermalScreen
    from station.tui.session import Session

    profile = ramp([(0.0, 20.0), (60.0, 50.0), (120.0, 20.0)])
    unit = SimDevice(seed=1, rate_hz=100.0, scenario="still", temperature=profile)
    server = PtyServer(unit, speed=4.0).start()
    device = open_device(server.port_path)
    app = StationApp(TuiConfig(out=work / "thermal.yaml"))

    async def drive() -> None:
        async with app.run_test(size=(120, 44)) as pilot:
            await _wait(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 5, "the connect screen")
            app.session = Session(device, "simulated chamber", info=device.get_info())
            app.show("thermal")
            screen = await _wait(pilot, lambda: isinstance(app.screen, ThermalScreen) and app.screen, 5,
                                 "thermal")
            await _wait(pilot, lambda: _recorded(screen) >= 9000, 120, "90 s of the sweep")
            await pilot.pause(1.0)
            _save(app.export_screenshot(), "tui-thermal.svg")
            await pilot.press("q")

    try:
        asyncio.run(drive())
    finally:
        device.close()
        server.stop()


def tui_datasheet(work: Path) -> None:
    """The datasheet screen (d) on the parameter file of the simulated examples/campaign.yaml (about two
    minutes): the figures, the scale factor across temperature and the turn-ons per soak."""
    from station.tui.app import StationApp
    from station.tui.config import TuiConfig

    os.chdir(work)
    _station("run", "--plan", str(ROOT / "examples" / "campaign.yaml"), "--simulate", "--serial", "auto",
             "--files", "files", "--db", "records.sqlite")
    params = next((work / "files").rglob("params.yaml"))
    app = StationApp(TuiConfig(out=params))

    async def drive() -> None:
        async with app.run_test(size=SIZE) as pilot:
            await _wait(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 10, "the connect screen")
            await pilot.press("d")
            await _wait(pilot, lambda: type(app.screen).__name__ == "DatasheetScreen", 5, "the datasheet")
            await pilot.pause(1.0)
            _save(app.export_screenshot(), "tui-datasheet.svg")
            await pilot.press("q")

    asyncio.run(drive())


def _recorded(screen) -> int:
    recording = getattr(screen, "recording", None)
    return recording.count if recording is not None else 0


def _station(*args: str) -> None:
    from station.cli import main

    print("$ imu-station " + " ".join(args), flush=True)
    code = main(list(args))
    if code != 0:
        raise RuntimeError(f"imu-station {' '.join(args)} exited {code}")


def plots(work: Path) -> None:
    """The commands' own --plot PNGs on one simulated unit (seed 1), as in the getting-started tour."""
    os.chdir(work)
    _station("demo", "--out", "demo-out")
    _station("calibrate", "demo-out/sequence.h5", "--method", "turntable", "-o", "unit.yaml",
             "--plot", "calibration.png")
    _station("capture", "--port", "sim://?seed=1&speed=100", "--duration", "7200", "-o", "still.h5")
    _station("allan", "still.h5", "-o", "unit.yaml", "--plot", "adev.png")
    _station("capture", "--port", "sim://?scenario=chamber&seed=1&speed=400", "--duration", "10800",
             "-o", "sweep.h5")
    _station("thermal", "sweep.h5", "-o", "unit.yaml", "--plot", "thermal.png")
    _station("export", "unit.yaml", "--format", "px4", "-o", "unit.params", "--plot", "px4.png")
    for name in ("calibration.png", "adev.png", "thermal.png", "px4.png"):
        shutil.copyfile(name, ASSETS / name)
        print(f"wrote docs/assets/{name}")


STEPS = {"tui": tui_flow, "allan-screen": tui_allan, "thermal-screen": tui_thermal,
         "datasheet-screen": tui_datasheet, "plots": plots}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", choices=sorted(STEPS), help="make only these (repeatable)")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    ASSETS.mkdir(parents=True, exist_ok=True)
    for name in args.only or list(STEPS):
        with tempfile.TemporaryDirectory(prefix=f"docs-assets-{name}-") as work:
            here = Path.cwd()
            try:
                STEPS[name](Path(work))
            finally:
                os.chdir(here)
    return 0


if __name__ == "__main__":
    sys.exit(main())
