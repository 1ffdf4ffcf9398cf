"""Hostile YAML is refused quickly and within bounded memory, by the one reader every YAML input
goes through (``station.common.yaml_file``): parameter files (``export``, the merge of ``calibrate``,
``allan`` and ``thermal``), sequence files and plan files.
"""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from station import cli
from station.acquisition.sequences import load_yaml
from station.common.yaml_file import MAX_BYTES, MAX_DEPTH, MAX_NODES, read_yaml
from station.errors import InputFileError
from station.export.params.file import ParamsFile
from station.factory.plan import load_plan

MEMORY_BOUND = 32 * 2**20  # bytes of Python allocations while refusing


def billion_laughs(top: str) -> str:
    """Nine levels of nine aliases each: 3.9 kB that a plain safe_load expands to 9^9 strings."""
    lines = [top, 'l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for level in range(1, 10):
        lines.append(f"l{level}: &l{level} [" + ", ".join([f"*l{level - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def refused_quickly(load: Callable[[Path], Any], path: Path) -> InputFileError:
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(InputFileError) as info:
            load(path)
        elapsed = time.perf_counter() - start
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert elapsed < 1.0, f"{elapsed:.2f} s"
    assert peak < MEMORY_BOUND, f"{peak / 2**20:.1f} MiB"
    assert "\n" not in str(info.value) and str(path) in str(info.value)
    return info.value


LOADERS: dict[str, tuple[str, Callable[[Path], Any]]] = {
    "params": ("schema: imu-station/params/1", ParamsFile.load),
    "merge": ("schema: imu-station/params/1", ParamsFile.load_or_new),
    "sequence": ("name: a", load_yaml),
    "plan": ("schema: imu-station/plan/1", load_plan),
}


@pytest.mark.parametrize("kind", LOADERS)
def test_billion_laughs_refused(tmp_path: Path, kind: str) -> None:
    top, load = LOADERS[kind]
    path = tmp_path / "laughs.yaml"
    path.write_text(billion_laughs(top))
    assert path.stat().st_size < 4000
    error = refused_quickly(load, path)
    assert f"expands to more than {MAX_NODES} values" in str(error)
    assert error.line is not None


@pytest.mark.parametrize("kind", LOADERS)
def test_a_100_mb_list_refused_before_it_is_read(tmp_path: Path, kind: str) -> None:
    top, load = LOADERS[kind]
    path = tmp_path / "big.yaml"
    chunk = b"  - 1.0\n" * 65536
    with path.open("wb") as fh:
        fh.write(top.encode() + b"\nsteps:\n")
        for _ in range(100 * 2**20 // len(chunk)):
            fh.write(chunk)
    error = refused_quickly(load, path)
    assert f"larger than {MAX_BYTES // 1024} KiB" in str(error)


@pytest.mark.parametrize(("text", "line", "words"), [
    ("a: " + "[" * 100_000 + "]" * 100_000 + "\n", 1, f"nests deeper than {MAX_DEPTH} levels"),
    ("a: &a [1, *a]\n", 1, "alias *a refers to a node that contains it"),
    ("a: &a\n  b: 1\n  <<: *a\n", 3, "alias *a refers to a node that contains it"),
    ("a: [" + ", ".join(["1"] * (MAX_NODES + 10)) + "]\n", 1, f"more than {MAX_NODES} values"),
    ("a: 1\nb: !!binary aGVsbG8=\n", 2, "tag !!binary is not read here"),
    ("a: !!set {x, y}\n", 1, "tag !!set is not read here"),
])
def test_other_hostile_documents(tmp_path: Path, text: str, line: int, words: str) -> None:
    path = tmp_path / "hostile.yaml"
    path.write_text(text)
    with pytest.raises(InputFileError) as info:
        read_yaml(path, "missing").construct()
    assert words in str(info.value)
    assert info.value.line == line


def test_export_of_a_hostile_parameter_file_exits_4(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "laughs.yaml"
    path.write_text(billion_laughs("schema: imu-station/params/1"))
    for fmt in ("yaml", "json"):
        start = time.perf_counter()
        code = cli.main(["export", str(path), "-f", fmt, "-o", str(tmp_path / f"out.{fmt}")])
        assert time.perf_counter() - start < 1.0
        err = capsys.readouterr().err
        assert code == 4 and err.count("\n") == 1 and "expands to more than" in err, err
        assert not (tmp_path / f"out.{fmt}").exists()


@pytest.mark.parametrize(("text", "line", "words"), [
    (b"schema: imu-station/params/1\ncreated: \x1b[2J\n", 2, "character U+001B is not allowed"),
    (b"schema: imu-station/params/1\ndevice:\n  serial: \xff\n", 3, "is not UTF-8 text"),
    (b"schema: imu-station/params/1\n---\nschema: x\n", 2, "a single document in the stream, but found"),
    (b"schema: imu-station/params/1\na: &x 1\nb: &x 2\n", 3, "found duplicate anchor 'x'"),
    (b"schema: imu-station/params/1\nunits: {accel: [\n", 3, "while parsing a flow"),
])
def test_yaml_errors_are_one_line_with_the_line_number(tmp_path: Path, text: bytes, line: int,
                                                       words: str) -> None:
    path = tmp_path / "broken.yaml"
    path.write_bytes(text)
    with pytest.raises(InputFileError) as info:
        ParamsFile.load(path)
    message = str(info.value)
    assert "\n" not in message and words in message, message
    assert info.value.line == line
