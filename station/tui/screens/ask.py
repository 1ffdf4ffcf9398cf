"""A question with a few one-key answers, and optionally a file name to edit: the TUI's confirmations."""

from __future__ import annotations

from rich.text import Text
from textual import events
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Input, Static


class AskScreen(ModalScreen[tuple[str, str]]):
    """``question`` with ``answers`` (key, what it does); dismissed with ``(key, path)``.

    Escape answers ``back``. With ``path`` given, an input holds the file the answer applies to:
    ``e`` edits it and Enter in it answers with the first answer's key.

    Parameters
    ----------
    question : str
        What is asked, one or two short lines.
    answers : list of (str, str)
        Each answer's key and what it does; the first is Enter's.
    path : str, optional
        The file name to show and let the operator change.
    """

    DEFAULT_CSS = """
    AskScreen { align: center middle; }
    AskScreen > Vertical { width: 76; max-width: 100%; height: auto; border: heavy $warning;
                           background: $panel; padding: 0 1; }
    AskScreen Input { width: 1fr; }
    """
    BINDINGS = [Binding("escape", "answer('back')", "back", show=False)]

    def __init__(self, question: str, answers: list[tuple[str, str]], path: str | None = None) -> None:
        super().__init__()
        self.question = question
        self.answers = answers
        self.path = path

    def compose(self) -> ComposeResult:
        """The question, the file (if any) and the keys."""
        with Vertical():
            yield Static(Text(self.question, style="bold"), id="question")
            if self.path is not None:
                field = Input(self.path, id="path", placeholder="parameter file")
                field.can_focus = False  # the keys answer; the file name takes them only after ``e``
                yield field
            keys = [f"{key}: {what}" for key, what in self.answers]
            keys.append("Esc: back" + (" · e: edit the file name" if self.path is not None else ""))
            yield Static(" · ".join(keys), id="keys")

    def on_key(self, event: events.Key) -> None:
        """An answer's key (outside the file name) answers; ``e`` edits the file name."""
        key = event.key
        if isinstance(self.focused, Input):
            return
        if key == "e" and self.path is not None:
            field = self.query_one("#path", Input)
            field.can_focus = True
            field.focus()
        elif key == "enter":
            self.action_answer(self.answers[0][0])
        elif any(key == k for k, _ in self.answers):
            self.action_answer(key)
        else:
            return
        event.stop()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        """Enter in the file name answers with the first answer."""
        self.action_answer(self.answers[0][0])

    def action_answer(self, key: str) -> None:
        """Close with ``(key, the file name)``."""
        path = self.query_one("#path", Input).value.strip() if self.path is not None else ""
        self.dismiss((key, path))
