"""The sequence wizard: each step's instruction and drawing, live checks, automatic capture, prompts.

With ``--table`` the rate table places and turns the unit for each step
(:class:`~station.tui.table.TableTuiOperator`) and the step panel says what it is doing; ``x``
(abort) or Escape stops the table at once, as does leaving the screen."""

from __future__ import annotations

import time

from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.timer import Timer
from textual.widgets import Footer, Header, ProgressBar, Static

from station.acquisition.operator import Action, Operator, Prompt, SimulatedOperator
from station.acquisition.recorder import Recorder
from station.acquisition.runner import (
    LiveStatus,
    RecorderSink,
    RunOptions,
    RunResult,
    SequenceRunner,
    State,
    StepRecord,
)
from station.acquisition.sequences import PoseStep, Sequence, Step, resolve
from station.errors import StationError
from station.tui.art import bar, step_caption, step_drawing, step_instruction
from station.tui.bridge import RunnerEvent, TuiOperator
from station.tui.config import TuiConfig
from station.tui.messages import LinkFailed
from station.tui.screens.station_screen import StationScreen
from station.tui.table import TableTuiOperator

MARKS = {"accepted": "[green]✓[/green]", "skipped": "[yellow]↷[/yellow]", "failed": "[red]✗[/red]",
         "aborted": "[red]✗[/red]"}
KEYS = {Action.ACCEPT: "k", Action.REDO: "r", Action.SKIP: "s", Action.ABORT: "x"}
IDLE_HINT = "r: redo this step · s: skip it · x: abort (what was captured is kept)"
STEP_NOTICE_S = 3600.0  # a step's notice stays until the step ends (cleared then), not on a timer
NAMES = {Action.ACCEPT: "go on", Action.REDO: "redo", Action.SKIP: "skip", Action.ABORT: "abort"}
# The live checks' frame rate, whatever the unit's: the runner sends at most this many statuses a second
# (and forced ones at a step's events), the screen draws the newest at most this often, without a layout
# pass while the checks keep their lines. 20 a second through a rich Table and a layout pass each was
# most of the wizard's CPU during a capture (issue 30).
UI_RATE_HZ = 10.0
LABEL_WIDTH = 6


def build_sequence(config: TuiConfig) -> Sequence:
    """The sequence the config asks for (built-in name or file, rotations, hold, turn rate)."""
    return resolve(config.sequence, rotations=config.rotations, hold_s=config.hold_s,
                   rotation_rate_dps=config.rotation_rate_dps)


class WizardScreen(StationScreen):
    """The sequence run step by step: what to do and its drawing on the left, the live checks and
    the capture's progress on the right, the steps and the prompt below."""

    BINDINGS = [
        Binding("enter", "answer('default')", "next", show=True),
        Binding("r", "answer('redo')", "redo"),
        Binding("s", "answer('skip')", "skip"),
        Binding("k", "answer('accept')", "keep", show=False),  # offered by the prompt that needs it
        Binding("x", "answer('abort')", "abort"),
        Binding("escape", "stop_table", "stop the table", show=False),  # with --table
    ]
    # At 80x24 the borders go but the steps' and the prompt's top rule: the drawing keeps its rows.
    DEFAULT_CSS = """
    WizardScreen #top { height: 1fr; }
    WizardScreen #step { width: 1fr; border: round $accent; padding: 0 1; }
    WizardScreen #side { width: 52; }
    WizardScreen.-narrow #side { width: 34; }
    WizardScreen #checks { border: round $secondary; padding: 0 1; height: auto; }
    WizardScreen.-short #checks { border: none; border-left: round $secondary; }
    WizardScreen #capture { padding: 0 1; height: 1; }
    WizardScreen #steps { height: auto; padding: 0 1; border: round $primary; }
    WizardScreen.-short #steps { border: none; border-top: solid $primary; }
    WizardScreen #prompt { height: auto; min-height: 3; border: heavy $warning; padding: 0 1; }
    WizardScreen.-short #prompt { min-height: 2; border: none; border-top: heavy $warning; }
    """

    TOASTS_ABOVE = "#steps"  # the steps, the prompt and its keys stay readable under a notice

    def __init__(self, sequence: Sequence) -> None:
        super().__init__()
        self.sequence = sequence
        self.records: dict[str, StepRecord] = {}
        self.current = -1
        self.result: RunResult | None = None
        self.prompt: Prompt | None = None
        self.table_operator: TableTuiOperator | None = None
        self.step_head = Text()
        self.step_foot = ""
        self.table_line: Text | None = None
        self.status: LiveStatus | None = None  # the newest live status, drawn at most UI_RATE_HZ a second
        self._status_drawn = 0.0  # time.monotonic() of the last drawing
        self._status_timer: Timer | None = None
        self._checks_shape: tuple[int, str] | None = None

    def compose(self) -> ComposeResult:
        """The step panel, the checks with the progress bar, the steps, the prompt, the keys."""
        yield Header()
        with Horizontal(id="top"):
            yield Static("", id="step")
            with Vertical(id="side"):
                yield Static("", id="checks")
                yield ProgressBar(total=1.0, show_eta=False, id="capture")
        yield Static("", id="steps")
        yield Static("", id="prompt")
        yield Footer()

    def on_mount(self) -> None:
        """Show the overview and start the run."""
        self.title = f"imu-station · {self.sequence.name}"
        self.step_notices = False
        self.operator = TuiOperator(self)
        table = self.session.table
        if table is not None:
            self.table_operator = TableTuiOperator(table, self.operator)
        overview = Text(f"Sequence {self.sequence.name}\n\n", style="bold")
        if table is not None:
            overview.append(f"The rate table {table.table.url} places and turns the unit (mounted "
                            f"{table.mount} along its axis) for every step: keep clear of it. Capture "
                            "starts by itself once the unit is in the pose and still, and the next step "
                            "follows.\n\n"
                            "x or Escape: abort and stop the table (what was captured is kept) · ? help")
        else:
            overview.append("For each step: put the unit as drawn and let go. Capture starts by itself once "
                            "the unit is in the pose and still, and the next step follows. A turn is asked "
                            "for after a short still capture; turn at about the rate shown, then hold "
                            "still.\n\nr redo · s skip · x abort (what was captured is kept) · ? help")
        self.query_one("#step", Static).update(overview)
        self.show_steps()
        self._run()

    def on_unmount(self) -> None:
        """Abort the run's prompts and stop the table: the screen is going away."""
        self.operator.close()
        if self.table_operator is not None and self.result is None:
            self.table_operator.stop_soon()

    @work(thread=True, exclusive=True, group="reader")
    def _run(self) -> None:
        session = self.session
        operator: Operator
        if self.table_operator is not None:
            operator = self.table_operator
        elif session.rig is None:
            operator = self.operator
        else:
            operator = SimulatedOperator(session.rig, self.operator)
        path = self.station.config.capture_path()
        try:
            recorder = None
            if path is not None:
                recorder = Recorder(path, device=session.info, with_step=True, port=session.name,
                                    protocol=session.device.protocol)
            options = RunOptions(status_rate_hz=UI_RATE_HZ)
            runner = SequenceRunner(session.device, self.sequence, operator, options,
                                    sink=RecorderSink(recorder, session.device) if recorder else None)
            try:
                runner.run()
            finally:
                if recorder is not None:
                    # The link with the clock guard's counts (outliers, jumps), not the device's alone.
                    recorder.close(runner.link_stats().as_dict())
        except (StationError, OSError) as exc:
            # The capture file could not be written (disk full, no permission): say so on the screen.
            self.post_message(LinkFailed(exc))

    def on_link_failed(self, message: LinkFailed) -> None:
        """The run stopped: say why."""
        text = Text(f"The run stopped: {message.error}\nq: quit", style="red")
        self.query_one("#prompt", Static).update(text)

    # ---- runner events -------------------------------------------------------------------------

    def on_runner_event(self, event: RunnerEvent) -> None:
        """Dispatch what the runner told the operator to ``_on_<kind>``."""
        handler = getattr(self, f"_on_{event.kind}")
        handler(event)

    def _on_begin(self, event: RunnerEvent) -> None:
        self.show_steps()

    def _on_place(self, event: RunnerEvent) -> None:
        self.current = event.index
        step: Step = event.payload
        # The caption first: on a short terminal the drawing's foot is what gets cut, not the words.
        title = Text(f"Step {event.index + 1} of {event.total}: {step.label}\n", style="bold")
        if isinstance(step, PoseStep):  # a turn's caption says all its instruction does
            title.append(step_instruction(step) + "\n")
        title.append("\n".join(step_caption(step)) + "\n", style="bold cyan")
        self.step_head, self.step_foot = title, "\n".join(step_drawing(step))
        self.table_line = None
        self.show_step()
        self.show_steps()

    def show_step(self) -> None:
        """The step's caption, what the table is doing (with --table), then its drawing."""
        text = self.step_head.copy()
        if self.table_line is not None:
            text.append_text(self.table_line)
            text.append("\n")
        text.append(self.step_foot)
        self.query_one("#step", Static).update(text)

    def _on_table(self, event: RunnerEvent) -> None:
        self.table_line = Text(f"{event.payload} (keep clear)", style="bold magenta")
        self.show_step()

    def _on_table_failed(self, event: RunnerEvent) -> None:
        self.table_line = Text(f"The table failed and was stopped: {event.payload}", style="bold red")
        self.show_step()

    def action_stop_table(self) -> None:
        """Escape with --table: stop the table at once and abort the run (what was captured is kept)."""
        if self.table_operator is None or self.result is not None:
            return
        self.table_operator.stop_soon()
        self.table_line = Text("Stopped: the table is brought to rest; the run is aborted.", style="bold red")
        self.show_step()
        self.action_answer("abort")

    def _on_rotate(self, event: RunnerEvent) -> None:
        self.place_toasts()
        self.notify(f"Turn now: {event.payload.label}", timeout=STEP_NOTICE_S)
        self.step_notices = True

    def end_step_notices(self) -> None:
        """Take down the notices of the step that ended."""
        if self.step_notices:
            self.app.clear_notifications()
            self.step_notices = False

    def _on_status(self, event: RunnerEvent) -> None:
        self.status = event.payload
        wait = self._status_drawn + 1.0 / UI_RATE_HZ - time.monotonic()
        if wait <= 0:
            self.show_status()
        elif self._status_timer is None:  # the newest status, when its turn comes
            self._status_timer = self.set_timer(wait, self.show_status)

    def show_status(self) -> None:
        """The newest live status: state, pose, stillness, angle, link, message; the capture's bar."""
        if self._status_timer is not None:
            self._status_timer.stop()
            self._status_timer = None
        s = self.status
        if s is None:
            return
        self._status_drawn = time.monotonic()
        checks = self.query_one("#checks", Static)
        width = max(10, checks.content_size.width - 10)
        rows: list[tuple[str, str | Text]] = [
            ("state", f"{s.state.value}" + (f" (attempt {s.attempt})" if s.attempt > 1 else ""))]
        if s.pose is not None:
            ok = "[green]✓[/green]" if s.pose.ok else "[red]✗[/red]"
            rows.append(("pose", f"{ok} {s.pose.angle_deg:5.1f} deg off, {s.pose.nearest or '?'} up"))
        if s.stillness is not None:
            ok = "[green]✓[/green]" if s.stillness.still else "[yellow]…[/yellow]"
            rows.append(("still", f"{ok} {bar(s.stillness.score, width)}"))
        turned = 0.0
        if s.angle_deg is not None and s.target_deg:
            turned = max(0.0, s.angle_deg / s.target_deg)
            rows.append(("angle", f"{s.angle_deg:+7.1f} of {s.target_deg:+.0f} deg"))
        rows.append(("link", f"{s.rate_hz:.0f} Hz, {s.lost} lost, {s.link_errors} err"))
        rows.append(("", Text(s.message, style="italic")))
        # The rows as a grid of a bold label column and a value column would show them, as one Text: a
        # rich Table measured its columns on every frame.
        text = Text()
        for k, (label, value) in enumerate(rows):
            if k:
                text.append("\n")
            text.append(label.ljust(LABEL_WIDTH) + " ", style="bold")
            text.append_text(value if isinstance(value, Text) else Text.from_markup(value))
        shape = (len(rows), s.message)
        checks.update(text, layout=shape != self._checks_shape)
        self._checks_shape = shape
        # The bar follows the capture of a hold, and the turn itself during a rotation.
        if s.state is State.ROTATING:
            progress = min(1.0, turned)
        elif s.state in (State.CAPTURING, State.SETTLING):
            progress = s.progress
        else:
            progress = 0.0
        self.query_one("#capture", ProgressBar).update(progress=progress)

    def _on_prompt(self, event: RunnerEvent) -> None:
        prompt: Prompt = event.payload
        self.prompt = prompt
        self.show_prompt(prompt)

    def _on_answered(self, event: RunnerEvent) -> None:
        self.prompt = None
        self.query_one("#prompt", Static).update(Text(IDLE_HINT, style="dim"))

    def _on_finished(self, event: RunnerEvent) -> None:
        self.end_step_notices()
        record: StepRecord = event.payload
        self.records[record.label] = record
        self.show_steps()

    def _on_end(self, event: RunnerEvent) -> None:
        self.end_step_notices()
        if self._status_timer is not None:  # no status after the end: the bar stays empty
            self._status_timer.stop()
            self._status_timer = None
        result: RunResult = event.payload
        self.result = result
        self.station.last_run = result
        text = Text(result.summary(), style="bold")
        if result.reason:
            text.append(f"\n{result.reason}")
        table_error = self.table_operator.error if self.table_operator is not None else None
        if table_error is not None:
            text.append(f"\ntable: {table_error}", style="red")
        path = self.station.config.capture_path()
        if path is not None:
            text.append(f"\nCapture saved to {path}")
        if result.capture.mag is not None:
            text.append("\nThe unit has a magnetometer: m for the magnetometer step")
        text.append("\nEnter: compute the calibration and show the results · q: quit")
        self.query_one("#prompt", Static).update(text)
        self.query_one("#capture", ProgressBar).update(progress=0.0)

    # ---- drawing -------------------------------------------------------------------------------

    def show_steps(self) -> None:
        """One mark per step: done, skipped, failed, current or to come."""
        text = Text()
        for i, step in enumerate(self.sequence.steps):
            record = self.records.get(step.label)
            if record is not None:
                text.append_text(Text.from_markup(MARKS.get(record.status, "?")))
            elif i == self.current and self.result is None:
                text.append("▶", style="bold cyan")
            else:
                text.append("·", style="dim")
            text.append(f"{step.label} ", style="bold" if i == self.current else "")
        self.query_one("#steps", Static).update(text)

    def show_prompt(self, prompt: Prompt) -> None:
        """The runner's question, its details and the key of each answer."""
        text = Text(prompt.text + "\n", style="bold")
        for line in prompt.details:
            text.append(f"  {line}\n", style="yellow")
        keys = [f"{'Enter' if a is prompt.default else KEYS[a]}: {NAMES[a]}" for a in prompt.choices]
        text.append(" · ".join(keys))
        self.query_one("#prompt", Static).update(text)

    # ---- keys ----------------------------------------------------------------------------------

    def action_answer(self, which: str) -> None:
        """Answer the prompt (Enter: its default), or request redo, skip or abort between prompts."""
        if self.result is not None:
            if which == "default":
                self.station.show_results(self.result)
            return
        prompt = self.prompt
        if which == "default":
            if prompt is None:
                return
            action = prompt.default
        else:
            action = Action(which)
        if action is Action.ABORT and self.table_operator is not None:
            self.table_operator.stop_soon()  # at once, not at the runner's next poll
        if not self.operator.answer(action) and prompt is None:
            self.place_toasts()
            self.notify(f"{NAMES[action]} requested", timeout=STEP_NOTICE_S)
            self.step_notices = True

