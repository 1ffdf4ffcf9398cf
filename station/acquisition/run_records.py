"""What a sequence run reports: the runner's state, the live status, each step's record, the result.

The sequence runner (:mod:`station.acquisition.runner`) makes these and the operator
(:mod:`station.acquisition.operator`) receives them, while the runner also calls the operator:
with the types here, below both, the operator's module need not import the runner's. Import them
from ``station.acquisition.runner`` as before; the operator's module and the runner take them
from here.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from station.acquisition import checks
from station.acquisition.capture_data import Capture
from station.acquisition.sequences import Sequence, Step


class State(enum.Enum):
    """Where the runner is in the sequence (the TUI shows it)."""

    STARTING = "starting"
    PLACING = "placing"
    CAPTURING = "capturing"
    SETTLING = "settling"
    ROTATING = "rotating"
    REVIEW = "review"
    DONE = "done"


@dataclass
class LiveStatus:
    """What the operator sees, at most ~20 times a second."""

    index: int
    total: int
    step: Step
    state: State
    attempt: int
    message: str
    stillness: checks.Stillness | None = None
    pose: checks.PoseCheck | None = None
    progress: float = 0.0  # of the automatic capture (hold or settle), 0..1
    angle_deg: float | None = None  # integrated turn of a rotation step
    target_deg: float | None = None
    acc_mean: tuple[float, float, float] | None = None
    gyro_mean: tuple[float, float, float] | None = None
    temp: float | None = None
    rate_hz: float = 0.0
    lost: int = 0
    link_errors: int = 0


@dataclass
class StepRecord:
    """What happened to one step: ``status`` accepted, skipped, failed or aborted."""

    label: str
    kind: str
    status: str
    attempts: int
    samples: int = 0
    duration_s: float = 0.0
    problems: list[str] = field(default_factory=list)
    pose: checks.PoseCheck | None = None
    rotation: checks.RotationCheck | None = None
    saturation: checks.Saturation | None = None
    dropouts: checks.Dropouts | None = None

    @property
    def ok(self) -> bool:
        """True when the step was accepted with no problem noted."""
        return self.status == "accepted" and not self.problems


@dataclass
class RunResult:
    """The outcome of a run: ``completed``, ``aborted``, ``timeout`` or ``link-error`` (``error`` set)."""

    outcome: str
    capture: Capture
    steps: list[StepRecord]
    sequence: Sequence
    error: BaseException | None = None
    reason: str = ""

    @property
    def accepted(self) -> list[str]:
        """The labels of the accepted steps, in order."""
        return [s.label for s in self.steps if s.status == "accepted"]

    @property
    def skipped(self) -> list[str]:
        """The labels of the steps the operator (or a review) skipped, in order."""
        return [s.label for s in self.steps if s.status == "skipped"]

    def summary(self) -> str:
        """One line for the operator: the outcome, steps captured of the sequence, steps skipped
        (a completed run may still lack some) and samples recorded."""
        return (f"Run {self.outcome}: {len(self.accepted)} of {len(self.sequence)} steps captured, "
                f"{len(self.skipped)} skipped, {len(self.capture)} samples.")
