"""Results: the parameters with their uncertainties, residuals, pass/fail, save to --out and exports."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich import box
from rich.console import Group, RenderableType
from rich.table import Table
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.widgets import Footer, Header, Static

from station.acquisition.runner import RunResult
from station.engines.calibration.common import CalibrationReport
from station.engines.shared.sensor_model import SensorCalibration
from station.errors import StationError
from station.export.params.file import ParamsFile, UnitMismatchError
from station.export.writers import write_export
from station.tui.calibrate import calibrate_run
from station.tui.limits import (
    ACCEL_LIMITS,
    BUILT_IN_MEANING,
    GYRO_LIMITS,
    Verdict,
    evaluate,
    limits_name,
    plan_verdicts,
)
from station.tui.messages import LinkFailed, Snapshot
from station.tui.saving import save_sections
from station.tui.screens.station_screen import StationScreen

# The engines' per-step keys, as the operator reads them.
RESIDUAL_LABELS = {
    "residual": "residual (m/s^2)",
    "norm_error": "|g| error (m/s^2)",
    "angle_error_deg": "angle error (deg)",
}


def _sigma(value: float) -> str:
    """A 1-sigma in two digits and a short exponent: 4.3e-5, not 4.3e-05 (a row fits 80 columns)."""
    mantissa, exponent = format(value, ".1e").split("e")
    return f"{mantissa}e{int(exponent)}"


def _pm(values: np.ndarray, sigma: object, fmt: str) -> list[str]:
    values = np.asarray(values, float).ravel()
    sig = np.asarray(sigma, float).ravel() if sigma is not None else None
    if sig is None or sig.shape != values.shape:
        return [format(v, fmt) for v in values]
    return [f"{format(v, fmt)}±{_sigma(s)}" for v, s in zip(values, sig, strict=True)]


def residual_unit(cal: SensorCalibration, unit: str) -> str:
    """The rotation method's residual is an angle; the engine says so in ``extra['residual']``.

    Parameters
    ----------
    cal : SensorCalibration
        The triad's calibration.
    unit : str
        The unit of a residual that is not an angle.

    Returns
    -------
    str
        ``rad`` or ``unit``.
    """
    return "rad" if "angle" in str(cal.extra.get("residual", "")) else unit


def sensor_table(title: str, cal: SensorCalibration, unit: str) -> Table:
    """One triad's bias, scale and misalignment with their 1-sigma, and its residual RMS.

    Parameters
    ----------
    title : str
        The table's title.
    cal : SensorCalibration
        The triad's calibration.
    unit : str
        The bias unit (m/s^2 or rad/s).

    Returns
    -------
    rich.table.Table
    """
    # No vertical rules: a row of three values with their 1-sigma fits 80 columns unclipped.
    table = Table(title=title, title_justify="left", title_style="bold", expand=False, padding=(0, 1),
                  box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False)
    table.add_column("parameter", no_wrap=True)
    for axis in "xyz":
        table.add_column(axis, justify="right", no_wrap=True)
    table.add_column("unit", no_wrap=True)
    sd = cal.stddev or {}
    table.add_row("bias", *_pm(cal.bias, sd.get("bias"), "+.5f"), unit)
    table.add_row("scale", *_pm(cal.scale, sd.get("scale"), ".5f"), "")
    s = cal.misalignment
    s_sd = np.asarray(sd["misalignment"], float) if sd.get("misalignment") is not None else None
    for i, axis in enumerate("xyz"):
        cells = []
        for j in range(3):
            if i == j:
                cells.append("·")
            else:
                sig = None if s_sd is None or s_sd.shape != (3, 3) else s_sd[i, j]
                cells.append(_pm(np.array([s[i, j]]), None if sig is None else np.array([sig]), "+.5f")[0])
        table.add_row(f"misalign {axis}·", *cells, "rad")
    if cal.residual_rms is not None:
        table.add_row("rms resid.", f"{cal.residual_rms:.3e}", "", "", residual_unit(cal, unit))
    return table


def verdict_table(verdicts: list[Verdict]) -> Table:
    """Each limit check: sensor, check, value, limit, PASS or FAIL.

    Parameters
    ----------
    verdicts : list of Verdict
        The checks against the limits.

    Returns
    -------
    rich.table.Table
    """
    table = Table(padding=(0, 1), box=box.SIMPLE_HEAD)
    for col in ("sensor", "check", "value", "limit", ""):
        table.add_column(col)
    for v in verdicts:
        mark = Text("PASS", style="bold green") if v.passed else Text("FAIL", style="bold red")
        table.add_row(v.sensor, v.name, f"{v.value:.4g} {v.unit}", v.limit_text(), mark)
    return table


class ResultsScreen(StationScreen):
    """The calibration of a sequence run, computed in a worker, judged against the limits; Enter
    saves it to --out and writes the --export formats.

    Parameters
    ----------
    run : RunResult
        The sequence run whose capture is calibrated.
    """

    # Enter saves to --out (a second Enter quits); without --out it asks where, then quits. One binding
    # each, the footer showing the one that applies (check_action): "save and quit" was shown on the
    # key that only saves.
    BINDINGS = [
        Binding("enter", "save", "save", show=True),
        Binding("enter", "save_and_quit", "save and quit", show=True),
        Binding("enter", "quit_saved", "quit", show=True),
        Binding("e", "export", "exports"),
    ]
    DEFAULT_CSS = """
    ResultsScreen #body { padding: 0 1; }
    ResultsScreen #status { height: auto; border: heavy $warning; padding: 0 1; }
    """

    def __init__(self, run: RunResult) -> None:
        super().__init__()
        self.run = run
        self.report: CalibrationReport | None = None
        self.verdicts: list[Verdict] = []
        self.saved = False

    def compose(self) -> ComposeResult:
        """The tables (filled once computed), the status line and the keys."""
        yield Header()
        with VerticalScroll(id="body"):
            yield Static(f"computing the calibration from {len(self.run.capture)} samples ...", id="tables")
        yield Static("", id="status")
        yield Footer()

    def on_mount(self) -> None:
        """Start computing the calibration."""
        self.title = "imu-station · results"
        self._compute()

    @work(thread=True, exclusive=True, group="compute")
    def _compute(self) -> None:
        try:
            report = calibrate_run(self.run.capture)
        except StationError as exc:
            self.post_message(LinkFailed(exc))
            return
        self.post_message(Snapshot({"report": report}))

    def on_link_failed(self, message: LinkFailed) -> None:
        """The calibration failed: say why and what the operator can do."""
        self.query_one("#tables", Static).update(Text(f"The calibration failed: {message.error}",
                                                      style="red"))
        self.query_one("#status", Static).update("w: run the sequence again · q: quit")
        self.station.calibration_failed = True

    def on_snapshot(self, message: Snapshot) -> None:
        """Show the computed calibration, its verdicts, residuals and warnings."""
        report: CalibrationReport = message.data["report"]
        self.report = report
        parts: list[RenderableType] = [
            Text(f"method: {report.method}   gravity: {report.gravity:.5f} m/s^2   "
                 f"run: {self.run.outcome}, {len(self.run.accepted)} of {len(self.run.sequence)} steps")]
        # The verdict first: it is what the operator asks before anything else.
        self.verdicts = self.judge(report)
        plan = self.station.config.plan
        source = f"{limits_name(plan)} ({BUILT_IN_MEANING if plan is None else plan.path})"
        # A line of its own: a table's title wraps at the table's width, and a plan's path is long.
        parts += [Text(f"limits: {source}", style="bold"), verdict_table(self.verdicts)]
        if report.accel is not None:
            parts.append(sensor_table("accelerometer", report.accel, "m/s^2"))
        if report.gyro is not None:
            parts.append(sensor_table("gyroscope", report.gyro, "rad/s"))
        residuals = self.residual_table(report)
        if residuals is not None:
            parts.append(residuals)
        for warning in report.warnings:
            parts.append(Text(f"warning: {warning}", style="yellow"))
        self.query_one("#tables", Static).update(Group(*parts))
        self.station.results_failed = not all(v.passed for v in self.verdicts)
        self.station.pending = self
        self.show_status()

    def judge(self, report: CalibrationReport) -> list[Verdict]:
        """The calibration against the plan's limits (``--plan``), else the built-in ones.

        Parameters
        ----------
        report : CalibrationReport
            The calibration.

        Returns
        -------
        list of Verdict
        """
        plan = self.station.config.plan
        if plan is not None:
            session = self.station.session
            link = session.device.stats.as_dict() if session is not None else {}
            return plan_verdicts(plan, report, link)
        verdicts = []
        if report.accel is not None:
            verdicts += evaluate("accel", report.accel, ACCEL_LIMITS, "m/s^2")
        if report.gyro is not None:
            verdicts += evaluate("gyro", report.gyro, GYRO_LIMITS, "rad/s",
                                 residual_unit(report.gyro, "rad/s"))
        return verdicts

    @staticmethod
    def residual_table(report: CalibrationReport) -> Table | None:
        """Per-pose residuals as the engine reports them (keys holding 'resid' or 'error').

        Parameters
        ----------
        report : CalibrationReport
            The calibration.

        Returns
        -------
        rich.table.Table or None
            None when the engine reports no residual.
        """
        rows = [p for p in report.poses if isinstance(p, dict)]
        keys = sorted({k for p in rows for k in p if "resid" in k or "error" in k})
        if not rows or not keys:
            return None
        table = Table(title="residuals per step", title_justify="left", title_style="bold", padding=(0, 1),
                      box=box.SIMPLE_HEAD)
        table.add_column("step")
        for key in keys:
            table.add_column(RESIDUAL_LABELS.get(key, key.replace("_", " ")), justify="right")
        for p in rows:
            cells = []
            for key in keys:
                value = p.get(key)
                arr = np.asarray(value, float) if value is not None else None
                cells.append("" if arr is None else " ".join(f"{x:+.2e}" for x in np.atleast_1d(arr)))
            table.add_row(str(p.get("label", p.get("step", ""))), *cells)
        return table

    def show_status(self, note: str = "") -> None:
        """PASS or FAIL, ``note``, and what Enter does next."""
        out = self.station.config.out
        passed = all(v.passed for v in self.verdicts)
        text = Text("PASS" if passed else "FAIL", style="bold green" if passed else "bold red")
        text.append(f" against the {limits_name(self.station.config.plan)} limits")
        text.append(f"  {note}\n" if note else "\n")
        if self.saved:
            text.append("Enter: quit")
        elif out is not None:
            text.append(f"Enter: save to {out}" + (f" and export {', '.join(self.station.config.export)}"
                                                    if self.station.config.export else ""))
        else:
            text.append("Enter: choose a file to save to (no --out given), or discard, then quit")
        self.query_one("#status", Static).update(text)

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Enter's binding that says what it does now: save (--out), save and quit (no --out: the app
        asks where), quit (saved)."""
        if action in ("save", "save_and_quit", "quit_saved"):
            wanted = "quit_saved" if self.saved else "save" if self.station.config.out is not None \
                else "save_and_quit"
            return action == wanted
        return True

    def action_save_and_quit(self) -> None:
        """Enter without --out: ask where to save (or discard), then quit."""
        self.action_save()

    def action_quit_saved(self) -> None:
        """Enter once saved: quit."""
        self.action_save()

    def action_save(self) -> None:
        """Save the sections to --out and write the exports (or quit once saved, or without --out:
        the app then asks where to save, or whether to discard). A file of another unit is not
        touched: the app asks to replace it or to choose another file."""
        if self.report is None:
            return
        out = self.station.config.out
        if self.saved or out is None:
            self.station.action_quit_app()
            return
        try:
            self.save_to(out)
        except UnitMismatchError as exc:
            self.station.ask_to_save(self, lambda: None, str(exc), str(out), other_unit=True)
        except (StationError, OSError) as exc:  # OSError: a folder that cannot be made
            self.show_status(f"[could not save: {exc}]")

    def save_to(self, path: Path, replace: bool = False) -> list[str]:
        """Merge the accel and gyro sections into ``path`` and write the --export formats beside it.

        Parameters
        ----------
        path : Path
            The parameter file.
        replace : bool
            Start the file afresh (it holds another unit's results and the operator said so).

        Returns
        -------
        list of str
            The parameter file and each export written.

        Raises
        ------
        UnitMismatchError
            ``path`` holds another unit's results (and ``replace`` is False); it is left untouched.
        StationError
            The file could not be read, merged or written.
        """
        if self.report is None:
            raise StationError("there is no calibration to save")
        session = self.station.session
        save_sections(path, session.info if session is not None else self.run.capture.device,
                      {"accel": self.report.accel, "gyro": self.report.gyro},
                      capture=self.station.config.capture_path(), replace=replace)
        written = [str(path)] + self.write_exports(path)
        self.saved = True
        self.station.saved = written
        self.station.pending = None
        self.show_status("saved " + ", ".join(written))
        self.refresh_bindings()  # Enter now quits
        return written

    def action_export(self) -> None:
        """Write the --export formats again from the saved parameter file."""
        config = self.station.config
        if config.out is None or not Path(config.out).exists():
            self.show_status("save first (Enter): exports are written from the parameter file")
            return
        try:
            self.show_status("exported " + ", ".join(self.write_exports(config.out)))
        except StationError as exc:
            self.show_status(f"[export failed: {exc}]")

    def write_exports(self, params_path: Path) -> list[str]:
        """Write each ``--export`` format of the saved parameter file, as ``imu-station export`` does.

        Parameters
        ----------
        params_path : Path
            The parameter file just saved.

        Returns
        -------
        list of str
            ``"FORMAT -> where"`` for each format written.
        """
        config = self.station.config
        out_dir = config.export_dir or Path(params_path).parent
        params = ParamsFile.load(params_path)
        files: list[str] = []
        for fmt in config.export:
            target = out_dir / "c" if fmt == "c" else out_dir
            write_export(params, fmt, target, source=params_path)
            files.append(f"{fmt} -> {target}")
        return files
