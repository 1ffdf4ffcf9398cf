"""The wheel as a user installs it: built by pip, installed (not editable) outside the source tree,
run from a folder that is not the source tree, with the source tree on no import path.

The wheel is built from a copy of the files a build reads (the packages, pyproject.toml, README.md,
LICENSE) so that nothing left in the checkout (``build/``, egg-info) slips into it; it is installed
with ``pip install --no-deps --target`` and its dependencies come from the running environment.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
import uuid
import zipfile
from pathlib import Path

import pytest

import station

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("station", "drivers", "protocols", "mocks")

pytestmark = pytest.mark.timeout(240)


def _run(args: list[str], cwd: Path, env: dict[str, str],
         timeout: float = 120) -> subprocess.CompletedProcess:
    result = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{args} exited {result.returncode}:\n{result.stdout}\n{result.stderr}"
    return result


def _build_and_install(base: Path, env: dict[str, str]) -> None:
    src, dist, site = base / "src", base / "dist", base / "site"
    for name in PACKAGES:
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(REPO / name, src / name)
    start = time.monotonic()
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(src)], base, env,
         timeout=180)
    wheels = list(dist.glob("imu_station-*.whl"))
    assert len(wheels) == 1, wheels
    _run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheels[0])],
         base, env)
    print(f"wheel built and installed in {time.monotonic() - start:.1f} s")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    """Build the wheel, install it into a folder of its own; the environment that runs it from there.

    Under pytest-xdist the workers share one build (the first to take the lock makes it).
    """
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the folder every worker's own one is in
    base = root / "wheel"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSAFEPATH")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    with open(root / "wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (base / "built").exists():
            shutil.rmtree(base, ignore_errors=True)
            base.mkdir()
            _build_and_install(base, env)
            (base / "built").touch()
    wheel = next((base / "dist").glob("imu_station-*.whl"))
    site = base / "site"
    work = tmp_path_factory.mktemp("work")
    env["PYTHONPATH"] = str(site)
    env["PATH"] = f"{site / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return {"wheel": wheel, "site": site, "work": work, "env": env}


def test_wheel_holds_the_packages_and_the_version(installed) -> None:
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    assert installed["wheel"].name == f"imu_station-{station.__version__}-py3-none-any.whl"
    for package in PACKAGES:
        assert f"{package}/__init__.py" in names
    assert "station/__main__.py" in names
    # Every file of the packages ships (a style sheet, template or YAML added beside the code must be
    # declared as package data in pyproject.toml, or the installed station would not find it).
    sources = [p.relative_to(REPO).as_posix() for name in PACKAGES for p in (REPO / name).rglob("*")
               if p.is_file() and "__pycache__" not in p.parts]
    assert sorted(set(sources) - set(names)) == []
    assert not [n for n in names if n.startswith(("tests/", "examples/", "benchmarks/", "docs/"))]
    entry_points = [n for n in names if n.endswith("entry_points.txt")]
    text = zipfile.ZipFile(installed["wheel"]).read(entry_points[0]).decode()
    assert "imu-station = station.cli:main" in text


def test_installed_package_is_imported_from_its_install_folder_not_the_source_tree(installed) -> None:
    probe = ("import json, sys, drivers, mocks, protocols, station; "
             "print(json.dumps([m.__file__ for m in (station, drivers, protocols, mocks)] + [sys.path]))")
    out = json.loads(_run([sys.executable, "-c", probe], installed["work"], installed["env"]).stdout)
    *files, path = out
    site = installed["site"].resolve()
    for file in files:
        assert Path(file).resolve().is_relative_to(site), file
    # No import path but the install folder holds one of the packages (the source tree is on none).
    holders = [p for p in path if p and any((Path(p) / name / "__init__.py").exists() for name in PACKAGES)]
    assert [Path(p).resolve() for p in holders] == [site]
    assert str(REPO) not in path and "" not in path[1:]


def test_version_from_python_m_station_and_the_command(installed) -> None:
    expected = f"imu-station {station.__version__}"
    for command in ([sys.executable, "-m", "station", "--version"], ["imu-station", "--version"]):
        out = _run(command, installed["work"], installed["env"]).stdout.strip()
        assert out == expected, command


def test_demo_runs_from_the_installed_wheel(installed) -> None:
    out = installed["work"] / "demo"
    start = time.monotonic()
    command = ["imu-station", "demo", "--seconds", "1", "--hold", "2", "--speed", "50", "--out", str(out)]
    result = _run(command, installed["work"], installed["env"], timeout=180)
    elapsed = time.monotonic() - start
    assert "demo done in" in result.stdout and "Traceback" not in result.stderr
    for name in ("capture.h5", "sequence.h5", "params.yaml", "firmware/imu_calib.h", "firmware/imu_calib.c",
                 "firmware/imu_calib.bin"):
        assert (out / name).stat().st_size > 0, name
    print(f"demo from the installed wheel: {elapsed:.1f} s")


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed (apt-get install tmux)")
def test_tui_starts_connects_and_quits_in_a_real_terminal(installed) -> None:
    """``imu-station tui --simulate`` from the install folder in tmux: the connect screen, the simulated
    unit connected, Enter to the live view, q to quit (exit 0)."""
    work, env = installed["work"], installed["env"]
    status = work / "tui-exit-code"
    socket, session = f"imu-wheel-{uuid.uuid4().hex[:8]}", "tui"
    # tmux gives a new session the server's environment: the command sets its own.
    command = (f"env PYTHONPATH={env['PYTHONPATH']} PATH={env['PATH']} imu-station tui --simulate "
               f"--out {work / 'tui.yaml'}; echo $? > {status}")

    def tmux(*args: str) -> str:
        return subprocess.run(["tmux", "-L", socket, *args], check=True, capture_output=True, text=True,
                              env=env).stdout

    def wait_for(text: str, timeout_s: float = 60.0) -> str:
        deadline = time.monotonic() + timeout_s
        screen = ""
        while time.monotonic() < deadline:
            screen = tmux("capture-pane", "-p", "-t", session)
            if text in screen:
                return screen
            time.sleep(0.3)
        raise AssertionError(f"never saw {text!r}; last screen:\n{screen}")

    tmux("new-session", "-d", "-s", session, "-x", "120", "-y", "40", "-c", str(work), command)
    try:
        wait_for("imu-station · connect")
        screen = wait_for("Connected.")
        assert "SIM-000000" in screen
        tmux("send-keys", "-t", session, "Enter")
        wait_for("imu-station · live")
        tmux("send-keys", "-t", session, "q")
        deadline = time.monotonic() + 20
        while not status.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        subprocess.run(["tmux", "-L", socket, "kill-server"], capture_output=True)
    assert status.read_text().strip() == "0"
