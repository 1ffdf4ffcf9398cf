"""The live status lines of a capture of many units: one line per unit, as ``capture`` shows one."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import IO

from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Column

from station.acquisition.multi_capture import UnitStatus
from station.console.markup import markup_safe
from station.console.status_line import status_text

# Fewer redraws than the single line's: 32 lines redrawn 10 times a second cost more than the units.
REFRESH_PER_SECOND = 2
# A failed unit's line shows the start of its error (the summary has all of it): the bars keep their room.
STATUS_WIDTH = 60


def unit_text(unit: UnitStatus) -> str:
    """What a unit's line says after its name: the capture's figures, or how it ended.

    Parameters
    ----------
    unit : UnitStatus
        The unit as the capture last saw it.

    Returns
    -------
    str
    """
    if unit.state == "preparing":
        return "asking the unit who it is"
    if unit.state.startswith("failed"):
        return unit.state
    return status_text(unit.stats, unit.rows) + ("  done" if unit.state == "done" else "")


class UnitStatusLines:
    """Live lines on ``err``, one per unit: name, progress (with a duration), rate, samples, errors, lost.

    Entering it starts the display and gives :meth:`update`, the capture's ``on_status``.

    Parameters
    ----------
    err : text stream
        Where the lines are drawn.
    ports : sequence of str
        The units' ports, one line each, in this order.
    duration_s : float, optional
        Each unit's capture length in device seconds, for the progress bars.
    """

    def __init__(self, err: IO[str], ports: Sequence[str], duration_s: float | None):
        # The unit's name keeps its width; the figures after it are cut first on a narrow terminal.
        self._width = max([len(p) for p in ports] + [12])
        self._progress = Progress(
            TextColumn("{task.fields[unit]}", table_column=Column(no_wrap=True, min_width=self._width)),
            BarColumn(bar_width=16),
            TextColumn("{task.fields[status]}",
                       table_column=Column(no_wrap=True, overflow="ellipsis", max_width=STATUS_WIDTH)),
            TimeElapsedColumn(), console=Console(file=err), transient=False,
            refresh_per_second=REFRESH_PER_SECOND,
        )
        self._tasks: dict[str, TaskID] = {
            port: self._progress.add_task(port, total=duration_s, unit=markup_safe(port).ljust(self._width),
                                          status="opening")
            for port in ports
        }
        self._stopped: set[TaskID] = set()

    def __enter__(self) -> Callable[[Sequence[UnitStatus]], None]:
        self._progress.start()
        return self.update

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    def update(self, units: Sequence[UnitStatus]) -> None:
        """Show each unit's state.

        Parameters
        ----------
        units : sequence of UnitStatus
            Every unit, as the capture sees it now.
        """
        for unit in units:
            task = self._tasks[unit.port]
            # the name may be the port, the status a unit's error: both go into the columns' markup
            self._progress.update(task, completed=unit.device_time_s,
                                  unit=markup_safe(unit.name).ljust(self._width),
                                  status=markup_safe(unit_text(unit), 2 * STATUS_WIDTH))
            if unit.state not in ("recording", "preparing") and task not in self._stopped:
                self._progress.stop_task(task)  # its clock stops where the unit ended
                self._stopped.add(task)
