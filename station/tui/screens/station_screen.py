"""The base of the station's screens: the app they run in, with its type."""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

from textual.screen import Screen

from station.tui.session import Session

if TYPE_CHECKING:
    from station.tui.app import StationApp


class StationScreen(Screen[None]):
    """A screen of :class:`~station.tui.app.StationApp`."""

    @property
    def station(self) -> StationApp:
        """The app with its config and session (textual types ``self.app`` as any App)."""
        return cast("StationApp", self.app)

    @property
    def session(self) -> Session:
        """The open session: the app shows every screen but connect only while one is open."""
        session = self.station.session
        if session is None:
            raise RuntimeError(f"{type(self).__name__} needs an open session; StationApp.show opens it first")
        return session
