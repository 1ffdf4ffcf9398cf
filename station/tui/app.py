"""The station's TUI application: screens, navigation, the open session."""

from __future__ import annotations

from textual.app import App
from textual.binding import Binding
from textual.screen import Screen

from station.acquisition.runner import RunResult
from station.errors import ExitCode
from station.tui.config import TuiConfig
from station.tui.screens.connect import ConnectScreen
from station.tui.screens.help import HelpScreen
from station.tui.session import Session


class StationApp(App[int]):
    """``config`` says what to open; ``session`` is the open device (None until connected).

    The app's return value is the exit code of ``imu-station tui``: 0 unless a run was aborted
    or failed (1).
    """

    TITLE = "imu-station"
    BINDINGS = [
        Binding("question_mark", "help", "help", key_display="?"),
        Binding("q", "quit_app", "quit"),
        Binding("l", "show('live')", "live", show=False),
        Binding("w", "show('wizard')", "wizard", show=False),
        Binding("a", "show('allan')", "Allan", show=False),
        Binding("t", "show('thermal')", "thermal", show=False),
    ]

    def __init__(self, config: TuiConfig) -> None:
        super().__init__()
        self.config = config
        self.session: Session | None = None
        self.last_run: RunResult | None = None
        self.saved: list[str] = []
        self.results_failed = False

    def on_mount(self) -> None:
        """Start on the connect screen."""
        self.push_screen(ConnectScreen())

    def action_help(self) -> None:
        """Show the help screen (once)."""
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen())

    def action_show(self, name: str) -> None:
        """Key binding: switch to the screen ``name`` (:meth:`show`)."""
        self.show(name)

    def show(self, name: str) -> None:
        """Switch to a screen by name; everything but connect needs an open session."""
        if self.session is None:
            self.notify("connect to a unit first (Enter on a port)", severity="warning")
            return
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
        else:
            raise ValueError(name)
        self.switch_screen(screen)

    def show_results(self, result: RunResult) -> None:
        """Replace the current screen by the results of ``result``."""
        from station.tui.screens.results import ResultsScreen

        self.switch_screen(ResultsScreen(result))

    def action_quit_app(self) -> None:
        """Quit with the exit code of the last run (:meth:`exit_code_for_run`)."""
        self.exit(self.exit_code_for_run())

    def exit_code_for_run(self) -> int:
        """1 when the last run did not complete (or is cut short by quitting) or its results are
        outside their limits, else 0."""
        from station.tui.screens.wizard import WizardScreen

        run = self.last_run
        screen = self.screen
        cut_short = isinstance(screen, WizardScreen) and screen.result is None and screen.current >= 0
        failed = (run is not None and run.outcome != "completed") or self.results_failed or cut_short
        return ExitCode.OUT_OF_LIMITS if failed else ExitCode.OK

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
        self.close_session()
