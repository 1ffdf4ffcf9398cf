"""The base of the station's screens, and what they need of the app they run in.

The screens see the app as a :class:`StationHost`: the state and navigation of
:class:`~station.tui.app.StationApp` they use, not the app's class. The app imports every screen, so a
screen that imported the app, even for its type alone, would close an import circle; the app is checked
against this protocol where it is defined.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol, cast

from textual.events import Resize
from textual.screen import Screen

from station.acquisition.runner import RunResult
from station.tui.config import TuiConfig
from station.tui.session import Session


class UnsavedResults(Protocol):
    """Results computed and not yet saved (the results screen), as the app keeps and saves them."""

    def save_to(self, path: Path, replace: bool = False) -> list[str]:
        """Write the results to ``path`` (and the exports beside it); the files written."""
        ...


class StationHost(Protocol):
    """What the screens use of :class:`~station.tui.app.StationApp`: its config, the open session, the
    outcome of the last run, and its navigation."""

    config: TuiConfig
    session: Session | None
    last_run: RunResult | None
    saved: list[str]
    results_failed: bool
    calibration_failed: bool
    pending: UnsavedResults | None
    connect_error: Exception | None

    def show(self, name: str) -> None:
        """Switch to the screen ``name``."""
        ...

    def show_results(self, result: RunResult) -> None:
        """Replace the current screen by the results of ``result``."""
        ...

    def close_session(self) -> None:
        """Close the unit's session, if one is open."""
        ...

    def action_quit_app(self) -> None:
        """Quit, once unsaved results are saved or discarded."""
        ...

    def ask_to_save(self, results: UnsavedResults, then: Callable[[], object], question: str,
                    path: str, other_unit: bool = False) -> None:
        """Ask to save ``results``, discard them, or go back."""
        ...


class StationScreen(Screen[None]):
    """A screen of :class:`~station.tui.app.StationApp`.

    ``TOASTS_ABOVE`` names the widget whose top the screen's notices (toasts) stay above: textual puts
    them above the footer alone, where at 80x24 they covered the wizard's line of keys.
    """

    TOASTS_ABOVE: str | None = None

    def on_resize(self, event: Resize) -> None:
        """Keep the notices above ``TOASTS_ABOVE`` at the new size, once laid out."""
        self.call_after_refresh(self.place_toasts)

    def place_toasts(self) -> None:
        """Raise the screen's notices above the top of ``TOASTS_ABOVE`` (as laid out now)."""
        if self.TOASTS_ABOVE is None:
            return
        racks = self.query("#textual-toastrack")  # the rack textual gives every screen
        anchors = self.query(self.TOASTS_ABOVE)
        if not racks or not anchors:
            return
        below = self.size.height - anchors.first().region.y  # rows from the anchor's top down
        racks.first().styles.margin = (0, 0, max(1, below), 0)

    @property
    def station(self) -> StationHost:
        """The app with its config and session (textual types ``self.app`` as any App)."""
        return cast(StationHost, self.app)

    @property
    def session(self) -> Session:
        """The open session: the app shows every screen but connect only while one is open."""
        session = self.station.session
        if session is None:
            raise RuntimeError(f"{type(self).__name__} needs an open session; StationApp.show opens it first")
        return session
