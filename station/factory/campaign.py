"""A chamber campaign (the plan's ``campaign:``), unattended, journaled step by step, resumable.

The campaign is a :class:`~station.factory.run.UnitRun` whose phases after ``connect`` are the
campaign's steps, in this order, each a phase of the one record::

    ramp-1            the chamber to soaks_c[0] at ramp_c_per_min; the unit recorded still (ramp.rate_hz)
                      until its own temperature settles (campaign.settle) -> ramp-1.csv
    soak-1.sequence   the plan's sequence on the table -> soak-1.sequence.csv
    soak-1.turn-on-K  K = 1..power_cycles: the supply off (off_s) and on, a still record
                      -> soak-1.turn-on-K.csv
    soak-1.still      a still record of still_s -> soak-1.still.csv
    ramp-2 ...        and so on for every soak; ramp-end to end_c when the plan gives one
    calibrate         each soak's sequence with calibrate_turntable, then fit_across_temperature
                      (bias, scale, misalignment as polynomials in T); turn-on repeatability per soak
                      (characterisation.turn_on); bias hysteresis from the ramps (campaign_figures)
    export            params.yaml (accel, gyro, thermal, characterisation) and the plan's exports

Journal and resume (``station.factory.journal``): a step's line is written and fsync'ed once its
files are closed and fsync'ed; ``run --resume RUN_DIR`` verifies every journaled file's SHA-256,
keeps aside (``interrupted/``) what a step cut short had written, brings the instruments back to
what the next step needs (the chamber to its soak and settled there, the table homed, the supply
on) and carries on with the first step not journaled. The record is made of the journaled phases
and the new ones, so a resumed campaign ends with the one record an uninterrupted one would have
(its notes say where it was resumed). Captures are streamed and fsync'ed every second.

Simulated time (``--simulate``): the plan's times are device seconds; the unit's clock runs at
``campaign.simulate.speed`` while the station records sequences and still records, and at
``wait_speed`` while it only waits on the chamber (``SimulatedPorts.pace``), with the unit at
``ramp.rate_hz``.

Why this module is long: the campaign's steps, the restore on resume and the end computations share
the run's record, journal, instruments and unit; they are methods of the one run object, as
``UnitRun``'s phases are.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.errors import CommandUnsupported, DriverError
from station.acquisition.capture import read_capture
from station.acquisition.recorder import Recorder, record
from station.acquisition.settle import Settle, SettleWatch
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.engines.characterisation.turn_on import reduce_record, turn_on_repeatability
from station.engines.thermal.intrinsics import matrices_at
from station.errors import StationError
from station.export.params.file import ParamsFile
from station.export.writers import DEFAULT_NAMES, write_export
from station.factory.campaign_figures import Sweep, bias_hysteresis
from station.factory.campaign_plan import CampaignPlan
from station.factory.journal import Journal, JournalError, file_entry, fsync_dir
from station.factory.measure import measure
from station.factory.records import Attachment, Measurement, Phase, RunRecord, utc_now
from station.factory.run import CALIBRATION_QUANTITIES, RunRequest, UnitRun, _Stop
from station.instruments.power_cycle import SupplyPowerCycle
from station.report.attachments import PARAMS_ATTACHMENT

log = logging.getLogger("imu_station.factory")

AIR_BAND_C = 1.0  # the settle window opens once the chamber's air is this close to the setpoint
AIR_POLL_S = 0.5  # wall seconds between readings of the chamber's air
PROGRESS_S = 15.0  # wall seconds between progress lines during a wait
SAMPLES_BACK_S = 10.0  # wall seconds a unit may take to stream again after its supply comes on
INTERRUPTED = "interrupted"


@dataclass(frozen=True)
class CampaignStep:
    """One step: ``kind`` ramp, sequence, turn-on or still; ``soak`` 1-based (0: the end ramp)."""

    id: str
    kind: str
    soak: int
    temp_c: float
    index: int = 0

    @property
    def file(self) -> str:
        """The capture the step writes."""
        return f"{self.id}.csv"


def campaign_steps(campaign: CampaignPlan) -> list[CampaignStep]:
    """Every step of ``campaign``, in the order they run (the module docstring)."""
    steps = []
    for i, temp in enumerate(campaign.soaks_c, 1):
        steps.append(CampaignStep(f"ramp-{i}", "ramp", i, temp))
        if campaign.sequence:
            steps.append(CampaignStep(f"soak-{i}.sequence", "sequence", i, temp))
        steps += [CampaignStep(f"soak-{i}.turn-on-{k}", "turn-on", i, temp, k)
                  for k in range(1, campaign.power_cycles + 1)]
        if campaign.still_s > 0:
            steps.append(CampaignStep(f"soak-{i}.still", "still", i, temp))
    if campaign.end_c is not None:
        steps.append(CampaignStep("ramp-end", "ramp", 0, campaign.end_c))
    return steps


def _phase_from(d: dict[str, Any]) -> Phase:
    return Phase(d["name"], d["start"], d["end"], d["outcome"],
                 [Measurement(**m) for m in d["measurements"]],
                 [Attachment(**a) for a in d["attachments"]], list(d["notes"]))


class CampaignRun(UnitRun):
    """A campaign, new or resumed from ``request.resume`` (see the module docstring)."""

    def __init__(self, request: RunRequest):
        self.journal: Journal | None = None
        self.resumed = request.resume is not None
        self._speed = 1.0
        self._session: list[Phase] = []
        if request.resume is not None:
            self.journal = Journal.open(Path(request.resume))
            problems = self.journal.verify()
            if problems:
                raise JournalError("the run's captures are not as journaled: " + "; ".join(problems[:5])
                                   + "; restore them, or start the campaign again")
            begin = self.journal.begin
            if begin["plan"]["sha256"] != request.plan.sha256:
                raise JournalError(f"the plan {request.plan.path} is not the one the run began with "
                                   f"({begin['plan']['path']}, SHA-256 {begin['plan']['sha256'][:12]}...); "
                                   "give that plan (or leave --plan out)")
            if request.simulate is not None:
                # the same unit as the run began with, where the journal left it
                simulated = begin.get("simulate") or {}
                request = dataclasses.replace(request, simulate=dataclasses.replace(
                    request.simulate, initial_c=self.journal.last_unit_c(),
                    thermal_intrinsics=bool(simulated.get("thermal_intrinsics", False))))
        super().__init__(request)
        if request.plan.campaign is None:
            raise StationError(f"{request.plan.path}: the plan has no 'campaign' section; --resume "
                               "carries on a chamber campaign")
        self.campaign: CampaignPlan = request.plan.campaign
        if request.simulate is not None:
            self._speed = request.simulate.speed
        if self.journal is not None:
            begin = self.journal.begin
            self.record = RunRecord(serial=begin["serial"], station=begin["station"], plan=begin["plan"],
                                    run_id=begin["run_id"], start=begin["start"])
            self.record.phases = [_phase_from(p) for p in begin["phases"]]
            self.record.phases += [_phase_from(e["phase"]) for e in self.journal.entries
                                   if e["type"] == "step"]

    # ---- the run's frame ------------------------------------------------------------------------

    def execute(self) -> RunRecord:
        """Run (or carry on) the campaign; the journal's end entry once the record is written."""
        try:
            record = super().execute()
            if self.journal is not None and self.files is not None and (self.files / "record.json").exists():
                self.journal.append({"type": "end", "outcome": record.outcome, "record": "record.json"})
            return record
        finally:
            if self.journal is not None:
                self.journal.close()

    def _make_files(self) -> Path:
        if self.req.resume is not None:
            return Path(self.req.resume).resolve()
        return super()._make_files()

    def _phase(self, name: str) -> Phase:
        if self.resumed and name in ("instruments", "connect"):
            # This session's: the record keeps the first session's (an uninterrupted run has one).
            phase = Phase(name)
            self._session.append(phase)
            log.info("phase %s (resumed run)", name)
            self._event(event="phase", phase=name)
            return phase
        return super()._phase(name)

    def _attach_transcript(self) -> None:
        if self.resumed:
            self._instruments_phase = next((p for p in self.record.phases if p.name == "instruments"), None)
        super()._attach_transcript()

    def _pace(self, speed: float) -> None:
        """The simulated unit's clock to ``speed`` times the wall clock (nothing on a real unit)."""
        if self.pace is not None:
            self.pace(speed)
            self._speed = speed

    def _set_rate(self, rate_hz: int) -> None:
        assert self.device is not None
        if self.req.plan.asks_serial:  # a board streaming its own frames is asked nothing
            self.device.set_rate(rate_hz)

    def _home(self) -> None:
        """The table to the mount's pose, at rest (still records and turn-ons in one pose)."""
        assert self.table is not None
        mount = self.req.plan.instruments.mount if self.req.plan.instruments is not None else "+z"
        try:
            self.table.pose(mount, self.req.plan.step_timeout_s)
            wait = getattr(self.table, "wait", None)
            if wait is not None:
                wait(self.req.plan.step_timeout_s)
        except DriverError as exc:
            raise _Stop("ERROR", f"turntable: {exc}") from None

    # ---- the campaign -----------------------------------------------------------------------------

    def _run(self, port: str, table_port: str | None) -> tuple[str, str]:
        phase = self._connect_phase(port, table_port)
        if self.bench is None or self.bench.chamber is None:
            phase.outcome = "ERROR"
            return "ERROR", "a campaign needs the plan's chamber (instruments.chamber)"
        if any(m.outcome == "FAIL" for m in phase.measurements):
            phase.outcome = "FAIL"
            return "FAIL", f"the unit reports another serial than {self.record.serial}"
        assert self.files is not None
        if self.journal is None:
            self.journal = Journal.create(self.files, self._begin())
        else:
            self.record.device = self.journal.begin["device"]
        steps = campaign_steps(self.campaign)
        done = self.journal.steps()
        pending = [s for s in steps if s.id not in done]
        notes = self._keep_aside(pending)
        if self.resumed:
            notes.insert(0, f"resumed at {utc_now()} after {len(done)} of {len(steps)} step(s)")
            if pending and pending[0].kind != "ramp":
                notes.append(self._restore(pending[0]))
        for n, step in enumerate(pending):
            self._step(step, steps.index(step), len(steps), notes if n == 0 else [])
        if not pending and notes:
            log.info("%s", "; ".join(notes))
        return self._finish(steps)

    def _begin(self) -> dict[str, Any]:
        sim = self.req.simulate
        return {"run_id": self.record.run_id, "start": self.record.start, "serial": self.record.serial,
                "station": self.record.station, "plan": self.record.plan, "device": self.record.device,
                # where a resume from another folder finds the plan again
                "plan_file": str(Path(self.req.plan.path).resolve()),
                "simulate": None if sim is None else {"seed": sim.seed, "grade": sim.grade,
                                                      "thermal_intrinsics": sim.thermal_intrinsics},
                "phases": [asdict(p) for p in self.record.phases]}

    def _keep_aside(self, pending: list[CampaignStep]) -> list[str]:
        """Files of steps not journaled (a step a crash cut short) go to interrupted/, kept, not used."""
        assert self.files is not None
        notes = []
        for step in pending:
            path = self.files / step.file
            if path.exists():
                aside = self.files / INTERRUPTED
                aside.mkdir(exist_ok=True)
                target = aside / f"{step.id}.{time.strftime('%Y%m%dT%H%M%S')}.csv"
                path.rename(target)
                fsync_dir(self.files)
                notes.append(f"{step.file}: cut short by the interruption, kept aside as "
                             f"{target.relative_to(self.files)} and recorded again")
        return notes

    def _restore(self, step: CampaignStep) -> str:
        """Resumed inside a soak: the chamber back to the soak's temperature, the unit settled there."""
        assert self.bench is not None and self.bench.chamber is not None
        log.info("resume: the chamber back to %g degC before %s", step.temp_c, step.id)
        watch = self._wait_chamber(step.temp_c, None, f"resume before {step.id}")
        return (f"instruments restored: chamber at {step.temp_c:g} degC, the unit settled at "
                f"{watch.temperature_c:.2f} degC; the table homed, the supply on")

    def _step(self, step: CampaignStep, index: int, total: int, notes: list[str]) -> None:
        assert self.journal is not None and self.files is not None
        self._check_time(self.record.phases[-1])
        phase = Phase(step.id)
        phase.notes += notes
        self.record.phases.append(phase)
        soaks = len(self.campaign.soaks_c)
        where = "end" if step.soak == 0 else f"soak {step.soak}/{soaks}"
        log.info("step %d/%d %s: %s %s at %g degC", index + 1, total, step.id, where, step.kind, step.temp_c)
        self._event(event="campaign", step=step.id, kind=step.kind, soak=step.soak, soaks=soaks,
                    temp_c=step.temp_c, index=index, total=total)
        try:
            results = {"ramp": self._ramp, "sequence": self._sequence_step, "turn-on": self._turn_on,
                       "still": self._still}[step.kind](step, phase)
        except _Stop:
            phase.outcome = "ERROR" if phase.outcome == "PASS" else phase.outcome
            phase.end = utc_now()
            raise
        except DriverError:
            phase.outcome = "ERROR"
            raise
        phase.end = utc_now()
        for m in phase.measurements:  # one name per measurement in the record: the step's id first
            m.name = f"{step.id}.{m.name}"
        path = self.files / step.file
        files = [file_entry(self.files, path)] if path.exists() else []
        self.journal.append({"type": "step", "step": step.id, "phase": asdict(phase), "files": files,
                             "results": results, "unit_c": results.get("unit_c")})

    def _wait_chamber(self, target: float, recorder: Recorder | None, what: str) -> SettleWatch:
        """Chamber to ``target``; read (and record) the unit until its temperature settles (device time)."""
        assert self.bench is not None and self.bench.chamber is not None and self.device is not None
        c = self.campaign
        chamber = self.bench.chamber
        self._pace(c.wait_speed)
        self._set_rate(c.ramp_rate_hz)
        with contextlib.suppress(CommandUnsupported):
            chamber.set_gradient(c.ramp_c_per_min)
        chamber.set_setpoint(target)
        with contextlib.suppress(CommandUnsupported):
            chamber.start()
        settle = Settle(c.settle_rate_c_per_min, c.settle_hold_s, c.settle_timeout_s)
        watch = SettleWatch(settle)
        first_t: float | None = None
        air_near, next_air, next_log, next_event = False, 0.0, time.monotonic() + PROGRESS_S, 0.0
        air = math.nan
        while True:
            if time.monotonic() > self.deadline:
                raise _Stop("TIMEOUT", f"the run took longer than the plan's timeout_s "
                            f"({self.req.plan.timeout_s:g} s), during {what}")
            batch = self.device.read(0.2)
            now = time.monotonic()
            if now >= next_air:
                air = chamber.temperature_c()
                near = abs(air - target) <= AIR_BAND_C
                if not near:
                    watch = SettleWatch(settle)  # the window counts once the air is at the setpoint
                air_near, next_air = near, now + AIR_POLL_S
            if len(batch):
                if recorder is not None:
                    recorder.write(batch)
                t = batch["t_us"] * 1e-6
                first_t = float(t[0]) if first_t is None else first_t
                if air_near:
                    watch.feed(t, batch["temp"])
                elapsed = float(t[-1]) - first_t
                if elapsed > c.settle_timeout_s:
                    slope = watch.slope()
                    raise _Stop("TIMEOUT", f"{what}: the unit's temperature did not settle at "
                                f"{target:g} degC "
                                f"within {c.settle_timeout_s:g} s (chamber air {air:.2f} degC, unit "
                                f"{float(np.nanmean(batch['temp'])):.2f} degC"
                                + (f", moving {slope:+.3f} degC/min" if slope is not None else "")
                                + "); lengthen campaign.settle.timeout_s or check the chamber")
                if now >= next_event:  # a reading a second is enough for a live line or run-many
                    self._event(event="temperature", unit_c=float(np.nanmean(batch["temp"])), air_c=air,
                                target_c=target, slope=watch.slope())
                    next_event = now + 1.0
            if recorder is not None:
                recorder.tick()
            if now >= next_log:
                slope = watch.slope()
                log.info("%s: chamber air %.2f degC, unit %s degC%s", what, air,
                         "?" if watch.temperature_c is None else f"{watch.temperature_c:.2f}",
                         "" if slope is None else f", {slope:+.3f} degC/min")
                next_log = now + PROGRESS_S
            if air_near and watch.settled():
                return watch

    def _ramp(self, step: CampaignStep, phase: Phase) -> dict[str, Any]:
        assert self.device is not None and self.files is not None
        c = self.campaign
        start_c = self._unit_now()
        recorder = None
        path = self.files / step.file
        if c.ramp_record:
            recorder = Recorder(path, device=self.device.info, port=self.device.port,
                                protocol=self.device.protocol)
        try:
            watch = self._wait_chamber(step.temp_c, recorder, step.id)
        finally:
            if recorder is not None:
                recorder.close()
        if recorder is not None:
            self._attach(phase, path, f"{step.id} ramp record")
        slope = watch.slope()
        log.info("%s: the unit settled at %.2f degC (%+.3f degC/min over %g s), from %s degC", step.id,
                 watch.temperature_c, slope, c.settle_hold_s, "?" if start_c is None else f"{start_c:.2f}")
        direction = 1 if step.temp_c > (start_c if start_c is not None else step.temp_c) else -1
        phase.measurements += [
            Measurement("chamber.setpoint_c", step.temp_c, "degC"),
            Measurement("unit.temperature_c", watch.temperature_c, "degC",
                        doc="the unit's own temperature once settled"),
            Measurement("unit.temperature_slope", slope, "degC/min", high=c.settle_rate_c_per_min,
                        outcome="PASS")]
        return {"from_c": start_c, "unit_c": watch.temperature_c, "slope": slope, "direction": direction}

    def _unit_now(self) -> float | None:
        assert self.device is not None
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            batch = self.device.read(0.2)
            if len(batch) and np.isfinite(batch["temp"]).any():
                return float(np.nanmean(batch["temp"]))
        return None

    def _sequence_step(self, step: CampaignStep, phase: Phase) -> dict[str, Any]:
        self._pace(self.campaign.speed)
        self._set_rate(self.req.plan.rate_hz)
        self._home()
        result = self._sequence(phase, step.file, f"{step.id} capture")
        stopped = self._sequence_outcome(result)
        self.capture = None  # read back from its file at the end: the same for a resumed run
        if stopped is not None:
            phase.outcome = "ERROR" if stopped[0] in ("ERROR", "TIMEOUT") else "FAIL"
            raise _Stop(*stopped)
        temp = result.capture.temp
        unit_c = float(np.nanmean(temp)) if temp is not None and np.isfinite(temp).any() else None
        phase.measurements.append(Measurement("unit.temperature_c", unit_c, "degC",
                                              doc="the unit's mean temperature over the sequence"))
        return {"unit_c": unit_c, "link": self._link}

    def _record_still(self, step: CampaignStep, phase: Phase, duration_s: float) -> dict[str, Any]:
        assert self.device is not None and self.files is not None
        path = self.files / step.file
        result = record(self.device, path, duration_s=duration_s, handle_sigint=False)
        if result.error is not None or result.device_time_s < 0.9 * duration_s:
            reason = result.error or f"only {result.device_time_s:.3g} s recorded"
            raise _Stop("ERROR", f"{step.id}: the still record ended early ({reason})")
        self._attach(phase, path, f"{step.id} still record")
        capture = read_capture(path)
        unit_c = float(np.nanmean(capture.temp)) if capture.temp is not None else None
        phase.measurements += [Measurement("unit.temperature_c", unit_c, "degC"),
                               Measurement("capture.samples", float(len(capture.t)))]
        return {"unit_c": unit_c, "samples": len(capture.t)}

    def _turn_on(self, step: CampaignStep, phase: Phase) -> dict[str, Any]:
        assert self.bench is not None and self.device is not None
        if self.bench.supply is None:
            raise _Stop("ERROR", "power cycles need the plan's supply (instruments.supply)")
        c = self.campaign
        self._home()
        self._pace(c.wait_speed)
        cycle = SupplyPowerCycle(self.bench.supply, off_s=c.off_s / self._speed)
        try:
            cycle(step.index)
        except DriverError as exc:
            raise _Stop("ERROR", f"supply: {exc}") from None
        deadline = time.monotonic() + SAMPLES_BACK_S
        while not len(self.device.read(0.2)):
            if time.monotonic() > deadline:
                raise _Stop("ERROR", f"no samples {SAMPLES_BACK_S:g} s after the supply switched the unit "
                            "on; check its wiring to the supply and the plan's volts and amps")
        self._pace(c.speed)
        self._set_rate(self.req.plan.rate_hz)
        self.device.read(0)  # the boot's first samples: the record starts after them
        phase.notes.append(f"supply off {c.off_s:g} s and on again (turn-on {step.index})")
        return self._record_still(step, phase, c.turn_on_s)

    def _still(self, step: CampaignStep, phase: Phase) -> dict[str, Any]:
        self._home()
        self._pace(self.campaign.speed)
        self._set_rate(self.req.plan.rate_hz)
        return self._record_still(step, phase, self.campaign.still_s)

    # ---- the end: calibration across temperature, figures, parameter file ----------------------------

    def _finish(self, steps: list[CampaignStep]) -> tuple[str, str]:
        return self._calibrate_and_export(lambda phase: self._calibrate_all(phase, steps),
                                          lambda phase, found: self._export_campaign(phase, *found))


    def _calibrate_all(self, phase: Phase, steps: list[CampaignStep]
                       ) -> tuple[Any, list[Any], list[Any], Any]:
        from station.engines.thermal.intrinsics_fit import SoakCalibration, fit_across_temperature

        assert self.files is not None and self.journal is not None
        plan = self.req.plan
        settings = TurntableSettings(gravity=self._gravity(), latitude_deg=plan.latitude)
        journaled = self.journal.steps()
        soaks, reports, turn_ons = [], [], []
        for i, temp in enumerate(self.campaign.soaks_c, 1):
            if self.campaign.sequence:
                capture = read_capture(self.files / f"soak-{i}.sequence.csv")
                data = TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step,
                                        rate_hz=float(plan.rate_hz))
                report = calibrate_turntable(data, settings)
                unit_c = float(np.nanmean(capture.temp)) if capture.temp is not None else math.nan
                soaks.append(SoakCalibration(unit_c, report, f"soak-{i} ({temp:g} degC)"))
                reports.append((i, unit_c, report))
                link = journaled.get(f"soak-{i}.sequence", {}).get("results", {}).get("link", {})
                for m in measure(plan, CALIBRATION_QUANTITIES, report, link):
                    phase.measurements.append(dataclasses.replace(m, name=f"soak-{i}.{m.name}"))
                phase.measurements.append(Measurement(f"soak-{i}.temperature_c", unit_c, "degC"))
                phase.notes += [f"soak-{i}: {w}" for w in report.warnings]
            if self.campaign.power_cycles:
                records = []
                for k in range(1, self.campaign.power_cycles + 1):
                    name = f"soak-{i}.turn-on-{k}.csv"
                    capture = read_capture(self.files / name)
                    records.append(reduce_record(name, capture.t, capture.acc, capture.gyro))
                acc, gyro = turn_on_repeatability(records)
                turn_ons.append((i, temp, acc, gyro))
                for triad, rep, unit in (("accel", acc, "m/s^2"), ("gyro", gyro, "rad/s")):
                    for axis, sigma in zip("xyz", rep.sigma, strict=True):
                        phase.measurements.append(Measurement(f"soak-{i}.{triad}.turn_on_sigma.{axis}",
                                                              float(sigma), unit,
                                                              doc="1-sigma turn-on bias repeatability"))
        across = None
        if len(soaks) >= 2:
            across = fit_across_temperature(soaks)
            # AcrossTemperature's accel and gyro at T_ref, judged as one calibration's
            phase.measurements += measure(plan, CALIBRATION_QUANTITIES, across, {})  # type: ignore[arg-type]
            phase.notes += list(across.warnings)
            phase.notes.append(f"fitted across {len(soaks)} soaks; orders {across.orders}")
        sweeps = self._sweeps(steps) if self.campaign.ramp_record else []
        if across is not None and sweeps:
            across = self._ramp_bias(phase, across, sweeps)
        hysteresis = bias_hysteresis(sweeps) if sweeps else None
        if hysteresis is not None and self.campaign.power_cycles:
            phase.notes.append("the bias hysteresis compares ramps recorded after different power-ups (the "
                               "soaks' power cycles): it includes the turn-on bias changes; a campaign with "
                               "power_cycles: 0 measures the hysteresis alone")
        if hysteresis is not None:
            for triad, values, unit in (("accel", hysteresis.accel, "m/s^2"),
                                        ("gyro", hysteresis.gyro, "rad/s")):
                for axis, value in zip("xyz", values, strict=True):
                    phase.measurements.append(Measurement(f"hysteresis.{triad}.bias.{axis}", float(value),
                                                          unit, doc="up minus down at equal temperature"))
        if any(m.outcome == "FAIL" for m in phase.measurements):
            phase.outcome = "FAIL"
        return across, reports, turn_ons, hysteresis

    def _ramp_bias(self, phase: Phase, across: Any, sweeps: list[Sweep]) -> Any:
        """The thermal bias as a function of T and dT from the ramp records, relative to the fit at T_ref
        (as ``imu-station thermal`` fits a sweep); the scale and misalignment polynomials the soaks'."""
        from station.engines.thermal.fit import ThermalSettings, ThermalSweep, fit_thermal

        # The ramps one after another on one time line: each starts where the soak before it settled.
        ts, offset = [], 0.0
        for sweep in sweeps:
            t = sweep.t - sweep.t[0] + offset
            ts.append(t)
            offset = float(t[-1]) + float(np.median(np.diff(t))) if len(t) > 1 else offset + 1.0
        reference = float(across.thermal.reference_temp)
        temp = np.concatenate([w.temp for w in sweeps])
        # The scale and misalignment's own change with T taken out first, so the bias fit does not take
        # it in (gravity along the mount axis would read as bias): raw' = M(T_ref) M(T)^-1 raw, eq. (1) of
        # station.engines.thermal.intrinsics, to first order in b.
        at = np.where(np.isfinite(temp), temp, reference)
        readings = {}
        for triad in ("accel", "gyro"):
            raw = np.concatenate([getattr(w, "acc" if triad == "accel" else "gyro") for w in sweeps])
            cal = getattr(across, triad)
            if cal is None:
                readings[triad] = raw
                continue
            m_t = matrices_at(cal.matrix, at, reference, across.thermal.scale.get(triad),
                              across.thermal.misalignment.get(triad))
            readings[triad] = np.linalg.solve(m_t, raw[:, :, None])[:, :, 0] @ np.asarray(cal.matrix).T
        try:
            data = ThermalSweep(np.concatenate(ts), temp, readings["accel"], readings["gyro"], None,
                                accel_cal=across.accel, gyro_cal=across.gyro)
            fit = fit_thermal(data, ThermalSettings(gravity=self._gravity(), reference_temp=reference))
        except StationError as exc:
            phase.notes.append(f"thermal bias from the soaks only: the ramp records could not be fitted "
                               f"({exc})")
            return across
        phase.notes.append("thermal bias (T and dT terms) fitted on the ramp records; scale factor and "
                           "misalignment as functions of T from the soaks")
        phase.notes += [f"ramps: {w}" for w in fit.warnings]
        return dataclasses.replace(across, thermal=fit.model.keeping_intrinsics(across.thermal))

    def _sweeps(self, steps: list[CampaignStep]) -> list[Sweep]:
        assert self.files is not None and self.journal is not None
        journaled = self.journal.steps()
        out = []
        for step in steps:
            if step.kind != "ramp" or not (self.files / step.file).exists():
                continue
            capture = read_capture(self.files / step.file)
            direction = int(journaled.get(step.id, {}).get("results", {}).get("direction", 0))
            if capture.temp is not None and direction:
                out.append(Sweep(direction, capture.temp, capture.acc, capture.gyro, capture.t))
        return out

    def _export_campaign(self, phase: Phase, across: Any, reports: list[Any], turn_ons: list[Any],
                         hysteresis: Any) -> None:
        assert self.files is not None
        params = ParamsFile()
        params.update_device({**self.record.device, "serial": self.record.serial})
        if across is not None:
            params.accel, params.gyro, params.thermal = across.accel, across.gyro, across.thermal
        elif reports:
            params.accel, params.gyro = reports[0][2].accel, reports[0][2].gyro
        character: dict[str, Any] = {}
        block: dict[str, Any] = {"soaks_c": [float(t) for t in self.campaign.soaks_c],
                                 "unit_c": [float(r[1]) for r in reports]}
        if turn_ons:
            character["turn_ons"] = self.campaign.power_cycles
            # the pooled figure: the root mean square over the soaks of each soak's sigma_to
            character["accel_bias_repeatability"] = np.sqrt(np.mean([a.sigma ** 2 for _, _, a, _ in turn_ons],
                                                                    axis=0)).tolist()
            character["gyro_bias_repeatability"] = np.sqrt(np.mean([g.sigma ** 2 for _, _, _, g in turn_ons],
                                                                   axis=0)).tolist()
            block["turn_on"] = [{"soak_c": float(t), "accel_bias_repeatability": a.sigma.tolist(),
                                 "gyro_bias_repeatability": g.sigma.tolist()} for _, t, a, g in turn_ons]
        if hysteresis is not None:
            block["hysteresis"] = hysteresis.to_dict()
        character["across_temperature"] = block
        params.set_section("characterisation", character)
        path = self.files / "params.yaml"
        params.save(path)
        self._attach(phase, path, PARAMS_ATTACHMENT)
        params = ParamsFile.load(path)
        for fmt in self.req.plan.export:
            target = self.files / ("c" if fmt == "c" else DEFAULT_NAMES[fmt])
            result = write_export(params, fmt, target, source=path, station_id=self.record.station)
            for written in sorted(result.files):
                self._attach(phase, written, f"export {fmt}: {written.name}")
        with contextlib.suppress(OSError):
            fsync_dir(self.files)


def resume_folder(path: Path) -> dict[str, Any]:
    """A run folder's journal's first entry (plan, serial, simulation), for ``run --resume``.

    Raises
    ------
    JournalError
        No resumable journal there.
    """
    journal = Journal.open(path)
    try:
        return dict(journal.begin)
    finally:
        journal.close()

