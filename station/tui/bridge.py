"""The TUI side of the runner's Operator interface: runner thread -> messages, keys -> answers.

The runner runs in a thread worker. Everything it tells the operator becomes a textual message
posted to the wizard screen (``post_message`` is thread-safe); a prompt blocks the runner's
thread until the screen answers with :meth:`TuiOperator.answer`. Requests made with keys while
no prompt is open (redo, skip, abort) wait in a queue for the runner's :meth:`poll`.
"""

from __future__ import annotations

import queue
import threading
from typing import Any

from textual.message import Message
from textual.message_pump import MessagePump

from station.acquisition.operator import Action, BaseOperator, Prompt
from station.acquisition.runner import LiveStatus, RunResult, StepRecord
from station.acquisition.sequences import RotationStep, Sequence, Step


class RunnerEvent(Message):
    """Something the runner told the operator; ``kind`` is the Operator method that was called."""

    def __init__(self, kind: str, payload: Any = None, index: int = 0, total: int = 0) -> None:
        super().__init__()
        self.kind = kind
        self.payload = payload  # what that method was given: a Step, a LiveStatus, a Prompt, ...
        self.index = index
        self.total = total


class TuiOperator(BaseOperator):
    """Posts every runner call to ``target`` as a :class:`RunnerEvent`; blocks on prompts."""

    def __init__(self, target: MessagePump) -> None:
        self.target = target
        self._answers: queue.Queue[Action] = queue.Queue()
        self._requests: queue.Queue[Action] = queue.Queue()
        self._prompt: Prompt | None = None
        self._lock = threading.Lock()
        self.closed = threading.Event()

    @property
    def prompt(self) -> Prompt | None:
        """The prompt waiting for the operator, or None."""
        with self._lock:
            return self._prompt

    def answer(self, action: Action) -> bool:
        """Answer the open prompt (True), or queue ``action`` as a request when none is open."""
        with self._lock:
            prompt = self._prompt
            if prompt is not None and action in prompt.choices:
                self._prompt = None
                self._answers.put(action)
                return True
        if prompt is None and action in (Action.REDO, Action.SKIP, Action.ABORT):
            self._requests.put(action)
        return False

    def close(self) -> None:
        """The screen is going away: any open prompt and every later one is answered with abort."""
        self.closed.set()
        self._requests.put(Action.ABORT)
        with self._lock:
            if self._prompt is not None:
                self._prompt = None
                self._answers.put(Action.ABORT)

    def _post(self, kind: str, payload: object = None, index: int = 0, total: int = 0) -> None:
        self.target.post_message(RunnerEvent(kind, payload, index, total))

    def tell(self, kind: str, payload: object = None) -> None:
        """Tell the screen something beside the runner's calls (what the table does: ``table``,
        ``table_failed``)."""
        self._post(kind, payload)

    def begin(self, sequence: Sequence) -> None:
        """Tell the screen the run of ``sequence`` starts."""
        self._post("begin", sequence)

    def place(self, step: Step, index: int, total: int) -> None:
        """Tell the screen to ask for the step's pose."""
        self._post("place", step, index, total)

    def rotate(self, step: RotationStep) -> None:
        """Tell the screen to ask for the step's rotation."""
        self._post("rotate", step)

    def status(self, status: LiveStatus) -> None:
        """Pass the live status to the screen."""
        self._post("status", status)

    def poll(self) -> Action | None:
        """The operator's queued request (key press), if any."""
        try:
            return self._requests.get_nowait()
        except queue.Empty:
            return None

    def confirm(self, prompt: Prompt) -> Action:
        """Post the prompt to the screen and block the runner's thread until it is answered (abort
        once the screen is closed)."""
        if self.closed.is_set():
            return Action.ABORT if Action.ABORT in prompt.choices else prompt.choices[-1]
        with self._lock:
            self._prompt = prompt
        self._post("prompt", prompt)
        action = self._answers.get()
        if action not in prompt.choices:
            action = prompt.choices[-1]
        self._post("answered", action)
        return action

    def step_finished(self, record: StepRecord) -> None:
        """Pass the step's record to the screen."""
        self._post("finished", record)

    def end(self, result: RunResult) -> None:
        """Pass the run's result to the screen."""
        self._post("end", result)
