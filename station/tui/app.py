"""The station's TUI application: screens, navigation, the open session."""

from __future__ import annotations

import asyncio
import signal
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from textual.app import App
from textual.binding import Binding
from textual.screen import Screen

from station.acquisition.runner import RunResult
from station.errors import ExitCode, StationError
from station.export.params.file import UnitMismatchError
from station.tui.config import TuiConfig
from station.tui.limits import limits_name
from station.tui.saving import REPLACE_KEY, recovery_path
from station.tui.screens.ask import AskScreen
from station.tui.screens.connect import ConnectScreen
from station.tui.screens.help import HelpScreen
from station.tui.screens.station_screen import StationHost, UnsavedResults
from station.tui.session import Session

# How often the unit's port is read while no screen reads it (results, a question, help): the bytes go
# into the port's bounded buffer instead of piling up in the link (a simulator's queue, a USB buffer),
# so the next screen that reads drains that buffer at once and starts from fresh samples.
KEEP_READ_S = 0.5


class StationApp(App[int]):
    """``config`` says what to open; ``session`` is the open device (None until connected).

    The app's return value is the exit code of ``imu-station tui`` (:meth:`exit_code_for_run`).
    A computed calibration that is not saved is never dropped silently: quitting, Ctrl-C or leaving
    the results screen asks to save, discard or go back; a hang-up (the terminal closed) saves it
    to a file of its own (:func:`~station.tui.saving.recovery_path`).
    """

    TITLE = "imu-station"
    ENABLE_COMMAND_PALETTE = False  # its footer entry would push the screen's own keys off at 80 columns
    HORIZONTAL_BREAKPOINTS = [(0, "-narrow"), (120, "-wide")]
    VERTICAL_BREAKPOINTS = [(0, "-short"), (36, "-tall")]
    BINDINGS = [
        Binding("question_mark", "help", "help", key_display="?"),
        Binding("q", "quit_app", "quit"),
        Binding("ctrl+c", "interrupt", "quit", show=False, priority=True),
        Binding("l", "show('live')", "live", show=False),
        Binding("w", "show('wizard')", "wizard", show=False),
        Binding("a", "show('allan')", "Allan", show=False),
        Binding("t", "show('thermal')", "thermal", show=False),
        Binding("m", "show('mag')", "magnetometer", show=False),
        Binding("o", "show('turnons')", "turn-ons", show=False),
        Binding("d", "show('datasheet')", "datasheet", show=False),
    ]

    def __init__(self, config: TuiConfig) -> None:
        super().__init__()
        self.config = config
        self.session: Session | None = None
        self.last_run: RunResult | None = None
        self.saved: list[str] = []
        self.results_failed = False
        self.calibration_failed = False
        self.pending: UnsavedResults | None = None  # results computed and not yet saved
        self.recovered: Path | None = None
        # Why the last port could not be opened, until one opens: quitting then exits with its code (a
        # missing --port exited 0).
        self.connect_error: Exception | None = None
        self.interrupted = False  # Ctrl-C cut a wizard run short: exit 130, saying so

    def on_mount(self) -> None:
        """Start on the connect screen; a hang-up saves what would be lost."""
        self.sub_title = f"limits: {limits_name(self.config.plan)}"
        self.push_screen(ConnectScreen())
        self.set_interval(KEEP_READ_S, self._keep_port_read)
        try:
            asyncio.get_running_loop().add_signal_handler(signal.SIGHUP, self.on_hangup)
        except (NotImplementedError, RuntimeError, ValueError):
            pass  # no SIGHUP on this platform, or not the main thread: nothing to hang up on

    def _keep_port_read(self) -> None:
        """Read what the unit's port has (asking for the link statistics does): its samples wait in the
        port's bounded buffer for the next screen that reads."""
        if self.session is not None:
            self.session.device.stats  # noqa: B018  (the read is the point)

    def on_hangup(self) -> None:
        """The terminal is gone, so nobody can be asked: save unsaved results beside --out, then exit."""
        results = self.pending
        if results is not None:
            path = recovery_path(self.config.out)
            try:
                results.save_to(path)
                self.recovered = path
            except (StationError, OSError):
                pass  # nowhere left to say it; the exit code still tells the script
        self.exit(self.exit_code_for_run())

    def action_help(self) -> None:
        """Show the help screen (once)."""
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen())

    def action_show(self, name: str) -> None:
        """Key binding: switch to the screen ``name`` (:meth:`show`)."""
        self.show(name)

    def show(self, name: str) -> None:
        """Switch to a screen by name; everything but connect needs an open session. Leaving
        unsaved results asks first (:meth:`leave`)."""
        if self.session is None and name != "datasheet":  # the datasheet reads --out alone
            self.notify("connect to a unit first (Enter on a port)", severity="warning")
            return
        self.leave(lambda: self._switch(name))

    def _switch(self, name: str) -> None:
        from station.tui.screens.allan import AllanScreen
        from station.tui.screens.live import LiveScreen
        from station.tui.screens.thermal import ThermalScreen
        from station.tui.screens.wizard import WizardScreen, build_sequence

        screen: Screen[None]
        if name == "live":
            screen = LiveScreen()
        elif name == "wizard":
            screen = WizardScreen(build_sequence(self.config))
        elif name == "allan":
            screen = AllanScreen()
        elif name == "thermal":
            screen = ThermalScreen()
        elif name == "mag":
            from station.tui.screens.mag import MagScreen

            screen = MagScreen()
        elif name == "datasheet":
            from station.tui.screens.datasheet import DatasheetScreen

            screen = DatasheetScreen()
        elif name == "turnons":
            from station.tui.screens.turn_ons import TurnOnsScreen

            screen = TurnOnsScreen()
        else:
            raise ValueError(name)
        self.switch_screen(screen)

    def show_results(self, result: RunResult) -> None:
        """Replace the current screen by the results of ``result``."""
        from station.tui.screens.results import ResultsScreen

        self.switch_screen(ResultsScreen(result))

    def action_quit_app(self) -> None:
        """Quit with the exit code of the last run (:meth:`exit_code_for_run`), once unsaved results
        are saved or discarded."""
        self.leave(lambda: self.exit(self.exit_code_for_run()))

    def action_interrupt(self) -> None:
        """Ctrl-C: during a wizard run, stop it (what was captured is kept) and exit 130 (the command says
        it was interrupted); else as ``q``."""
        if self.pending is None and self._run_in_progress():
            self.interrupted = True
            self.exit(ExitCode.INTERRUPTED)
            return
        self.action_quit_app()

    def _run_in_progress(self) -> bool:
        from station.tui.screens.wizard import WizardScreen

        screen = self.screen
        return isinstance(screen, WizardScreen) and screen.result is None and screen.current >= 0

    def exit_note(self) -> str | None:
        """The line the command prints on leaving, if any: the interrupted run and where its capture
        is, or why the port could not be opened (nothing else was done)."""
        if self.interrupted:
            path = self.config.capture_path()
            where = f"what was captured is in {path}" if path is not None else \
                "no --capture or --out was given, so the samples were not written"
            return f"interrupted during the sequence wizard; {where}"
        if self._connect_failed():
            return f"error: {self.connect_error}"
        return None

    def _connect_failed(self) -> bool:
        return self.connect_error is not None and self.session is None and self.last_run is None

    def leave(self, then: Callable[[], object]) -> None:
        """Run ``then`` now, or, with unsaved results, once the operator saved or discarded them.

        Parameters
        ----------
        then : callable
            What leaving does (quit, or show another screen); not run when the operator goes back.
        """
        results = self.pending
        if results is None or isinstance(self.screen, AskScreen):
            if results is None:
                then()
            return
        out = self.config.out
        where = f"save to {out}" if out is not None else "no --out was given"
        self.ask_to_save(results, then, f"The calibration is not saved ({where}).", str(out or "params.yaml"))

    def ask_to_save(self, results: UnsavedResults, then: Callable[[], object], question: str,
                    path: str, other_unit: bool = False) -> None:
        """Ask to save ``results`` (to an editable file name), discard them, or go back.

        Parameters
        ----------
        results : UnsavedResults
            The results screen holding the calibration.
        then : callable
            What to do once saved or discarded.
        question : str
            Why it asks.
        path : str
            The file name offered.
        other_unit : bool
            ``path`` holds another unit's results: offer to replace it too.
        """
        def answered(reply: tuple[str, str] | None) -> None:
            key, chosen = reply if reply is not None else ("back", "")
            if key == "d":
                self.pending = None
                then()
            elif key in ("s", REPLACE_KEY):
                if not chosen:
                    self.ask_to_save(results, then, "Give a file name to save to.", path)
                    return
                try:
                    results.save_to(Path(chosen), replace=key == REPLACE_KEY)
                except UnitMismatchError as exc:
                    self.ask_to_save(results, then, str(exc), chosen, other_unit=True)
                    return
                except (StationError, OSError) as exc:  # OSError: a folder that cannot be made
                    self.ask_to_save(results, then, f"Could not save: {exc}", chosen)
                    return
                then()

        answers = [("s", "save" if not other_unit else "save to the file named here (e: edit)")]
        if other_unit:
            answers.append((REPLACE_KEY, "replace that file: its sections are dropped"))
        answers.append(("d", "discard the results"))
        self.push_screen(AskScreen(question, answers, path), answered)

    def exit_code_for_run(self) -> int:
        """2 (aborted) when the last run did not complete, is cut short by quitting or its data
        gave no calibration; 1 when a result is outside its limits; the error's code (3 for a port,
        :class:`~station.errors.ExitCode`) when no port was ever opened because the last one failed;
        else 0."""
        if self._connect_failed():
            error = self.connect_error
            return error.exit_code if isinstance(error, StationError) else ExitCode.DEVICE
        run = self.last_run
        cut_short = self._run_in_progress()
        if cut_short or (run is not None and run.outcome != "completed") or self.calibration_failed:
            return ExitCode.ABORTED
        return ExitCode.OUT_OF_LIMITS if self.results_failed else ExitCode.OK

    def close_session(self) -> None:
        """Close the unit's session, if one is open."""
        if self.session is not None:
            self.session.close()
            self.session = None

    async def action_quit(self) -> None:
        """Textual's quit binding: the same as :meth:`action_quit_app`."""
        self.action_quit_app()

    def on_unmount(self) -> None:
        """Close the session when the app ends."""
        try:
            asyncio.get_running_loop().remove_signal_handler(signal.SIGHUP)
        except (NotImplementedError, RuntimeError, ValueError):
            pass  # never installed (see on_mount)
        self.close_session()


if TYPE_CHECKING:
    # The screens reach the app through StationHost (they cannot import it: it imports them); this is where
    # mypy checks that the app is one.
    _HOST: type[StationHost] = StationApp
