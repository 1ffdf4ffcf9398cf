"""The wizard's steps placed and turned by a rate table (``tui --table URL``) instead of the operator.

:class:`TableTuiOperator` is the factory's table operator (``station.factory.run.TableOperator``) in
front of the screen's :class:`~station.tui.bridge.TuiOperator`: each step is told to the screen,
then the table (a :class:`~station.instruments.mounted_table.MountedTable`) moves the unit there,
and the screen is told what the table does. Prompts still go to the person at the screen (start,
a failed check); an abort from them, or a table that fails, stops the table at once. A table error
never escapes into the runner: it is kept in :attr:`TableTuiOperator.error` and the next
:meth:`~TableTuiOperator.poll` aborts the run, keeping what was captured.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from drivers.errors import DriverError
from station.acquisition.operator import Action, BaseOperator, Prompt
from station.acquisition.runner import LiveStatus, RunResult, StepRecord
from station.acquisition.sequences import PoseStep, RotationStep, Sequence, Step
from station.instruments.mounted_table import PoseTable
from station.tui.bridge import TuiOperator


def _axis_name(step: RotationStep) -> str:
    return "+" + "xyz"[step.axis]


class TableTuiOperator(BaseOperator):
    """The table moves the unit for each step; ``inner`` (the screen) sees and answers everything else.

    Parameters
    ----------
    table : PoseTable
        The mounted table (poses and turns in the unit's axes).
    inner : TuiOperator
        The wizard screen's operator.
    timeout_s : float
        How long one pose or turn may take before the table counts as failed.
    """

    def __init__(self, table: PoseTable, inner: TuiOperator, timeout_s: float = 60.0):
        self.table = table
        self.inner = inner
        self.timeout_s = timeout_s
        self.error: Exception | None = None
        self._told = False

    def _move(self, what: Callable[[], None], doing: str) -> None:
        if self.error is not None:
            return
        self.inner.tell("table", doing)
        try:
            what()
        except (DriverError, ValueError) as exc:  # ValueError: a step label the table cannot read
            self.error = exc

    def begin(self, sequence: Sequence) -> None:
        """Pass the start on to the screen."""
        self.inner.begin(sequence)

    def place(self, step: Step, index: int, total: int) -> None:
        """Tell the screen the step, then start the table toward its pose (a rotation's start pose)."""
        self.inner.place(step, index, total)
        pose = step.label if isinstance(step, PoseStep) else step.start_pose
        self._move(lambda: self.table.pose(pose, self.timeout_s),
                   f"the table is moving the unit to {pose} up")

    def rotate(self, step: RotationStep) -> None:
        """Tell the screen the turn, then start the table turning about the step's axis."""
        self.inner.rotate(step)
        axis = _axis_name(step)
        self._move(lambda: self.table.rotate(axis, step.angle_deg, step.rate_dps, self.timeout_s),
                   f"the table is turning the unit {step.angle_deg:+g} deg about {axis} "
                   f"at {step.rate_dps:g} deg/s")

    def status(self, status: LiveStatus) -> None:
        """Pass the live status on to the screen."""
        self.inner.status(status)

    def poll(self) -> Action | None:
        """Abort once the table has failed (a mounted table's turn fails in its own thread); else the
        screen's request, an abort stopping the table first."""
        if self.error is None:
            self.error = getattr(self.table, "error", None)
        if self.error is not None:
            if not self._told:
                self._told = True
                self.stop()
                self.inner.tell("table_failed", self.error)
            return Action.ABORT
        action = self.inner.poll()
        if action is Action.ABORT:
            self.stop()
        return action

    def confirm(self, prompt: Prompt) -> Action:
        """The screen's answer; an abort stops the table."""
        action = self.inner.confirm(prompt)
        if action is Action.ABORT:
            self.stop()
        return action

    def step_finished(self, record: StepRecord) -> None:
        """Pass the step's record on to the screen."""
        self.inner.step_finished(record)

    def end(self, result: RunResult) -> None:
        """Pass the result on to the screen."""
        self.inner.end(result)

    def stop(self) -> None:
        """Bring the table to rest at once (abort, Escape, the screen closing)."""
        try:
            self.table.stop()
        except DriverError as exc:
            if self.error is None:
                self.error = exc

    def stop_soon(self) -> None:
        """:meth:`stop` in a thread of its own: the screen's thread never waits on the table's link."""
        threading.Thread(target=self.stop, name="stop-table", daemon=True).start()
