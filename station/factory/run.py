"""One unattended run of one unit: connect, sequence on the table, calibrate, judge, export, record.

Phases, in order (each a phase of the record, OpenHTF style)::

    instruments  where the plan names them: open the chamber, table and supply within the plan's
               limits, identify each, set the supply and switch it on (``station.instruments``)
    connect    open the unit's port, ask who it is, set the plan's rate (a board streaming its own
               frames, protocol frame:FILE.yaml, is asked nothing: its serial is given); open the
               table (the plan's rate table, through the mount, or the station's own), home it
    soak       where the plan gives the chamber a soak_c: the setpoint, until the unit's own
               temperature has settled (``station.acquisition.settle``; TIMEOUT if it does not)
    sequence   the plan's sequence through the sequence runner, the table placing and turning
               the unit; the labelled raw capture is streamed to capture.csv beside the record
    calibrate  the engine on the capture; parameters measured against the plan's limits
    export     params.yaml and the plan's export formats, beside the record

A run that got to its export phase (PASS or FAIL: the unit was calibrated) ends by writing the
unit's calibration certificate beside the record (``certificate.html``, ``station.report``),
attached to the export phase with its SHA-256 like every other file; a run cut short before has
no calibration to certify.

Outcome and exit code: PASS 0, FAIL 1 (a measurement outside its limits, or the unit reports
another serial), ABORTED 2 (a step kept failing its checks, the calibration could not be
determined, Ctrl-C), ERROR 3 (device, table or link error), TIMEOUT 5 (the plan's run or step
time was exceeded). Whatever happens, the record is saved with every file written so far, with
``instruments.json`` (the instruments' identities and every command and reply with its time)
where the plan names instruments. A run cut short (ABORTED, ERROR, TIMEOUT, Ctrl-C, SIGTERM)
leaves the instruments as the plan's ``on_abort`` says.

Why this module is long: ``UnitRun`` is the run's state machine (phases, stop reasons,
the record it fills); its phases read and write the same record and log, so they are methods of
one object, and the operators that drive a table or the simulated rig are its two plugs.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import logging
import re
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.errors import CommandUnsupported, DriverError
from drivers.interface import Device
from drivers.paced_port import open_paced
from drivers.turntable import Turntable
from protocols.units import STANDARD_GRAVITY
from station.acquisition.operator import Action, BaseOperator, Operator, Prompt, SimulatedOperator
from station.acquisition.recorder import Recorder
from station.acquisition.runner import RecorderSink, RunOptions, RunResult, SequenceRunner
from station.acquisition.sequences import PoseStep, RotationStep, Sequence, Step
from station.acquisition.settle import Settle, SettleTimeout, wait_settled
from station.common.files import atomic_write_text
from station.common.text import printable, printable_message
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.engines.shared.earth import normal_gravity
from station.errors import StationError
from station.export.params.file import ParamsFile
from station.export.writers import DEFAULT_NAMES, write_export
from station.factory.measure import measure
from station.factory.plan import Plan
from station.factory.records import (
    Attachment,
    Measurement,
    Phase,
    RunRecord,
    sha256_file,
    utc_now,
)
from station.factory.simrig import SimulatedUnit, simulated_rig
from station.instruments.bench import Bench, open_bench
from station.instruments.mounted_table import MountedTable, PoseTable
from station.report.attachments import CERTIFICATE_NAME, PARAMS_ATTACHMENT, RAW_CAPTURE
from station.report.certificate import CaptureFile, from_record, write_certificate

log = logging.getLogger("imu_station.factory")

EventSink = Callable[[dict[str, Any]], None]
CALIBRATION_QUANTITIES = [
    "accel.bias", "accel.scale_error", "accel.misalignment", "accel.residual_rms",
    "gyro.bias", "gyro.scale_error", "gyro.misalignment", "gyro.residual_rms",
]
MIMETYPES = {".csv": "text/csv", ".yaml": "application/yaml", ".json": "application/json",
             ".h": "text/x-c", ".c": "text/x-c", ".bin": "application/octet-stream",
             ".params": "text/plain", ".param": "text/plain", ".html": "text/html"}
_SAFE = re.compile(r"[^A-Za-z0-9._-]+")


class TableOperator(BaseOperator):
    """The motorized table as the runner's operator: places the unit for each step and turns it.

    A table error does not escape into the runner: it is kept in :attr:`error` and the next
    :meth:`poll` aborts the run, so the samples captured so far are kept.
    """

    def __init__(self, table: PoseTable, timeout_s: float = 30.0):
        # The station's own turntable, or any rate table through station.instruments.mounted_table.
        self.table = table
        self.timeout_s = timeout_s
        self.error: DriverError | None = None

    def _do(self, what: Callable[[], None]) -> None:
        if self.error is not None:
            return
        try:
            what()
        except DriverError as exc:
            self.error = exc

    def place(self, step: Step, index: int, total: int) -> None:
        """Turn the table to the step's pose (a rotation's start pose)."""
        pose = step.label if isinstance(step, PoseStep) else step.start_pose
        self._do(lambda: self.table.pose(pose, self.timeout_s))

    def rotate(self, step: RotationStep) -> None:
        """Turn the table about the step's axis by its angle at its rate."""
        self._do(lambda: self.table.rotate("+" + "xyz"[step.axis], step.angle_deg, step.rate_dps,
                                           self.timeout_s))

    def poll(self) -> Action | None:
        """Abort the run once the table has failed (a mounted table's turn fails in its own thread)."""
        if self.error is None:
            self.error = getattr(self.table, "error", None)
        return Action.ABORT if self.error is not None else None

    def stop(self) -> None:
        """Bring the table to rest at once (abort, Ctrl-C)."""
        self.table.stop()


class FactoryOperator(BaseOperator):
    """Nobody answers prompts on a line: start, retry a failed step while attempts last, then abort.

    Wraps the operator that moves the unit (a table, a scripted fixture) and passes every event
    on; aborts the run when ``deadline`` (time.monotonic) passes, or the inner operator asks.
    """

    def __init__(self, inner: Operator, deadline: float, on_event: EventSink | None = None):
        self.inner = inner
        self.deadline = deadline
        self.on_event = on_event
        self.timed_out = False

    def _event(self, **kw: Any) -> None:
        if self.on_event is not None:
            self.on_event(kw)

    def begin(self, sequence: Sequence) -> None:
        """Pass the start on, and report the sequence as an event."""
        self.inner.begin(sequence)
        self._event(event="sequence", name=sequence.name, steps=len(sequence))

    def place(self, step: Step, index: int, total: int) -> None:
        """Log and report the step, then let the inner operator place the unit."""
        log.info("step %d/%d: %s", index + 1, total, step.label)
        self._event(event="step", label=step.label, index=index, total=total)
        self.inner.place(step, index, total)

    def rotate(self, step: RotationStep) -> None:
        """Let the inner operator turn the unit."""
        self.inner.rotate(step)

    def status(self, status: Any) -> None:
        """Pass the live status on."""
        self.inner.status(status)

    def poll(self) -> Action | None:
        """Abort when the run's deadline has passed, else whatever the inner operator asks."""
        if time.monotonic() > self.deadline:
            self.timed_out = True
            return Action.ABORT
        return self.inner.poll()

    def confirm(self, prompt: Prompt) -> Action:
        """Start at once, redo a failed step while the runner offers it, abort on anything else."""
        if prompt.kind == "start":
            return Action.ACCEPT
        if prompt.kind == "review" and Action.REDO in prompt.choices:
            label = prompt.step.label if prompt.step else ""
            log.warning("step %s failed its checks (%s): trying again", label, "; ".join(prompt.details))
            return Action.REDO
        log.warning("%s", prompt.text)
        return Action.ABORT

    def step_finished(self, record: Any) -> None:
        """Pass the step's record on, and report it as an event."""
        self.inner.step_finished(record)
        self._event(event="step_done", label=record.label, status=record.status, attempts=record.attempts)

    def end(self, result: RunResult) -> None:
        """Pass the end of the run on."""
        self.inner.end(result)


@dataclass
class RunRequest:
    """One unit to run. Give ``port`` and ``table_port``, or ``port`` and ``operator`` (a manual
    fixture driven by a factory script), or ``simulate``."""

    plan: Plan
    serial: str = "auto"
    station: str = "station"
    port: str | None = None
    table_port: str | None = None
    operator: Operator | None = None
    simulate: SimulatedUnit | None = None
    files_root: Path = Path("imu-station-files")
    on_event: EventSink | None = None
    resume: Path | None = None
    """A campaign's run folder to carry on from its journal (``station.factory.campaign``)."""


class _Stop(Exception):
    """Ends the run early with an outcome (the record is still completed and saved)."""

    def __init__(self, outcome: str, reason: str):
        super().__init__(reason)
        self.outcome = outcome
        self.reason = reason


def _dir_name(text: str) -> str:
    return _SAFE.sub("_", text).strip("._") or "unknown"


class UnitRun:
    """Runs :class:`RunRequest` into a :class:`RunRecord` (see the module docstring)."""

    def __init__(self, request: RunRequest):
        self.req = request
        plan = request.plan
        self.record = RunRecord(serial=request.serial, station=request.station,
                                plan={"name": plan.name, "path": str(plan.path), "sha256": plan.sha256,
                                      "sequence": plan.sequence.name})
        self.deadline = time.monotonic() + plan.timeout_s
        self.capture: Any = None  # the sequence's labelled capture, for the certificate's residuals
        self.device: Device | None = None
        self.table: PoseTable | None = None
        self.bench: Bench | None = None
        self._instruments_phase: Phase | None = None
        self._identities: dict[str, dict[str, str]] = {}
        self.files: Path | None = None
        # The simulated unit's clock pace, settable while it runs (None on real instruments).
        self.pace: Callable[[float], None] | None = None

    def _event(self, **kw: Any) -> None:
        if self.req.on_event is not None:
            self.req.on_event({"serial": self.record.serial, **kw})

    def _phase(self, name: str) -> Phase:
        phase = Phase(name)
        self.record.phases.append(phase)
        log.info("phase %s", name)
        self._event(event="phase", phase=name)
        return phase

    def _attach(self, phase: Phase, path: Path, name: str | None = None) -> None:
        assert self.files is not None
        rel = path.relative_to(self.files)
        phase.attachments.append(Attachment(name or str(rel), str(rel), sha256_file(path),
                                            path.stat().st_size,
                                            MIMETYPES.get(path.suffix, "application/octet-stream")))

    def _check_time(self, phase: Phase) -> None:
        if time.monotonic() > self.deadline:
            phase.outcome = "ERROR"
            raise _Stop("TIMEOUT", f"the run took longer than the plan's timeout_s "
                        f"({self.req.plan.timeout_s:g} s)")

    def execute(self) -> RunRecord:
        """Run every phase; whatever happens, finish the record and write record.json beside it.

        Returns
        -------
        RunRecord
            The run's record, with its outcome and exit code.

        Raises
        ------
        StationError
            A request with neither ports nor a simulation, or a unit that reports no serial
            number when ``serial`` is ``auto``.
        """
        outcome, reason = "ERROR", ""
        instruments = self.req.plan.instruments
        no_table = self.req.table_port is None and (instruments is None or instruments.table is None)
        if self.req.simulate is None and (self.req.port is None or (self.req.operator is None and no_table)):
            raise StationError("give the unit's --port and the turntable's --table-port (or a table in the "
                               "plan's instruments), or --simulate (a manual fixture is driven from a "
                               "factory script: the Python API with a ScriptedOperator)")
        check_serial(self.req)
        try:
            if self.req.simulate is not None:
                serial = self.req.serial if self.req.serial != "auto" else f"SIM-{self.req.simulate.seed:06d}"
                if not self.req.plan.asks_serial:  # a board that cannot be asked: the simulation names it
                    self.record.serial = serial
                    _log_serial(printable(serial))
                kinds = list(instruments.urls()) if instruments is not None else []
                with simulated_rig(self.req.simulate, serial, self.req.plan.rate_hz,
                                   self.req.plan.protocol, instruments=kinds) as ports:
                    self.pace = ports.pace
                    if self.req.operator is not None:
                        # A manual fixture in simulation: a simulated hand does what the script asks.
                        self.req.operator = SimulatedOperator(ports.rig, self.req.operator)
                    with self._instruments(ports.instruments):
                        outcome, reason = self._run(ports.port, ports.table_port)
                        self._leave_safe_unless_done(outcome)
            else:
                assert self.req.port is not None  # a request without one was refused above
                with self._instruments({}):
                    outcome, reason = self._run(self.req.port, self.req.table_port)
                    self._leave_safe_unless_done(outcome)
        except _Stop as stop:
            outcome, reason = stop.outcome, stop.reason
        except DriverError as exc:
            outcome, reason = "ERROR", str(exc)
            self._phase_broke()
        except KeyboardInterrupt:
            outcome, reason = "ABORTED", "interrupted (Ctrl-C)"
            self._phase_broke()
        finally:
            for phase in self.record.phases:
                phase.end = phase.end or utc_now()
            self.record.finish(outcome, reason)
            self._close()
            if self.files is not None:
                self._attach_transcript()
                self._certify()
                atomic_write_text(self.files / "record.json",
                                  json.dumps(self.record.to_dict(), indent=1, allow_nan=False) + "\n")
        log.info("outcome %s%s", outcome, f": {reason}" if reason else "")
        self._event(event="outcome", outcome=outcome, exit_code=self.record.exit_code, reason=reason)
        return self.record

    def _certify(self) -> None:
        """Write the certificate beside the record and attach it to the export phase; a certificate
        that cannot be written is logged and noted, never the run's failure."""
        assert self.files is not None
        export = next((p for p in self.record.phases if p.name == "export"), None)
        if export is None:
            return
        captures = []
        raw = next((a for a in self.record.attachments() if a.name == RAW_CAPTURE), None)
        if self.capture is not None and raw is not None:
            captures.append(CaptureFile(str(self.files / raw.path), raw.sha256, self.capture))
        path = self.files / "certificate.html"
        try:
            write_certificate(from_record(self.record, captures), path)
        except (StationError, OSError, ValueError) as exc:
            log.warning("the calibration certificate was not written: %s", exc)
            export.notes.append(f"calibration certificate not written: {exc}")
            return
        self._attach(export, path, CERTIFICATE_NAME)

    def _phase_broke(self) -> None:
        """The phase under way when the run was cut short did not pass."""
        if self.record.phases and self.record.phases[-1].outcome == "PASS":
            self.record.phases[-1].outcome = "ERROR"

    @contextlib.contextmanager
    def _instruments(self, simulated: dict[str, str]) -> Iterator[None]:
        """The plan's instruments for the block (the simulated ones where ``simulated`` names them):
        identified, the supply switched on; left as ``on_abort`` says if the block fails."""
        plan = self.req.plan.instruments
        if plan is None:
            yield
            return
        phase = self._phase("instruments")
        self._instruments_phase = phase
        with open_bench(plan.with_urls(simulated)) as bench:
            self.bench = bench
            self._identities = bench.identities()
            for kind, seen in self._identities.items():
                phase.measurements.append(Measurement(f"instrument.{kind}", seen["identity"],
                                                      doc=seen["url"]))
            if bench.supply is not None:
                if plan.supply_v is not None:
                    bench.supply.set_voltage(plan.supply_v)
                if plan.supply_a is not None:
                    bench.supply.set_current(plan.supply_a)
                bench.supply.set_output(True)
            phase.end = utc_now()
            yield

    def _leave_safe_unless_done(self, outcome: str) -> None:
        """A run that stopped short (aborted, timed out, an error) leaves its instruments as the plan
        says; one that ran to its end (PASS or FAIL) leaves them as they are."""
        if self.bench is not None and outcome not in ("PASS", "FAIL"):
            self.bench.leave_safe()

    def _attach_transcript(self) -> None:
        """Every instrument command and reply, with its time, beside the record."""
        if self.bench is None or self.files is None or self._instruments_phase is None:
            return
        path = self.files / "instruments.json"
        atomic_write_text(path, json.dumps({"instruments": self._identities,
                                            "on_abort": self.bench.notes,
                                            "transcript": self.bench.transcript.to_list()},
                                           indent=1, allow_nan=False) + "\n")
        self._attach(self._instruments_phase, path, "instruments")

    def _soak(self, phase: Phase) -> None:
        """The chamber to the plan's soak temperature, until the unit's own temperature settles."""
        plan = self.req.plan.instruments
        assert plan is not None and plan.soak_c is not None and self.bench is not None
        assert self.bench.chamber is not None and self.device is not None
        chamber = self.bench.chamber
        chamber.set_setpoint(plan.soak_c)
        with contextlib.suppress(CommandUnsupported):
            chamber.start()
        settle = Settle(plan.settle_rate_c_per_min, plan.settle_s,
                        min(plan.settle_timeout_s, max(1.0, self.deadline - time.monotonic())))
        try:
            watch = wait_settled(self.device, settle)
        except SettleTimeout as exc:
            phase.outcome = "ERROR"
            raise _Stop("TIMEOUT", str(exc)) from None
        phase.measurements.append(Measurement("chamber.soak_c", plan.soak_c, "degC"))
        phase.measurements.append(Measurement("unit.temperature_c", watch.temperature_c, "degC",
                                              doc="the unit's own temperature once settled"))
        phase.measurements.append(Measurement("unit.temperature_slope", watch.slope(), "degC/min",
                                              high=plan.settle_rate_c_per_min))

    def _close(self) -> None:
        # A mounted table's link is the bench's, which closes it.
        for thing in (self.device, self.table if isinstance(self.table, Turntable) else None):
            if thing is not None:
                with contextlib.suppress(Exception):
                    thing.close()

    def _connect_phase(self, port: str, table_port: str | None) -> Phase:
        """The connect phase, ended; a device or link error marks it ERROR and goes on up."""
        phase = self._phase("connect")
        try:
            self._connect(phase, port, table_port)
        except DriverError:
            phase.outcome = "ERROR"
            raise
        phase.end = utc_now()
        return phase

    def _run(self, port: str, table_port: str | None) -> tuple[str, str]:
        plan = self.req.plan
        phase = self._connect_phase(port, table_port)
        serial_ok = all(m.outcome != "FAIL" for m in phase.measurements)
        self._check_time(phase)
        if self.req.plan.instruments is not None and self.req.plan.instruments.soak_c is not None:
            phase = self._phase("soak")
            self._soak(phase)
            phase.end = utc_now()
            self._check_time(phase)

        phase = self._phase("sequence")
        result = self._sequence(phase)
        phase.end = utc_now()
        stopped = self._sequence_outcome(result)
        if stopped is not None:
            phase.outcome = "ERROR" if stopped[0] in ("ERROR", "TIMEOUT") else "FAIL"
            return stopped
        self._check_time(phase)

        return self._calibrate_and_export(lambda phase: self._calibrate(phase, result),
                                          lambda phase, report: self._export(phase, report, plan), serial_ok)

    def _calibrate_and_export(self, calibrate: Callable[[Phase], Any], export: Callable[[Phase, Any], None],
                              serial_ok: bool = True) -> tuple[str, str]:
        """The run's end: the calibrate phase, then the export phase with what it found, then the verdict
        (FAIL for a measurement outside its limits or another serial; an error in either phase ABORTED)."""
        found, stopped = self._guarded("calibrate", "calibration", calibrate)
        if stopped is None:
            _, stopped = self._guarded("export", "export", lambda phase: export(phase, found))
        if stopped is not None:
            return stopped
        failed = [m for p in self.record.phases for m in p.measurements if m.outcome == "FAIL"]
        if failed or not serial_ok:
            names = ", ".join(m.name for m in failed[:6]) + (" ..." if len(failed) > 6 else "")
            return "FAIL", f"outside limits: {names}"
        return "PASS", ""

    def _guarded(self, name: str, what: str,
                 work: Callable[[Phase], Any]) -> tuple[Any, tuple[str, str] | None]:
        """Phase ``name`` doing ``work``: what it returns, or an error of the station ending the phase ERROR
        and the run ABORTED ("``what``: the error")."""
        phase = self._phase(name)
        try:
            found = work(phase)
        except StationError as exc:
            phase.outcome = "ERROR"
            phase.end = utc_now()
            return None, ("ABORTED", f"{what}: {exc}")
        phase.end = utc_now()
        return found, None

    def _gravity(self) -> float:
        """Local gravity: the plan's, or the normal gravity at its latitude and height, else standard."""
        plan = self.req.plan
        if plan.gravity is not None:
            return plan.gravity
        if plan.latitude is not None:
            return normal_gravity(plan.latitude, plan.height)
        return STANDARD_GRAVITY

    # ---- phases -------------------------------------------------------------------------------------

    def _connect(self, phase: Phase, port: str, table_port: str | None) -> None:
        plan = self.req.plan
        # Read in the runner's own loop, a batch every 20 ms: no reader thread waking the runner, and its
        # checks over the whole window, for every few bytes a unit at 1 kHz sends.
        self.device = open_paced(port, protocol=plan.protocol)
        if plan.asks_serial:
            self._connect_native(phase, port)
        else:
            self._connect_streaming(phase, port)
        self.files = self._make_files()
        self.record.files_dir = str(self.files)
        if self.req.operator is None and self.bench is not None and self.bench.table is not None:
            assert self.req.plan.instruments is not None
            accel = self.req.plan.instruments.limits.max_accel_dps2 or 100.0
            self.table = MountedTable(self.bench.table, self.req.plan.instruments.mount, accel)
            phase.measurements.append(Measurement("table.identity", self.bench.table.identify()))
        elif self.req.operator is None:
            assert table_port is not None  # execute() refused a request with neither
            self.table = turntable = Turntable(table_port)
            table_info = turntable.identify()
            turntable.home()
            phase.measurements.append(Measurement("table.serial", table_info.get("serial", "")))
            log.info("turntable %s %s on %s", printable(table_info.get("model")),
                     printable(table_info.get("serial")), table_port)

    def _make_files(self) -> Path:
        """The run's folder, FILES/<serial>/<start>-<run id>, made."""
        day = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
        files = self.req.files_root / _dir_name(self.record.serial) / f"{day}-{self.record.run_id[:8]}"
        files = files.resolve()
        files.mkdir(parents=True, exist_ok=True)
        return files

    def _connect_native(self, phase: Phase, port: str) -> None:
        """A unit of the native protocol: asked who it is, set to the plan's rate, started."""
        plan = self.req.plan
        assert self.device is not None
        info = self.device.get_info()
        self.device.set_rate(plan.rate_hz)
        self.device.start()
        reported = str(info.get("serial", ""))
        if self.record.serial == "auto":
            if not reported:
                raise StationError(f"{port}: the unit did not report a serial number; give --serial SN")
            self.record.serial = reported
            _log_serial(printable(reported))
        self.record.device = {"port": port, **{k: info.get(k) for k in ("serial", "model", "firmware")},
                              "rate_hz": plan.rate_hz}
        expected = self.record.serial
        phase.measurements.append(Measurement(
            "device.serial", reported, outcome="PASS" if reported == expected else "FAIL",
            doc=f"serial the unit reports; expected {expected}"))
        phase.measurements.append(Measurement("device.firmware", str(info.get("firmware", ""))))
        log.info("unit %s (%s, firmware %s) on %s at %d Hz", printable(reported),
                 printable(info.get("model")), printable(info.get("firmware")), port, plan.rate_hz)

    def _connect_streaming(self, phase: Phase, port: str) -> None:
        """A board that streams its own frames: nothing to ask it; the serial is the one given."""
        plan = self.req.plan
        assert self.device is not None
        self.record.device = {"port": port, "serial": self.record.serial, "protocol": self.device.protocol,
                              "rate_hz": plan.rate_hz}
        phase.measurements.append(Measurement(
            "device.serial", self.record.serial,
            doc=f"given to the run: the {self.device.protocol} protocol has no command to ask the unit"))
        log.info("unit %s (%s) on %s at %d Hz", printable(self.record.serial),
                 printable(self.device.protocol), port, plan.rate_hz)

    def _sequence(self, phase: Phase, capture_name: str = "capture.csv", attachment: str = RAW_CAPTURE
                  ) -> RunResult:
        plan = self.req.plan
        assert self.device is not None and self.files is not None
        inner = self.req.operator
        if inner is None:
            assert self.table is not None  # _connect opened it for a run without an operator
            inner = TableOperator(self.table)
        self._inner = inner
        self._factory_op = FactoryOperator(inner, self.deadline, self._relay)
        options = RunOptions(step_timeout_s=plan.step_timeout_s, max_attempts=plan.max_attempts)
        capture_path = self.files / capture_name
        recorder = Recorder(capture_path, device=self.device.info, with_step=True, port=self.device.port,
                            protocol=self.device.protocol)
        runner = SequenceRunner(self.device, plan.sequence, self._factory_op, options,
                                sink=RecorderSink(recorder, self.device))
        try:
            result = runner.run()
        finally:
            # The link with the clock guard's counts (outliers left out, jumps), not the device's alone.
            recorder.close(runner.link_stats().as_dict())
            self._attach(phase, capture_path, attachment)
        link = runner.link_stats().as_dict()
        accepted = sum(1 for s in result.steps if s.status == "accepted")
        phase.measurements.append(Measurement("sequence.steps_accepted", float(accepted), "",
                                              float(len(plan.sequence)), float(len(plan.sequence)),
                                              "PASS" if accepted == len(plan.sequence) else "FAIL"))
        attempts = float(sum(s.attempts for s in result.steps))
        phase.measurements.append(Measurement("sequence.attempts", attempts))
        phase.measurements.append(Measurement("capture.samples", float(len(result.capture))))
        phase.measurements += measure(plan, ["link.lost_fraction"], None, link)
        phase.notes += [f"{s.label}: {s.status} after {s.attempts} attempt(s)"
                        + (f" ({'; '.join(s.problems)})" if s.problems else "") for s in result.steps]
        self._link = link
        self.capture = result.capture
        return result

    def _relay(self, event: dict[str, Any]) -> None:
        self._event(**event)

    def _sequence_outcome(self, result: RunResult) -> tuple[str, str] | None:
        if result.outcome == "completed":
            if all(s.status == "accepted" for s in result.steps):
                return None
            return "ABORTED", "not every step was accepted"
        if result.outcome == "link-error":
            return "ERROR", f"link lost during the sequence: {result.reason}"
        if result.outcome == "timeout":
            return "TIMEOUT", result.reason
        table_error = getattr(self._inner, "error", None)
        if table_error is not None:
            return "ERROR", f"turntable: {table_error}"
        if self._factory_op.timed_out:
            return "TIMEOUT", f"the run took longer than the plan's timeout_s ({self.req.plan.timeout_s:g} s)"
        return "ABORTED", result.reason

    def _calibrate(self, phase: Phase, result: RunResult) -> Any:
        plan = self.req.plan
        capture = result.capture
        # The runner labels every sample; TurntableCapture refuses an unlabelled capture itself.
        data = TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step,
                                rate_hz=float(plan.rate_hz))
        settings = TurntableSettings(gravity=self._gravity(), latitude_deg=plan.latitude)
        report = calibrate_turntable(data, settings)
        phase.measurements += measure(plan, CALIBRATION_QUANTITIES, report, self._link)
        phase.notes += list(report.warnings)
        if any(m.outcome == "FAIL" for m in phase.measurements):
            phase.outcome = "FAIL"
        return report

    def _export(self, phase: Phase, report: Any, plan: Plan) -> None:
        assert self.files is not None
        params_path = self.files / "params.yaml"
        params = ParamsFile()
        params.update_device({**self.record.device, "serial": self.record.serial})
        params.accel = report.accel
        params.gyro = report.gyro
        params.save(params_path)
        self._attach(phase, params_path, PARAMS_ATTACHMENT)
        params = ParamsFile.load(params_path)  # exported as saved, as `imu-station export` would read it
        for fmt in plan.export:
            target = self.files / ("c" if fmt == "c" else DEFAULT_NAMES[fmt])
            result = write_export(params, fmt, target, source=params_path, station_id=self.record.station)
            for path in sorted(result.files):
                self._attach(phase, path, f"export {fmt}: {path.name}")


def check_serial(request: RunRequest) -> None:
    """Refuse, before any port is opened, a run that cannot learn the unit's serial.

    Parameters
    ----------
    request : RunRequest
        The run.

    Raises
    ------
    StationError
        ``serial`` is ``auto`` but the plan's protocol (a board's own frames) cannot ask the unit.
    """
    if request.serial == "auto" and not request.plan.asks_serial and request.simulate is None:
        raise StationError(f"a unit read through {request.plan.protocol} cannot be asked its serial number: "
                           "give --serial SN")


class _UnitField(logging.Filter):
    """Puts the unit's serial in every log line, escaped as the line's message is (the serial is what
    the unit or the operator gave; a message names steps, files and replies); the serial may only be
    known once the unit answered."""

    def __init__(self, serial: str):
        super().__init__()
        self.serial = serial

    def filter(self, record: logging.LogRecord) -> bool:
        record.unit = printable(self.serial)
        record.msg, record.args = printable_message(record.getMessage()), None
        return True


def configure_logging(serial: str, stream: Any = None) -> logging.Handler:
    """Log lines on stderr, each naming the unit (several units' logs interleave on a line).

    Parameters
    ----------
    serial : str
        The unit's serial as known so far (``auto`` until the unit answers).
    stream : text stream, optional
        Where the lines go (default: stderr).

    Returns
    -------
    logging.Handler
        The handler installed on the factory's logger (remove it when the run ends).
    """
    import sys

    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(unit)s %(levelname)s %(message)s", "%H:%M:%S"))
    handler.addFilter(_UnitField(serial))
    log.handlers[:] = [handler]
    log.setLevel(logging.INFO)
    log.propagate = False
    return handler


def _log_serial(serial: str) -> None:
    for handler in log.handlers:
        for f in handler.filters:
            if isinstance(f, _UnitField):
                f.serial = serial
