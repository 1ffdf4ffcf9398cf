"""The model selection's compiled solver: ready once cached, reported cold where the cache is empty (a
command then says why it waits); ``./scripts/setup`` compiles it ahead of use."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from station.engines.allan import prepare_solver, solver_ready

ROOT = Path(__file__).resolve().parents[1]


def test_the_solver_is_ready_once_prepared() -> None:
    prepare_solver()  # loads from the cache ./scripts/setup filled (compiles if it is empty)
    assert solver_ready()


def test_an_empty_cache_is_reported_cold(tmp_path: Path) -> None:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", "from station.engines.allan import solver_ready; "
                           "print(solver_ready())"], env=env, capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


def test_setup_compiles_the_solver() -> None:
    setup = (ROOT / "scripts" / "setup").read_text(encoding="utf-8")
    assert "prepare_solver()" in setup and "solver_ready()" in setup
