"""Help on ``?``: every key of every screen."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

HELP = """\
[b]imu-station TUI: keys[/b]   (keyboard only; Enter always does the next thing)

[b]Everywhere[/b]
  ?        this help              q / ctrl+q   quit
  l        live view              w            sequence wizard
  a        Allan recording        t            temperature-sweep monitor

[b]Connect[/b]
  up/down  choose a port          Enter        connect / continue to the live view
  c        choose another port

[b]Live view[/b]
  Enter    start the sequence wizard

[b]Sequence wizard[/b]
  Enter    answer the prompt with its default (start, redo a failed step, ...)
  r        redo the current step  s            skip the current step
  k        keep a step that failed a check   x   abort (what was captured is kept)
  The unit is captured automatically once it is in the asked pose and still.

[b]Results[/b]
  Enter    save the parameter file (--out) and the exports, then quit
  e        export only

[b]Allan recording / temperature sweep[/b]
  Enter    stop the recording and fit        Escape   back
"""


class HelpScreen(ModalScreen[None]):
    BINDINGS = [Binding("escape,question_mark,enter,q", "dismiss", "close")]
    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll {
        width: 84; height: 30; border: round $accent; background: $panel; padding: 0 1;
    }
    """

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static(HELP)
