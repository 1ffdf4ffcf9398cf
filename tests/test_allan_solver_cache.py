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


def test_a_command_that_must_compile_says_why_it_waits(tmp_path: Path) -> None:
    # stopped once it said so: the compile itself takes half a minute
    import signal
    import time

    csv = tmp_path / "still.csv"
    rows = ["t,ax,ay,az,gx,gy,gz"] + [f"{k / 100:.2f},0,0,9.8,0.001,0,0" for k in range(6000)]
    csv.write_text("\n".join(rows) + "\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "COLUMNS": "200"}
    command = [str(Path(sys.executable).with_name("imu-station")), "allan", str(csv), "--force"]
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    said = ""
    deadline = time.monotonic() + 120
    assert proc.stderr is not None
    while "compiling the noise model's solver" not in said and time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        said += line
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=60)
    assert "compiling the noise model's solver, once per installation" in said, said


def test_setup_compiles_the_solver() -> None:
    setup = (ROOT / "scripts" / "setup").read_text(encoding="utf-8")
    assert "prepare_solver()" in setup and "solver_ready()" in setup
