"""Whole-process timing for the benchmarks that compare commands with other programs: wall and CPU seconds
of a child process (CPU from its own rusage, so a run on a shared machine still compares the work done),
and the child's peak resident memory."""

from __future__ import annotations

import os
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass
class ProcessRun:
    """One child process: wall seconds, CPU seconds (user + system), peak resident memory in bytes."""

    wall: float
    cpu: float
    peak: int


CLOCK_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a running process ``pid`` so far, every thread (``/proc/PID/stat``)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
        fields = fh.read().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) * CLOCK_TICK_S  # utime, stime: fields 14 and 15


PYCACHE = Path.home() / ".cache" / "imu-station" / "pycache"


def installed_env(**extra: str) -> dict[str, str]:
    """The environment with Python's bytecode cache on, as in an installed station (pip compiles the
    modules when it installs them): where PYTHONDONTWRITEBYTECODE is set (as in the development
    sessions), every run would compile the station's modules from source, 80 ms of CPU for a command.
    The cache goes to PYCACHE, outside the working tree; a first, untimed run fills it."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(PYCACHE)
    env.update(extra)
    return env


def run_process(cmd: list[str], env: dict[str, str] | None = None,
                cwd: str | Path | None = None) -> ProcessRun:
    """Run ``cmd`` to completion (it must succeed) in ``cwd``, output discarded; its wall time, CPU and
    peak RSS."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=cwd)
    assert proc.stderr is not None
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    proc.stderr.close()
    if proc.returncode != 0:
        message = err.decode(errors="replace")[-1000:]
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {message}")
    return ProcessRun(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024)
