"""The layering rules of the design (shared/DESIGN.md, "folder / may import"), checked on the source.

Every import statement of the package (those inside functions and under ``TYPE_CHECKING`` too) is
read with ``ast`` and checked against the rule of the folder it is in; a violation names the
file, the line, the module imported and the rule. Where the design allows something its table
leaves out, the exception is written here beside its reason.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("protocols", "drivers", "mocks", "station")
STDLIB = frozenset(sys.stdlib_module_names)

# Station modules every station layer may import: the version, the exception root and station.common
# (atomic file writing, the bounded YAML reader, printable text and tables, lazy exports) are the
# house's plumbing, not a layer.
STATION_CORE = ("station.errors", "station.common")
# ``from station import __version__``: the package itself, not everything under it.
STATION_ROOT = "station"
# The lowest layer's constants and exception root: importable from everywhere, that is why they live there.
PROTOCOL_CORE = ("protocols.units", "protocols.errors")


@dataclass(frozen=True)
class Rule:
    """What the files under ``folder`` may import: project modules by prefix, third-party by top name."""

    folder: str
    project: tuple[str, ...]
    third_party: tuple[str, ...]
    text: str
    # Allowed in one file only: (file, module prefix) -> why.
    exceptions: tuple[tuple[str, str], ...] = ()
    no_io: bool = False


RULES = (
    Rule("protocols/", ("protocols",), ("numpy",),
         "protocols imports only the standard library and numpy",
         # The MAVLink decoder wraps pymavlink's message definitions (the optional 'mavlink' extra);
         # it is imported lazily and its absence is a StationError.
         exceptions=(("protocols/mavlink.py", "pymavlink"),)),
    # Lab instruments: pymodbus frames Modbus (no hand-written framing or CRC).
    Rule("drivers/instruments/", ("drivers", *PROTOCOL_CORE, "protocols"), ("serial", "pymodbus"),
         "instrument drivers import protocols, pyserial and pymodbus"),
    # numpy: samples travel as numpy batches (design rule), so the drivers' buffers hold them.
    Rule("drivers/", ("drivers", *PROTOCOL_CORE, "protocols"), ("serial", "numpy"),
         "drivers import protocols, pyserial and numpy"),
    # scipy: the truth model's Gauss-Markov and flicker bias noise are IIR-filtered (scipy.signal.lfilter).
    Rule("mocks/", ("mocks", "protocols"), ("numpy", "serial", "scipy"),
         "mocks import protocols, numpy, pyserial (and scipy for the noise filters)",
         # A simulated recording handed to the engines as the station's Capture (tests and the
         # chamber's sweeps use it); imported lazily so the simulator alone never loads the station.
         exceptions=(("mocks/rig.py", "station.acquisition.capture"),
                     # The Modbus chambers' emulators serve with pymodbus's own servers (no hand-written
                     # framing or CRC on either side of the link).
                     ("mocks/instruments/modbus_chambers.py", "pymodbus"))),
    # numba: the Allan deviation's inner loop, compiled (station/engines/allan/_kernel.py).
    # station.common.lazy: a subject package's __init__ names its public functions without importing them.
    Rule("station/engines/", ("station.engines", "station.errors", "station.common.lazy", *PROTOCOL_CORE),
         ("numpy", "scipy", "numba"),
         "engines import numpy and scipy only: arrays in, results out, no files, devices or printing",
         # The World Magnetic Model is pygeomag's coefficients and series, pure Python, no file read.
         exceptions=(("station/engines/magnetometer/geomagnetic.py", "pygeomag"),),
         no_io=True),
    # The plumbing every layer uses: the standard library, pyyaml for the bounded reader.
    Rule("station/common/", ("station.common", "station.errors", *PROTOCOL_CORE), ("yaml",),
         "station.common imports nothing of the station but errors: every layer imports it"),
    # The instruments as the station uses them: description files read, limits, safe states.
    Rule("station/instruments/", ("station.instruments", "drivers", "protocols", *STATION_CORE), (),
         "station.instruments imports the instrument drivers and the station's plumbing"),
    # Frame descriptions: read (acquisition's level), checked live on a port, guessed from bytes.
    Rule("station/frames/", ("station.frames", "drivers", "protocols", *STATION_CORE), ("numpy", "yaml"),
         "frames import drivers and protocols, as acquisition does"),
    # h5py and rosbags read and write the capture files and bags; pyyaml the sequence files; pymavlink
    # indexes ArduPilot's DataFlash logs (its DFReader) and holds ArduPilot's board rotations; numba walks
    # a ULog's message headers (station/acquisition/ulog_reader.py: one compiled loop, 100x Python's).
    Rule("station/acquisition/", ("station.acquisition", "drivers", "protocols", *STATION_CORE),
         ("numpy", "yaml", "h5py", "rosbags", "pymavlink", "numba"),
         "acquisition imports drivers (through their interface) and protocols",
         # Taking ArduPilot's own correction out of a log's IMU messages evaluates the formula the
         # ArduPilot export documents and checks (ardupilot_offsets, names): one implementation of it.
         exceptions=(("station/acquisition/autopilot_log.py", "station.export.autopilot.ardupilot"),
                     ("station/acquisition/log_magnetometer.py", "station.export.autopilot.ardupilot"),
                     ("station/acquisition/log_magnetometer.py", "station.export.autopilot.shared"))),
    # Engines: their result types and the pure functions that evaluate them (the error an autopilot
    # leaves is computed with the station's own correction); protocols.crc: the blob's CRC-32 is
    # the protocols' one implementation; matplotlib draws the PNGs written beside an export.
    Rule("station/export/", ("station.export", "station.engines", "station.plots", "protocols.crc",
                             *PROTOCOL_CORE, *STATION_CORE), ("numpy", "yaml"),
         "export imports the engines' result types and pyyaml"),
    Rule("station/report/", ("station.report", "station.export", "station.engines", "station.plots",
                             "station.factory.records", *PROTOCOL_CORE, *STATION_CORE),
         ("numpy", "jinja2", "yaml"),
         "report imports export, the engines' result types and the factory records"),
    # Every figure the station draws (PNG and inline SVG), from the engines' result types and arrays:
    # below export and report, which draw with it.
    Rule("station/plots/", ("station.plots", "station.engines", *PROTOCOL_CORE, *STATION_CORE),
         ("numpy", "matplotlib"), "plots import the engines' result types and matplotlib"),
)
# Layers nobody but the composition root and the operator's front ends may import.
TOP = (
    ("station.commands", ("station/cli.py",),
     "station.commands is imported by nothing but station/cli.py"),
    ("station.tui", ("station/cli.py", "station/commands/", "station/tui/"),
     "station.tui is imported by nothing but station/cli.py and the commands"),
    # What the commands and screens show on a terminal while they run: acquisition and the factory
    # would import upward if it lived below them.
    ("station.console", ("station/cli.py", "station/commands/", "station/tui/", "station/console/"),
     "station.console is imported by nothing but station/cli.py, the commands and the TUI"),
)
# Modules that read or write files or devices: the engines import none of them.
IO_MODULES = ("pathlib", "io", "shutil", "tempfile", "h5py", "yaml", "serial", "station.common.files",
              "drivers", "mocks", "sqlite3", "socket", "subprocess")


def _source_files() -> list[Path]:
    return sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))


def _is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imported_modules(tree: ast.AST) -> list[tuple[int, str]]:
    """Every module an ``import`` or ``from ... import`` names, with its line; ``from a import b``
    gives ``a.b`` when b is a module of the project, else ``a``."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"line {node.lineno}: relative import; the project imports absolutely"
            base = node.module or ""
            for alias in node.names:
                full = f"{base}.{alias.name}"
                found.append((node.lineno, full if _is_module(full) else base))
    return found


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def _rule_of(rel: str) -> Rule | None:
    return next((r for r in RULES if rel.startswith(r.folder)), None)


def violations(rel: str, source: str) -> list[str]:
    """The layering violations of one source file, each as 'file:line: imports X: rule'."""
    tree = ast.parse(source, filename=rel)
    rule = _rule_of(rel)
    out = []
    for line, module in imported_modules(tree):
        top = module.split(".")[0]
        for layer, importers, text in TOP:
            if _under(module, layer) and not any(rel == i or (i.endswith("/") and rel.startswith(i))
                                                 for i in importers):
                if not (layer == "station.commands" and rel.startswith("station/commands/")
                        and module == "station.commands"):
                    out.append(f"{rel}:{line}: imports {module}: {text}")
        if rule is None or top == "__future__":
            continue
        if rule.no_io and any(_under(module, m) for m in IO_MODULES):
            out.append(f"{rel}:{line}: imports {module}: {rule.text}")
            continue
        if top in STDLIB:
            continue
        allowed = (any(_under(module, p) for p in rule.project) or module == STATION_ROOT if top in PACKAGES
                   else top in rule.third_party)
        if not allowed and any(rel == f and _under(module, m) for f, m in rule.exceptions):
            allowed = True
        if not allowed:
            out.append(f"{rel}:{line}: imports {module}: {rule.text}")
    for node in ast.walk(tree):
        # A command run as a module (``python -m station.commands.run``) is imported all the same.
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and rel != "station/cli.py" \
                and _under(node.value, "station.commands") and not rel.startswith("station/commands/"):
            out.append(f"{rel}:{node.lineno}: runs {node.value}: {TOP[0][2]}")
    if rule is not None and rule.no_io:
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("open",
                                                                                                 "print"):
                out.append(f"{rel}:{node.lineno}: calls {node.func.id}(): {rule.text}")
    return list(dict.fromkeys(out))  # one line per import statement and module


def test_every_file_keeps_its_layer() -> None:
    found = []
    for path in _source_files():
        rel = path.relative_to(ROOT).as_posix()
        found += violations(rel, path.read_text(encoding="utf-8"))
    assert not found, "layering rules broken (shared/DESIGN.md):\n" + "\n".join(found)


def test_the_rules_cover_every_folder_of_the_design() -> None:
    folders = {r.folder for r in RULES}
    assert {"protocols/", "drivers/", "mocks/", "station/engines/", "station/acquisition/",
            "station/export/"} <= folders
    assert {"station/common/", "station/frames/", "station/plots/", "station/report/"} <= folders
    assert {layer for layer, _, _ in TOP} == {"station.commands", "station.tui", "station.console"}


@pytest.mark.parametrize(("rel", "source", "expected"), [
    ("station/tui/screens/x.py", "from station.commands.thermal import format_report\n",
     "station/tui/screens/x.py:1: imports station.commands.thermal: station.commands is imported by nothing "
     "but station/cli.py"),
    ("station/commands/records.py", "\n\nfrom station.commands import run\n",
     "station/commands/records.py:3: imports station.commands.run: station.commands is imported by nothing "
     "but station/cli.py"),
    ("station/factory/run.py", "def f():\n    from station.tui.app import StationApp\n",
     "station/factory/run.py:2: imports station.tui.app: station.tui is imported by nothing but "
     "station/cli.py and the commands"),
    ("protocols/x.py", "import serial\n",
     "protocols/x.py:1: imports serial: protocols imports only the standard library and numpy"),
    ("drivers/x.py", "from station.errors import StationError\n",
     "drivers/x.py:1: imports station.errors: drivers import protocols, pyserial and numpy"),
    ("station/engines/x.py", "from pathlib import Path\n",
     "station/engines/x.py:1: imports pathlib: engines import numpy and scipy only: arrays in, results out, "
     "no files, devices or printing"),
    ("station/engines/x.py", "def f(x):\n    print(x)\n",
     "station/engines/x.py:2: calls print(): engines import numpy and scipy only: arrays in, results out, "
     "no files, devices or printing"),
    ("station/export/x.py", "from drivers import open_device\n",
     "station/export/x.py:1: imports drivers: export imports the engines' result types and pyyaml"),
    ("station/acquisition/x.py", "import matplotlib\n",
     "station/acquisition/x.py:1: imports matplotlib: acquisition imports drivers (through their interface) "
     "and protocols"),
    ("station/factory/many.py", "CMD = ['python', '-m', 'station.commands.run']\n",
     "station/factory/many.py:1: runs station.commands.run: station.commands is imported by nothing but "
     "station/cli.py"),
    ("mocks/x.py", "from station.acquisition.capture import Capture\n",
     "mocks/x.py:1: imports station.acquisition.capture: mocks import protocols, numpy, pyserial (and scipy "
     "for the noise filters)"),
])
def test_a_violation_names_file_line_and_rule(rel: str, source: str, expected: str) -> None:
    assert violations(rel, source) == [expected]


@pytest.mark.parametrize(("rel", "source"), [
    ("station/cli.py", "from station.commands import export\n"),
    ("station/commands/tui.py", "from station.tui.config import TuiConfig\n"),
    ("station/engines/x.py", "from protocols.units import STANDARD_GRAVITY\nimport scipy.linalg\n"),
    ("protocols/mavlink.py", "from pymavlink.dialects.v20 import ardupilotmega\n"),
    ("mocks/rig.py", "from station.acquisition.capture import Capture\n"),
    ("station/export/firmware/blob.py", "from protocols.crc import crc32\n"),
])
def test_what_the_design_allows_passes(rel: str, source: str) -> None:
    assert violations(rel, source) == []
