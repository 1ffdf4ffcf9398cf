"""Help on ``?``: every key of every screen."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

HELP = """\
[b]imu-station TUI: keys[/b]  (Enter always does the next thing)

[b]Everywhere[/b]
  ?        this help              q, ctrl+c  quit (asks first about
                                             unsaved results)
  l        live view              w          sequence wizard
  a        Allan recording        t          temperature sweep
  o        turn-on repeatability (restarts the unit, or asks
           you to power-cycle it)
  m        magnetometer step      d          datasheet of --out

[b]Connect[/b]
  up/down  choose a port          Enter      connect, then the live view
  c        choose another port    p          change the protocol

[b]Live view[/b]
  Enter    start the sequence wizard

[b]Sequence wizard[/b]
  Enter    answer the prompt with its default (start, redo, ...)
  r        redo the current step  s          skip the current step
  k        keep a failed step     x          abort (keeps what was
                                             captured)
  Capture starts by itself once the unit is in the pose and still.

[b]Results[/b]
  Enter    save to --out and write the exports, then quit
  e        export only            up/down    scroll the tables
  Judged against the built-in loose limits or a factory plan's
  (--plan); the header says which.

[b]Magnetometer step[/b]
  Turn the unit until the two half-spheres are filled: it ends
  by itself at 80 %.  Enter  finish earlier (from 15 %)
  Escape   back to the live view

[b]Allan recording / temperature sweep[/b]
  Enter    stop the recording and fit   Escape   back

[b]Datasheet[/b] (also without a unit)
  The figures of --out; across temperature, the scale factor's change
  and the turn-on repeatability per soak, plotted.
  s        plot the other triad   r          read --out again
  Escape   back
"""


class HelpScreen(ModalScreen[None]):
    """Every key of every screen; it scrolls where the terminal is smaller than it."""

    BINDINGS = [Binding("escape,question_mark,enter,q", "dismiss", "close")]
    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll {
        width: 92; max-width: 100%; height: 30; max-height: 100%; border: round $accent;
        background: $panel; padding: 0 1;
    }
    """

    def compose(self) -> ComposeResult:
        """The keys, in a scrolling box."""
        with VerticalScroll():
            yield Static(HELP)
