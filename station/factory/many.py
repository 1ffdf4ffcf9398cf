"""Several units at once: one ``imu-station run`` process per unit, and a live summary table.

Each child writes its record to the shared database (SQLite in WAL mode takes several writers;
PostgreSQL is built for it), its JSON record on stdout and its progress as ``@event {json}``
lines on stderr, which feed the table; its other log lines go to a log file per unit. The
outcome of the whole is the worst of the units' (:data:`SEVERITY`). A unit whose record the
database did not take keeps its outcome; its ``record_pending`` event marks it in the table.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.text import Text

from station.common.text import printable
from station.errors import ExitCode

# Worst last: a configuration error says more about the line than a unit's failure does.
SEVERITY = (ExitCode.OK, ExitCode.OUT_OF_LIMITS, ExitCode.ABORTED, ExitCode.TIMEOUT, ExitCode.DEVICE,
            ExitCode.USAGE)
STOP_WAIT_S = 30.0  # after Ctrl-C, how long the children get to save their records
OUTCOME_NAMES: dict[int, str] = {
    ExitCode.OK: "PASS", ExitCode.OUT_OF_LIMITS: "FAIL", ExitCode.ABORTED: "ABORTED",
    ExitCode.DEVICE: "ERROR", ExitCode.USAGE: "USAGE", ExitCode.TIMEOUT: "TIMEOUT"}
STYLES = {"PASS": "bold green", "FAIL": "bold red", "ABORTED": "yellow", "ERROR": "bold magenta",
          "TIMEOUT": "magenta", "USAGE": "bold magenta"}


@dataclass
class UnitSpec:
    """One unit of a run-many: a real one (``port``, ``table_port``) or simulated (``seed``)."""

    label: str
    serial: str = "auto"
    port: str | None = None
    table_port: str | None = None
    table: str | None = None
    seed: int | None = None
    speed: float = 1.0

    def arguments(self) -> list[str]:
        """The unit's options of ``imu-station run``."""
        if self.seed is not None:
            return ["--simulate", "--seed", str(self.seed), "--speed", f"{self.speed:g}",
                    "--serial", self.serial]
        assert self.port is not None
        table = ["--table", self.table] if self.table is not None else \
            ["--table-port", self.table_port] if self.table_port is not None else []
        return ["--port", self.port, *table, "--serial", self.serial]


@dataclass
class UnitProgress:
    """What is known of one unit's run: its phase and step as the events tell, then its outcome."""

    spec: UnitSpec
    log_path: Path
    serial: str = ""
    phase: str = "starting"
    step: str = ""
    steps: str = ""
    started: float = field(default_factory=time.monotonic)
    ended: float | None = None
    exit_code: int | None = None
    reason: str = ""
    record: dict[str, Any] | None = None
    pending: str = ""
    """Where the unit's record is kept pending, when the database did not take it."""

    @property
    def outcome(self) -> str:
        """PASS, FAIL, ... from the exit code; ``running`` until the process ends."""
        if self.exit_code is None:
            return "running"
        return OUTCOME_NAMES.get(self.exit_code, f"exit {self.exit_code}")

    @property
    def elapsed_s(self) -> float:
        """Seconds since the unit's process started, up to its end."""
        return (self.ended or time.monotonic()) - self.started


def worst_exit_code(codes: list[int]) -> int:
    """The most severe exit code of the units (:data:`SEVERITY`; unknown codes rank worst).

    Parameters
    ----------
    codes : list of int
        The units' exit codes.

    Returns
    -------
    int
        The most severe, 0 when there is none.
    """
    rank: dict[int, int] = {code: i for i, code in enumerate(SEVERITY)}
    return max(codes, key=lambda c: rank.get(c, len(SEVERITY))) if codes else 0


def summary_table(units: list[UnitProgress], title: str) -> Table:
    """The live table: unit, serial, phase, step, time, outcome and detail of every unit.

    Parameters
    ----------
    units : list of UnitProgress
        Every unit's progress.
    title : str
        The table's title.

    Returns
    -------
    rich.table.Table
    """
    table = Table(title=title)
    for column in ("unit", "serial", "phase", "step", "time", "outcome", "detail"):
        table.add_column(column, justify="right" if column == "time" else "left")
    for u in units:
        outcome = u.outcome
        detail = ("record pending; " if u.pending else "") + u.reason
        # Labels, serials, steps and reasons come from the units and the plan: Text, never markup.
        table.add_row(Text(printable(u.spec.label)), Text(printable(u.serial or u.spec.serial)),
                      Text(printable(u.phase)), Text(printable(u.steps or u.step)), f"{u.elapsed_s:.0f} s",
                      Text(printable(outcome), style=STYLES.get(outcome, "")), Text(printable(detail, 60)))
    return table


class RunMany:
    """Start every unit's process, follow them, and return their progress once all ended."""

    def __init__(self, plan: Path, units: list[UnitSpec], common: list[str], log_dir: Path,
                 console: Console | None = None):
        self.plan = plan
        self.common = common
        self.console = console or Console(stderr=True)
        log_dir.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        self.units = [UnitProgress(spec, log_dir / f"{stamp}-{_safe(spec.label)}.log") for spec in units]
        self._lock = threading.Lock()

    def _command(self, spec: UnitSpec) -> list[str]:
        # The CLI loads only the command it runs, so each child imports the run command alone.
        return [sys.executable, "-m", "station.cli", "run", "--plan", str(self.plan), "--json", "--events",
                *self.common, *spec.arguments()]

    def run(self) -> list[UnitProgress]:
        """Run every unit to its end (Ctrl-C stops them, their records saved) and return them."""
        procs = []
        for unit in self.units:
            log = unit.log_path.open("w", encoding="utf-8")
            proc = subprocess.Popen(self._command(unit.spec), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, bufsize=1)
            readers = [threading.Thread(target=self._follow, args=(unit, proc.stderr, log), daemon=True),
                       threading.Thread(target=self._collect, args=(unit, proc.stdout), daemon=True)]
            for r in readers:
                r.start()
            procs.append((unit, proc, readers, log))
        title = f"imu-station run-many: {self.plan.name}, {len(self.units)} units"
        with Live(summary_table(self.units, title), console=self.console, refresh_per_second=4,
                  transient=False) as live:
            try:
                self._follow_all(procs, live, title)
            except KeyboardInterrupt:
                # Ctrl-C reached every child too (one process group): each records its unit as
                # aborted. Wait for those records, then stop whatever still runs.
                deadline = time.monotonic() + STOP_WAIT_S
                while any(p.poll() is None for _, p, _, _ in procs) and time.monotonic() < deadline:
                    time.sleep(0.1)
                for _, proc, _, _ in procs:
                    if proc.poll() is None:
                        proc.terminate()
                        proc.wait()
            for unit, proc, readers, log in procs:
                for r in readers:
                    r.join(timeout=5.0)
                log.close()
                with self._lock:
                    unit.exit_code = proc.returncode
                    unit.ended = unit.ended or time.monotonic()
                    if unit.record is not None:
                        unit.reason = unit.record.get("reason", "")
                        unit.serial = unit.record.get("serial", unit.serial)
            live.update(summary_table(self.units, title))
        return self.units

    def _follow_all(self, procs: list, live: Live, title: str) -> None:
        while any(p.poll() is None for _, p, _, _ in procs):
            with self._lock:
                live.update(summary_table(self.units, title))
            time.sleep(0.25)

    def _follow(self, unit: UnitProgress, stream: IO[str], log: IO[str]) -> None:
        for line in stream:
            if line.startswith("@event "):
                try:
                    self._apply(unit, json.loads(line[7:]))
                except json.JSONDecodeError:
                    log.write(line)
                continue
            log.write(line)
            log.flush()
            if "error:" in line:
                with self._lock:
                    unit.reason = line.split("error:", 1)[1].strip()

    def _apply(self, unit: UnitProgress, event: dict[str, Any]) -> None:
        with self._lock:
            unit.serial = event.get("serial", unit.serial)
            kind = event.get("event")
            if kind == "phase":
                unit.phase, unit.steps = event["phase"], ""
            elif kind == "step":
                unit.step = event["label"]
                unit.steps = f"{event['label']} ({event['index'] + 1}/{event['total']})"
            elif kind == "record_pending":
                unit.pending = str(event.get("path", ""))
            elif kind == "outcome":
                unit.phase = "done"
                unit.reason = event.get("reason", "")
                unit.ended = time.monotonic()

    def _collect(self, unit: UnitProgress, stream: IO[str]) -> None:
        text = stream.read()
        try:
            record = json.loads(text) if text.strip() else None
        except json.JSONDecodeError:
            record = None
        with self._lock:
            unit.record = record


def _safe(text: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in text).strip("._") or "unit"
