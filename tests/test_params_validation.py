"""Parameter files are checked against the schema on read: a bad one is refused with one line naming
file, key, line and unit (exit 4), never a traceback, and nothing the export writes from an accepted
one is refused by its own loader or by gcc.

The fuzz test runs a seeded mutator over a valid parameter file (wrong types, booleans, NaN and
infinities, huge values, wrong shapes, missing keys, cut or damaged text) through
``imu-station export`` in every format and ``imu-station apply``, in process.
"""

from __future__ import annotations

import copy
import json
import math
import shutil
import subprocess
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from export_params import make_params

from station import cli
from station.acquisition.capture import Capture
from station.acquisition.capture_csv import read_csv, write_csv
from station.errors import InputFileError
from station.export.firmware.blob import parse_blob
from station.export.params.file import ParamsFile

N_FILES = 240
FORMATS = ("c", "bin", "json", "yaml", "px4", "ardupilot")
CC = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-fsyntax-only"]
WEIRD: list[Any] = [True, False, None, math.nan, math.inf, -math.inf, 1e30, -1e30, 1e300, 10**400, -(10**25),
                    0, -1, "x", "1.5", [], [1, 2], {}, {"a": 1}, [[1, 2, 3]] * 3, [1.0] * 4, 3.4e38, 1e-320]


def valid_doc() -> dict[str, Any]:
    params = make_params(seed=7)
    params.noise = {
        "accel": {"N": [1e-3, 1.1e-3, 9e-4], "K": None, "B": [2e-4, 2e-4, 3e-4], "Q": None, "R": None,
                  "stddev": {"N": [1e-5, 1e-5, 1e-5], "B": None}},
        "gyro": {"N": [1e-4, 1e-4, 1e-4], "K": [1e-6, None, 1e-6], "B": [5e-6] * 3, "Q": None, "R": None},
    }
    return params.to_dict()


def dump(doc: Any) -> str:
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


def paths_in(node: Any, path: tuple = ()) -> list[tuple]:
    out = [path]
    if isinstance(node, dict):
        for key, value in node.items():
            out += paths_in(value, (*path, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += paths_in(value, (*path, i))
    return out


def mutate(doc: dict[str, Any], rng: np.random.Generator) -> str:
    """One or two changes to the document, then at times a cut or a foreign character in its text."""
    doc = copy.deepcopy(doc)
    for _ in range(int(rng.integers(1, 3))):
        paths = [p for p in paths_in(doc) if p]
        *parents, key = paths[int(rng.integers(0, len(paths)))]
        parent: Any = doc
        for k in parents:
            parent = parent[k]
        roll = rng.random()
        value = parent[key]
        if roll < 0.15 and isinstance(parent, dict):
            del parent[key]
        elif roll < 0.25 and isinstance(value, list) and value:
            parent[key] = value[:-1] if rng.random() < 0.5 else [*value, value[-1]]
        elif roll < 0.4 and isinstance(value, int | float) and not isinstance(value, bool):
            parent[key] = value * float(rng.choice([-1.0, 1e6, 1e12, 1e-12, 0.0]))
        else:
            parent[key] = copy.deepcopy(WEIRD[int(rng.integers(0, len(WEIRD)))])
    text = dump(doc)
    roll = rng.random()
    if roll < 0.05:
        text = text[: int(rng.integers(0, len(text)))]
    elif roll < 0.1:
        at = int(rng.integers(0, len(text)))
        text = text[:at] + str(rng.choice(["\0", "\x01", "\x1b", ":", "[", "&a", "*b", "\t"])) + text[at:]
    return text


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = cli.main(argv)
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def capture_csv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("capture") / "raw.csv"
    rng = np.random.default_rng(1)
    n = 40
    write_csv(path, Capture(t=np.arange(n) * 0.01, acc=rng.normal(0, 5, (n, 3)),
                            gyro=rng.normal(0, 1, (n, 3)), temp=np.linspace(-20.0, 70.0, n)))
    return path


def check_outputs(fmt: str, out: Path) -> None:
    """What a successful export wrote loads where it is meant to (the C is compiled afterwards)."""
    if fmt == "c":
        parse_blob((out / "imu_calib.bin").read_bytes())
    elif fmt == "bin":
        parse_blob(out.read_bytes())
    elif fmt == "json":
        json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{out}: {c} in the JSON"))
    elif fmt == "yaml":
        ParamsFile.load(out)
    else:
        text = out.read_text().lower()
        assert "nan" not in text and "inf" not in text, text


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc compiles the C exports")
def test_mutated_parameter_files_exit_0_or_4_and_export_only_what_loads(
        tmp_path: Path, capture_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(22)
    base = valid_doc()
    outcomes: Counter[tuple[str, int]] = Counter()
    c_sources = []
    for i in range(N_FILES):
        params = tmp_path / f"p{i}.yaml"
        params.write_text(mutate(base, rng), encoding="utf-8")
        fmt = FORMATS[i % len(FORMATS)]
        out = tmp_path / (f"c{i}" if fmt == "c" else f"o{i}.{fmt}")
        argv = ["export", str(params), "-f", fmt, "-o", str(out), "--station-id", "fuzz"]
        code, err = run_cli(argv, capsys)
        outcomes[("export", code)] += 1
        assert code in (0, 4), err
        if code == 0:
            check_outputs(fmt, out)
            if fmt == "c":
                c_sources.append(str(out / "imu_calib.c"))
        else:
            assert err.count("\n") == 1 and str(params) in err, err
        argv = ["apply", str(params), str(capture_csv), "-o", str(tmp_path / f"a{i}.csv")]
        code, err = run_cli(argv, capsys)
        outcomes[("apply", code)] += 1
        assert code in (0, 4), err
        if code == 0:
            assert np.all(np.isfinite(read_csv(tmp_path / f"a{i}.csv").acc))
    # Both outcomes are exercised, and every accepted C export compiles (one gcc run for all of them:
    # each source includes the header beside it).
    assert outcomes[("export", 0)] > 20 and outcomes[("export", 4)] > 100, outcomes
    assert len(c_sources) > 3
    proc = subprocess.run([*CC, *c_sources], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[:2000]


def write(tmp_path: Path, doc: Any) -> Path:
    path = tmp_path / "unit.yaml"
    path.write_text(dump(doc), encoding="utf-8")
    return path


def line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


@pytest.mark.parametrize(("where", "value", "words"), [
    (("accel", "bias", 1), True, "must be a number (m/s^2), not true"),
    (("gyro", "bias", 0), -1e30, "outside the plausible range"),
    (("accel", "matrix", 2, 2), math.nan, "nan"),
    (("gyro", "matrix", 0, 0), math.inf, "inf"),
    (("accel", "bias", 2), 10**400, "outside the plausible range"),
    (("thermal", "reference_temp"), 1e6, "degC"),
    (("thermal", "dtemp_filter", "tau_s"), -3.0, "0..100000 s"),
    (("thermal", "accel", "segments", 1, "t_min"), 0.0, "before the previous one ends"),
    (("thermal", "gyro", "segments", 0, "coeffs"), [[0.0] * 7] * 2, "must be a list of 3 lists"),
    (("thermal", "gyro", "clamp", "dtemp"), [1.0, -1.0], "not a range"),
    (("thermal", "gyro", "temp_sensitivity_sd"), [1e-5, "x", 1e-5], "must be a number"),
    (("thermal", "accel", "temp_sensitivity_sd"), [1e-5, -1e-5, 1e-5], "negative"),
    (("noise", "gyro", "N"), [1e-4, -1e-4, 1e-4], "negative"),
    (("units", "accel"), "g", "this station reads accel in m/s^2"),
    (("accel", "matrix"), [[1, 0, 0], [0, 1, 0], [0, 0, 1e-9]], "singular"),
    (("device", "serial"), ["a"], "must be text"),
    (("device", "accel_device_id"), "2228242", "must be a sensor's device id"),
    (("device", "gyro_device_id"), -1, "must be a sensor's device id"),
])
def test_each_bad_value_is_named_with_key_line_and_unit(tmp_path: Path, where: tuple, value: Any,
                                                        words: str) -> None:
    doc = valid_doc()
    parent: Any = doc
    for key in where[:-1]:
        parent = parent[key]
    parent[where[-1]] = value
    path = write(tmp_path, doc)
    with pytest.raises(InputFileError) as info:
        ParamsFile.load(path)
    message = str(info.value)
    assert words in message, message
    assert "\n" not in message and message.startswith(f"{path}, line ")
    key = "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in where).lstrip(".")
    assert info.value.column is not None and info.value.column.startswith(key), message
    assert info.value.line is not None


def test_the_line_is_the_line_of_the_key(tmp_path: Path) -> None:
    doc = valid_doc()
    doc["thermal"]["reference_temp"] = True
    path = write(tmp_path, doc)
    with pytest.raises(InputFileError) as info:
        ParamsFile.load(path)
    assert info.value.line == line_of(path, "reference_temp:")
    assert info.value.column == "thermal.reference_temp"


def test_missing_keys_and_wrong_section_types(tmp_path: Path) -> None:
    doc = valid_doc()
    del doc["gyro"]["bias"]
    with pytest.raises(InputFileError, match="section 'gyro' lacks the required key 'bias'"):
        ParamsFile.load(write(tmp_path, doc))
    doc = valid_doc()
    doc["thermal"] = [1, 2]
    with pytest.raises(InputFileError, match="column 'thermal': must be a mapping"):
        ParamsFile.load(write(tmp_path, doc))


def test_every_command_that_reads_a_params_file_exits_4_in_one_line(
        tmp_path: Path, capture_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    doc = valid_doc()
    doc["accel"]["bias"][0] = math.nan
    path = write(tmp_path, doc)
    for argv in (["export", str(path), "-f", "c", "-o", str(tmp_path / "c")],
                 ["export", str(path), "-f", "json", "-o", str(tmp_path / "x.json")],
                 ["apply", str(path), str(capture_csv), "-o", str(tmp_path / "o.csv")]):
        code, err = run_cli(argv, capsys)
        assert code == 4, err
        assert err.count("\n") == 1
        assert f"{path}, line {line_of(path, 'bias:')}, column 'accel.bias[0]'" in err
    assert not (tmp_path / "c").exists() and not (tmp_path / "o.csv").exists()


def test_a_valid_file_reads_as_before(tmp_path: Path) -> None:
    doc = valid_doc()
    path = write(tmp_path, doc)
    back = ParamsFile.load(path)
    assert back.accel is not None and np.array_equal(back.accel.matrix, np.asarray(doc["accel"]["matrix"]))
    assert back.created == "2026-11-22T10:00:00Z"
    assert back.to_dict() == ParamsFile.from_dict(doc).to_dict()
