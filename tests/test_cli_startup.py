"""Start-up: `imu-station --help`, `--version` and every `COMMAND --help` load none of the heavy
libraries (numpy, scipy, matplotlib, h5py, textual): each command imports them when it runs. The
names --help shows without loading the registries are checked against the registries here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from station import cli
from station.console import options

HEAVY = ("numpy", "scipy", "matplotlib", "h5py", "textual", "serial", "yaml", "rich")

PROBE = """
import json, os, sys
from station.cli import main
try:
    main(json.loads(sys.argv[1]))
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if sys.argv[2] == "all" or '.' not in m)))
"""


def _loaded(argv: list[str], every: bool = False, env: dict[str, str] | None = None) -> tuple[set[str], str]:
    """The modules ``imu-station ARGV`` loaded in a fresh interpreter (top-level packages, or ``every``
    module), and what it printed."""
    done = subprocess.run([sys.executable, "-c", PROBE, json.dumps(argv), "all" if every else "top"],
                          capture_output=True, text=True, timeout=60, check=True, env=env)
    *shown, modules = done.stdout.strip().splitlines()
    return set(json.loads(modules)), "\n".join(shown)


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["completion", "--help"]]
                         + [[name.replace("_", "-"), "--help"] for name in cli.COMMANDS])
def test_help_loads_no_heavy_library(argv: list[str]) -> None:
    modules, shown = _loaded(argv)
    assert shown.startswith(("usage: imu-station", "imu-station ")), shown[:200]
    assert not modules & set(HEAVY), f"{' '.join(argv)} loaded {sorted(modules & set(HEAVY))}"


def test_a_command_still_loads_what_it_needs() -> None:
    # the same probe sees the libraries once a command runs (here: export of a missing file, exit 4)
    modules, _ = _loaded(["export", "/nonexistent.yaml", "-f", "json", "-o", "/tmp/x.json"])
    assert {"numpy", "yaml"} <= modules


def test_help_loads_no_record_store_nor_frame_reader() -> None:
    modules, _ = _loaded(["--help"], every=True)
    assert not modules & {"station.factory.records", "sqlite3", "station.frames.reader", "protocols.frame"}


def test_free_calibration_loads_only_what_it_uses(tmp_path) -> None:
    # imu_tk's Xsens session through the whole command: no scipy (the fits are numpy's), not the turntable
    # engine, not the frame-description reader; OpenBLAS held to one thread unless the user chose
    import numpy as np

    from station.acquisition.capture import Capture
    from station.acquisition.capture_csv import write_csv

    folder = Path(__file__).parent / "data" / "xsens-imu_tk"
    acc, gyro = (np.loadtxt(folder / f"xsens_{name}.txt.gz") for name in ("acc", "gyro"))
    csv = tmp_path / "xsens.csv"
    write_csv(csv, Capture(acc[:, 0], acc[:, 1:], gyro[:, 1:]))
    argv = ["calibrate", str(csv), "--method", "free", "--imu-tk", "--gravity", "9.81744", "--convention",
            "upper", "--initial-still", "50", "--json"]
    modules, shown = _loaded(argv, every=True)
    assert '"method": "free' in shown
    assert "numpy" in modules and "station.engines.calibration.free" in modules
    unneeded = {"scipy", "station.engines.calibration.turntable", "station.frames.reader", "protocols.frame",
                "matplotlib", "h5py"}
    assert not modules & unneeded, sorted(modules & unneeded)


@pytest.mark.parametrize("preset", [None, "3"])
def test_openblas_threads_default_to_one(preset: str | None) -> None:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    code = ("import os, station.cli, numpy, threadpoolctl; "
            "print(os.environ['OPENBLAS_NUM_THREADS'], "
            "[i['num_threads'] for i in threadpoolctl.threadpool_info() if i['internal_api'] == 'openblas'])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          check=True, env=env)
    value, threads = done.stdout.split(" ", 1)
    # the user's setting is left alone (OpenBLAS caps it at the cores it finds)
    assert value == (preset or "1")
    if preset is None:
        assert json.loads(threads) == [1]


def test_the_names_help_shows_are_the_registries() -> None:
    import mocks.encoders_extra  # noqa: F401
    from drivers import DEFAULT_BAUDRATE
    from mocks.device import ENCODERS, SCENARIOS
    from protocols.registry import DECODER_OPTIONS, DECODERS
    from station.engines.allan import fit, terms
    from station.export.writers import FORMATS, MAX_INSTANCE
    from station.factory.records import OUTCOMES

    assert options.DEFAULT_BAUDRATE == DEFAULT_BAUDRATE
    assert options.PROTOCOLS == tuple(sorted(DECODERS))
    assert options.PROTOCOL_OPTIONS == tuple(DECODER_OPTIONS)
    assert options.EXPORT_FORMATS == FORMATS
    assert options.EXPORT_MAX_INSTANCE == MAX_INSTANCE
    assert options.SIM_SCENARIOS == tuple(SCENARIOS)
    assert options.RECORD_OUTCOMES == OUTCOMES
    assert options.SIM_ENCODERS == tuple(sorted(ENCODERS))
    assert fit.TERMS is terms.TERMS
