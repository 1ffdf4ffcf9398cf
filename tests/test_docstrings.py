"""Every public module-level function and class, and every public method of a public class, in
protocols, drivers, mocks and station has a docstring (the project's rule; numpydoc style).

Public means not underscore-prefixed (dunder methods included among the private); a property's
setter or deleter shares its getter's docstring, and ``typing.overload`` stubs are left out.
The source is read with ``ast``, so nothing is imported and every file is checked.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("protocols", "drivers", "mocks", "station")
Definition = ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef


def _exempt(node: Definition) -> bool:
    decorators = [ast.unparse(d) for d in node.decorator_list]
    return node.name.startswith("_") or any(
        d.endswith((".setter", ".deleter")) or d in ("overload", "typing.overload") for d in decorators)


def public_definitions(tree: ast.Module) -> list[tuple[str, Definition]]:
    """Qualified name and node of every public function, class and method of a public class."""
    found: list[tuple[str, Definition]] = []

    def walk(body: list[ast.stmt], prefix: str) -> None:
        for node in body:
            if isinstance(node, Definition) and not _exempt(node):
                found.append((prefix + node.name, node))
                if isinstance(node, ast.ClassDef):
                    walk(node.body, f"{prefix}{node.name}.")

    walk(tree.body, "")
    return found


def missing_docstrings(root: Path, packages: tuple[str, ...] = PACKAGES) -> list[str]:
    """``path:line name`` of every public definition under ``root/packages`` without a docstring."""
    missing = []
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for name, node in public_definitions(tree):
                if ast.get_docstring(node) is None:
                    missing.append(f"{path.relative_to(root)}:{node.lineno} {name}")
    return missing


def test_the_rule_sees_what_it_should(tmp_path: Path) -> None:
    """The walker flags public functions, classes and methods, and leaves private ones, dunders,
    setters, overloads and nested functions alone."""
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "mod.py").write_text('''
from typing import overload

def bare(): pass
def _private(): pass
def documented():
    """Doc."""
    def inner(): pass
class Bare:
    def method(self): pass
    def __init__(self): pass
    @property
    def value(self):
        """Doc."""
    @value.setter
    def value(self, v): pass
class _Hidden:
    def method(self): pass
@overload
def twice(x: int) -> int: ...
''')
    assert missing_docstrings(tmp_path, ("pkg",)) == [
        "pkg/mod.py:4 bare", "pkg/mod.py:9 Bare", "pkg/mod.py:10 Bare.method"]


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_definition_has_a_docstring(package: str) -> None:
    missing = missing_docstrings(REPO, (package,))
    assert not missing, f"{len(missing)} public definitions without a docstring:\n" + "\n".join(missing)
