"""The operator the sequence runner talks to: whoever places the unit and answers its questions.

The runner asks an :class:`Operator` to place the unit for a step, to turn it, and to confirm
(start, review a failed check, give up waiting); it tells it the live state at most ~20 times a
second and polls it for asynchronous requests (redo, skip, abort). The TUI, a factory script,
a turntable and the tests each implement it:

- :class:`ScriptedOperator`: answers from a script (a mapping of prompt kinds to answers, or a
  callable), for factory lines with a manual fixture and for tests; keeps a transcript.
- :class:`SimulatedOperator`: wraps another operator and moves the simulated unit as each step
  asks, so a whole sequence runs unattended against the simulator.
"""

from __future__ import annotations

import enum
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from station.acquisition.run_records import LiveStatus, RunResult, StepRecord
from station.acquisition.sequences import PoseStep, RotationStep, Sequence, Step


class Action(enum.Enum):
    """What the operator can answer or request."""

    ACCEPT = "accept"
    REDO = "redo"
    SKIP = "skip"
    ABORT = "abort"


@dataclass(frozen=True)
class Prompt:
    """A question the runner blocks on. ``default`` is what Enter answers in the TUI.

    ``kind``: ``start`` (begin the sequence), ``review`` (a step failed a check),
    ``timeout`` (the unit did not reach the asked state in time).
    """

    kind: str
    text: str
    choices: tuple[Action, ...]
    default: Action
    step: Step | None = None
    details: tuple[str, ...] = ()


class Operator(Protocol):
    """What the runner needs of whoever handles the unit. See the module docstring."""

    def begin(self, sequence: Sequence) -> None:
        """The run of ``sequence`` starts."""

    def place(self, step: Step, index: int, total: int) -> None:
        """Ask for the unit in the step's pose (a rotation's start pose); returns at once."""

    def rotate(self, step: RotationStep) -> None:
        """Ask for the turn of a rotation step now (the unit is in its start pose and still)."""

    def status(self, status: LiveStatus) -> None:
        """The live state; called at most ``RunOptions.status_rate_hz`` times a second."""

    def poll(self) -> Action | None:
        """An asynchronous request (redo, skip or abort the current step), or None."""

    def confirm(self, prompt: Prompt) -> Action:
        """Block until the operator answers one of ``prompt.choices``."""

    def step_finished(self, record: StepRecord) -> None:
        """A step ended (accepted, repeated or skipped): its record."""

    def end(self, result: RunResult) -> None:
        """The run ended: its result."""


class BaseOperator:
    """Does nothing on every call and accepts every prompt's default; subclass what you need."""

    def begin(self, sequence: Sequence) -> None:
        """Nothing to do when the run starts."""

    def place(self, step: Step, index: int, total: int) -> None:
        """Nothing to do: the unit is assumed in place."""

    def rotate(self, step: RotationStep) -> None:
        """Nothing to do: the rotation is assumed done."""

    def status(self, status: LiveStatus) -> None:
        """Ignore the live status."""

    def poll(self) -> Action | None:
        """No request from the operator."""
        return None

    def confirm(self, prompt: Prompt) -> Action:
        """Accept the prompt's default action."""
        return prompt.default

    def step_finished(self, record: StepRecord) -> None:
        """Nothing to do when a step ends."""

    def end(self, result: RunResult) -> None:
        """Nothing to do when the run ends."""


Answer = Action | str | Callable[[Prompt], Action | str]

def redo_then_abort(prompt: Prompt) -> Action:
    """Redo a failed step while the runner still offers it (``RunOptions.max_attempts``), then abort."""
    return Action.REDO if Action.REDO in prompt.choices else Action.ABORT


# What a factory line wants when nobody is there: go on, retry a failed step a few times,
# give up on a unit that never gets into position.
FACTORY_ANSWERS: dict[str, Answer] = {"start": Action.ACCEPT, "review": redo_then_abort,
                                      "timeout": Action.ABORT}


@dataclass
class TranscriptEntry:
    """One event a scripted operator saw: its kind, the step label and a detail."""

    event: str
    label: str = ""
    detail: str = ""


@dataclass
class ScriptedOperator(BaseOperator):
    """Answers prompts from ``answers`` (prompt kind -> Action, its name, or a callable of the prompt).

    Kinds missing from ``answers`` get the prompt's default. ``on_place``/``on_rotate`` let a
    factory script drive a fixture or tell a person at the line; ``requests`` queues
    asynchronous requests (as a TUI key would) for :meth:`poll`. Every call is recorded in
    ``transcript``.
    """

    answers: Mapping[str, Answer] = field(default_factory=dict)
    on_place: Callable[[Step, int, int], None] | None = None
    on_rotate: Callable[[RotationStep], None] | None = None
    transcript: list[TranscriptEntry] = field(default_factory=list)
    statuses: int = 0

    def __post_init__(self) -> None:
        self._requests: list[Action] = []
        self._lock = threading.Lock()

    def request(self, action: Action | str) -> None:
        """Queue an asynchronous request (redo, skip, abort), as an operator's key press would."""
        with self._lock:
            self._requests.append(Action(action))

    def begin(self, sequence: Sequence) -> None:
        """Note the start in the transcript."""
        self.transcript.append(TranscriptEntry("begin", sequence.name))

    def place(self, step: Step, index: int, total: int) -> None:
        """Note the placement, then call ``on_place`` if given (a test moves the unit there)."""
        self.transcript.append(TranscriptEntry("place", step.label, f"{index + 1}/{total}"))
        if self.on_place is not None:
            self.on_place(step, index, total)

    def rotate(self, step: RotationStep) -> None:
        """Note the rotation, then call ``on_rotate`` if given."""
        self.transcript.append(TranscriptEntry("rotate", step.label))
        if self.on_rotate is not None:
            self.on_rotate(step)

    def status(self, status: LiveStatus) -> None:
        """Count the live status updates."""
        self.statuses += 1

    def poll(self) -> Action | None:
        """The oldest queued request (``request``), if any."""
        with self._lock:
            return self._requests.pop(0) if self._requests else None

    def confirm(self, prompt: Prompt) -> Action:
        """The scripted answer for the prompt's kind (or its default), noted in the transcript."""
        answer: Any = self.answers.get(prompt.kind, prompt.default)
        if callable(answer) and not isinstance(answer, Action):
            answer = answer(prompt)
        action = Action(answer)
        if action not in prompt.choices:
            raise ValueError(f"scripted answer {action.value!r} to a {prompt.kind!r} prompt is not one of "
                             f"{', '.join(c.value for c in prompt.choices)}")
        label = prompt.step.label if prompt.step is not None else ""
        self.transcript.append(TranscriptEntry(f"confirm:{prompt.kind}", label, action.value))
        return action

    def step_finished(self, record: StepRecord) -> None:
        """Note the step's outcome in the transcript."""
        self.transcript.append(TranscriptEntry("finished", record.label, record.status))

    def end(self, result: RunResult) -> None:
        """Note the run's outcome in the transcript."""
        self.transcript.append(TranscriptEntry("end", result.outcome))


class Rig(Protocol):
    """What moves a simulated (or motorized) unit: a pose by label, a turn about a sensor axis."""

    # What they return (the simulator: the move's duration) is not used.
    def set_pose(self, pose: str, move_s: float = ...) -> object:
        """Turn the unit to the pose label ``pose`` over ``move_s``."""

    def rotate(self, axis: str, angle_deg: float, rate_dps: float, settle_s: float = ...) -> object:
        """Turn the unit about ``axis`` (+x, -z, ...) by ``angle_deg`` at ``rate_dps``, then settle."""


class SimulatedOperator(BaseOperator):
    """Moves the simulated unit as each step asks, then lets ``inner`` see and answer everything.

    ``inner`` is the TUI (so a person watches and presses Enter) or a :class:`ScriptedOperator`.
    ``move_s`` is how long the simulated hand takes between poses; ``settle_s`` how long it holds
    still before and after a turn (the runner has already captured its own settle when it asks).
    """

    def __init__(self, rig: Rig, inner: Operator | None = None, move_s: float = 0.5, settle_s: float = 0.2):
        self.rig = rig
        self.inner: Operator = inner if inner is not None else BaseOperator()
        self.move_s = move_s
        self.settle_s = settle_s

    def begin(self, sequence: Sequence) -> None:
        """Pass the start on to ``inner``."""
        self.inner.begin(sequence)

    def place(self, step: Step, index: int, total: int) -> None:
        """Tell ``inner``, then move the simulated unit to the step's pose."""
        self.inner.place(step, index, total)
        pose = step.label if isinstance(step, PoseStep) else step.start_pose
        self.rig.set_pose(pose, self.move_s)

    def rotate(self, step: RotationStep) -> None:
        """Tell ``inner``, then turn the simulated unit as the step asks."""
        self.inner.rotate(step)
        sign = "+" if step.angle_deg > 0 else "-"
        self.rig.rotate(sign + "xyz"[step.axis], abs(step.angle_deg), step.rate_dps, self.settle_s)

    def status(self, status: LiveStatus) -> None:
        """Pass the live status on to ``inner``."""
        self.inner.status(status)

    def poll(self) -> Action | None:
        """``inner``'s request, if any."""
        return self.inner.poll()

    def confirm(self, prompt: Prompt) -> Action:
        """``inner``'s answer to the prompt."""
        return self.inner.confirm(prompt)

    def step_finished(self, record: StepRecord) -> None:
        """Pass the step's record on to ``inner``."""
        self.inner.step_finished(record)

    def end(self, result: RunResult) -> None:
        """Pass the result on to ``inner``."""
        self.inner.end(result)
