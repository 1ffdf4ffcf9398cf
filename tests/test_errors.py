"""One exception tree under StationError, drawn in station/errors.py, and one exit-code enum.

The classes are found by reading the source (``ast``), so a new error class anywhere in the
package that is not under the root, or not in the drawn tree, fails here by name.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import station.errors
from drivers.errors import CommandTimeout, DriverError, PortNotFound
from drivers.turntable import TableFault
from protocols.errors import ExitCode, StationError
from protocols.mavlink import MavlinkUnavailable
from station import cli
from station.acquisition.sequences import SequenceError, pose_vector
from station.export.firmware.blob import BlobError

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("protocols", "drivers", "mocks", "station")
# Exceptions that never leave their module: control flow inside one loop, each caught where raised.
INTERNAL = {
    "_Abort", "_Restart", "_Skip",  # the sequence runner's operator answers
    "_Stop",  # the factory run's early end, turned into the record's outcome
    "_Refused",  # the bounded YAML reader's loader signal, turned into an InputFileError
    "_Reject", "BadPacket",  # decoders' damaged-frame signals, counted, never raised to a caller
    "_SupplyFailed",  # the TUI's turn-on worker's reason to stop, shown on its screen
}


Classes = dict[str, tuple[str, list[str]]]
BUILTIN = ("Exception", "BaseException", "ValueError", "RuntimeError", "TypeError", "OSError", "KeyError")


def _classes() -> Classes:
    """Every class of the package: name -> (file:line, base names)."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ClassDef):
                    bases = [ast.unparse(b).split(".")[-1] for b in node.bases]
                    found[node.name] = (f"{path.relative_to(ROOT)}:{node.lineno}", bases)
    return found


def _is_exception(name: str, classes: Classes, seen: frozenset[str] = frozenset()) -> bool:
    if name in BUILTIN:
        return True
    if name not in classes or name in seen:
        return False
    return any(_is_exception(b, classes, seen | {name}) for b in classes[name][1])


def _under_root(name: str, classes: Classes) -> bool:
    if name == "StationError":
        return True
    return name in classes and any(_under_root(b, classes) for b in classes[name][1])


def test_every_error_class_is_under_station_error_and_in_the_drawn_tree() -> None:
    classes = _classes()
    errors = [n for n in classes if _is_exception(n, classes) and n not in INTERNAL and n != "StationError"]
    outside = [f"{classes[n][0]} {n}" for n in errors if not _under_root(n, classes)]
    assert not outside, f"exceptions outside the StationError tree: {outside}"
    tree = station.errors.__doc__ or ""
    undrawn = [f"{classes[n][0]} {n}" for n in errors if not re.search(rf"── {n}\b", tree)]
    assert not undrawn, f"exceptions missing from station/errors.py's drawn tree: {undrawn}"
    assert len(errors) >= 15  # the scan sees the tree (19 classes when written)


@pytest.mark.parametrize(("error", "code"), [
    (PortNotFound("/dev/x: no such port", "/dev/x"), ExitCode.DEVICE),
    (CommandTimeout("/dev/x: no answer", "/dev/x"), ExitCode.DEVICE),
    (TableFault("/dev/t: limit switch", "/dev/t"), ExitCode.DEVICE),
    (MavlinkUnavailable("the MAVLink protocol needs pymavlink"), ExitCode.USAGE),
    (SequenceError("pose 'up' is not signed axes"), ExitCode.USAGE),
    (BlobError("nothing to export"), ExitCode.USAGE),
])
def test_one_root_one_exit_code_each(error: StationError, code: ExitCode) -> None:
    assert isinstance(error, StationError) and not isinstance(error, ValueError)
    assert error.exit_code == code
    assert isinstance(error, DriverError) == (code == ExitCode.DEVICE)


def test_a_sequence_label_error_is_a_station_error() -> None:
    with pytest.raises(StationError, match="signed axes"):
        pose_vector("up")


def test_the_exit_codes_are_the_documented_ones() -> None:
    assert {c.name: int(c) for c in ExitCode} == {"OK": 0, "OUT_OF_LIMITS": 1, "ABORTED": 2, "DEVICE": 3,
                                                 "USAGE": 4, "TIMEOUT": 5, "INTERRUPTED": 130,
                                                 "TERMINATED": 143}
    assert station.errors.ExitCode is ExitCode and station.errors.StationError is StationError


def test_no_command_returns_a_bare_number() -> None:
    """Every code a command or the CLI returns is an ExitCode member (or a record's / an error's)."""
    found = []
    for path in [ROOT / "station" / "cli.py", *sorted((ROOT / "station" / "commands").glob("*.py"))]:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Return) and isinstance(node.value, ast.Constant) \
                    and isinstance(node.value.value, int) and not isinstance(node.value.value, bool):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: return {node.value.value}")
    assert not found, found


def test_a_driver_error_is_one_line_and_exit_3(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["capture", "--port", str(tmp_path / "no-such-port"), "-o", str(tmp_path / "x.csv")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == ExitCode.DEVICE and len(err) == 1 and "no such port" in err[0], err
