"""Start-up: `imu-station --help`, `--version` and every `COMMAND --help` load none of the heavy
libraries (numpy, scipy, matplotlib, h5py, textual): each command imports them when it runs. The
names --help shows without loading the registries are checked against the registries here."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from station import cli, cli_options

HEAVY = ("numpy", "scipy", "matplotlib", "h5py", "textual", "serial", "yaml", "rich")

PROBE = """
import json, sys
from station.cli import main
try:
    main(json.loads(sys.argv[1]))
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if '.' not in m)))
"""


def _loaded(argv: list[str]) -> tuple[set[str], str]:
    done = subprocess.run([sys.executable, "-c", PROBE, json.dumps(argv)], capture_output=True, text=True,
                          timeout=60, check=True)
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


def test_the_names_help_shows_are_the_registries() -> None:
    import mocks.encoders_extra  # noqa: F401
    from drivers import DEFAULT_BAUDRATE
    from mocks.device import ENCODERS, SCENARIOS
    from protocols.registry import DECODER_OPTIONS, DECODERS
    from station.engines import allan_fit, allan_terms
    from station.export.writers import FORMATS, MAX_INSTANCE

    assert cli_options.DEFAULT_BAUDRATE == DEFAULT_BAUDRATE
    assert cli_options.PROTOCOLS == tuple(sorted(DECODERS))
    assert cli_options.PROTOCOL_OPTIONS == tuple(DECODER_OPTIONS)
    assert cli_options.EXPORT_FORMATS == FORMATS
    assert cli_options.EXPORT_MAX_INSTANCE == MAX_INSTANCE
    assert cli_options.SIM_SCENARIOS == tuple(SCENARIOS)
    assert cli_options.SIM_ENCODERS == tuple(sorted(ENCODERS))
    assert allan_fit.TERMS is allan_terms.TERMS
