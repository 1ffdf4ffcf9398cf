"""The house's arrangement (docs/development/architecture.md), checked on the source.

- no import circle between modules, counting imports inside functions and under ``TYPE_CHECKING``
  (a circle is named module by module, each with the line that closes it);
- a subject package's private modules (``_name.py``) are imported by nothing outside it but the tests;
- each subject package names its public functions in its ``__init__`` (lazily, ``station.common.lazy``),
  and the names its type checkers see are the names it gives;
- the station's root holds the composition alone, and a module above ``LONG_LINES`` lines says why;
- the old module paths still import, with a DeprecationWarning, as the module that now holds the code;
- the "where does X live" table of the architecture page names every package, and only packages.
"""

from __future__ import annotations

import ast
import importlib
import re
import warnings
from pathlib import Path

import pytest
from test_layering import ROOT, imported_modules

from station.common.moved import MOVED

PACKAGES = ("protocols", "drivers", "mocks", "station")
# Outside the packages, what else may not reach into a private module.
OTHER_CODE = ("benchmarks", "scripts", "examples")
LONG_LINES = 500
LONG_REASON = "Why this module is long:"
ROOT_MODULES = {"__init__.py", "__main__.py", "cli.py", "errors.py"}
ARCHITECTURE = ROOT / "docs" / "development" / "architecture.md"


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}


def import_graph(modules: dict[str, Path]) -> dict[str, dict[str, int]]:
    """Module -> {imported project module: the line of its first import}, every import statement
    (function bodies and ``TYPE_CHECKING`` blocks too); a package's own submodules imported by its
    ``__init__`` are edges like any other."""
    graph: dict[str, dict[str, int]] = {}
    for name, path in modules.items():
        edges: dict[str, int] = {}
        for line, target in imported_modules(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if target in modules and target != name:
                edges.setdefault(target, line)
        graph[name] = edges
    return graph


def circles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def describe_circle(graph: dict[str, dict[str, int]], component: list[str]) -> str:
    """One path round the circle, each step as 'module (line N) -> module'."""
    members = set(component)
    start = component[0]
    path, seen = [start], {start}
    while True:
        here = path[-1]
        nxt = next((w for w in sorted(graph[here]) if w in members and (w == start or w not in seen)), None)
        if nxt is None or nxt == start:
            break
        path.append(nxt)
        seen.add(nxt)
    steps = [f"{a} (line {graph[a][b]})" for a, b in zip(path, path[1:] + [start], strict=True)]
    return " -> ".join(steps) + f" -> {start}"


def test_no_import_circles() -> None:
    graph = import_graph(_modules())
    found = [describe_circle(graph, c) for c in circles(graph)]
    assert not found, "modules that import each other:\n" + "\n".join(found)


def test_a_circle_is_named_with_its_lines() -> None:
    graph = {"a": {"b": 3}, "b": {"c": 7}, "c": {"a": 1}, "d": {"a": 2}}
    assert circles(graph) == [["a", "b", "c"]]
    assert describe_circle(graph, ["a", "b", "c"]) == "a (line 3) -> b (line 7) -> c (line 1) -> a"


def _private_owner(module: str) -> str | None:
    """The project package that owns ``module`` when one of its parts is private (``_name``), else None
    (another library's private modules are that library's business)."""
    parts = module.split(".")
    if parts[0] not in PACKAGES:
        return None
    for i, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            return ".".join(parts[:i])
    return None


def test_private_modules_stay_inside_their_package() -> None:
    found = []
    files = [p for package in PACKAGES + OTHER_CODE for p in (ROOT / package).rglob("*.py")]
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        importer = _module_name(path)
        for line, module in imported_modules(ast.parse(path.read_text(encoding="utf-8"))):
            owner = _private_owner(module)
            if owner is not None and not (importer == owner or importer.startswith(owner + ".")):
                found.append(f"{rel}:{line}: imports {module}, private to {owner}")
    assert not found, "private modules imported from outside their package:\n" + "\n".join(found)


def _lazy_packages() -> list[Path]:
    return sorted(p for p in (ROOT / "station").rglob("__init__.py") if "lazy_exports(" in p.read_text())


def test_the_subject_packages_name_their_public_functions() -> None:
    named = {_module_name(p) for p in _lazy_packages()}
    assert {"station.engines.allan", "station.engines.calibration", "station.engines.magnetometer",
            "station.engines.characterisation", "station.engines.thermal", "station.engines.shared"} <= named


@pytest.mark.parametrize("init", _lazy_packages(), ids=lambda p: _module_name(p))
def test_lazy_exports_are_what_type_checkers_see(init: Path) -> None:
    package = _module_name(init)
    tree = ast.parse(init.read_text())
    checked: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            for stmt in node.body:
                assert isinstance(stmt, ast.ImportFrom) and stmt.module
                for alias in stmt.names:
                    assert alias.asname == alias.name, f"{init}: re-export {alias.name} as itself"
                    checked[alias.name] = stmt.module.removeprefix(package + ".")
    module = importlib.import_module(package)
    assert sorted(checked) == module.__all__
    for name, where in checked.items():
        assert getattr(module, name) is getattr(importlib.import_module(f"{package}.{where}"), name)
    with pytest.raises(AttributeError, match=f"module '{package}' has no attribute 'no_such_name'"):
        module.no_such_name  # noqa: B018


def test_the_station_root_holds_the_composition_alone() -> None:
    loose = sorted(p.name for p in (ROOT / "station").glob("*.py") if p.name not in ROOT_MODULES)
    assert not loose, f"modules at the station's root besides the composition: {loose}; put each in a package"


def test_a_long_module_says_why() -> None:
    found = []
    for path in sorted(_modules().values()):
        lines = path.read_text(encoding="utf-8").count("\n")
        if lines > LONG_LINES and LONG_REASON not in (ast.get_docstring(ast.parse(path.read_text())) or ""):
            found.append(f"{path.relative_to(ROOT)}: {lines} lines")
    assert not found, (f"modules above {LONG_LINES} lines without '{LONG_REASON}' in their docstring (split "
                       "them, or say why one module is right):\n" + "\n".join(found))


@pytest.mark.parametrize(("old", "new"), sorted(MOVED.items()))
def test_an_old_module_path_warns_and_is_the_new_module(old: str, new: str) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
    assert module is importlib.import_module(new)
    assert module.__name__ == new and module.__spec__ is not None and module.__spec__.name == new
    if caught:  # the first import of the old name warns; a later one finds it in sys.modules
        assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught)


def test_an_old_module_path_warns_in_a_fresh_interpreter(tmp_path: Path) -> None:
    import subprocess
    import sys

    code = ("import warnings; warnings.simplefilter('error', DeprecationWarning)\n"
            "try:\n    import station.engines.calibration_turntable\nexcept DeprecationWarning as e:\n"
            "    print(e)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                          check=True, cwd=tmp_path)
    assert done.stdout.strip() == ("station.engines.calibration_turntable moved to "
                                   "station.engines.calibration.turntable; the old name goes in the next "
                                   "release")


def _where_table() -> dict[str, str]:
    text = ARCHITECTURE.read_text(encoding="utf-8")
    section = text.split("## Where does X live", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `([\w./]+)/` \| (.+?) \|$", section, re.M)
    return dict(rows)


def test_the_where_table_names_every_package() -> None:
    table = _where_table()
    packages = sorted(p.parent.relative_to(ROOT).as_posix() for package in PACKAGES
                      for p in (ROOT / package).rglob("__init__.py"))
    missing = [p for p in packages if p not in table]
    stale = [p for p in table if p not in packages]
    assert not missing and not stale, (f"{ARCHITECTURE.relative_to(ROOT)}: packages missing from the table "
                                       f"{missing}; rows naming no package {stale}")
