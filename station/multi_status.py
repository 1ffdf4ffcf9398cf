"""The live status lines of a capture of many units: one line per unit, as ``capture`` shows one."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import IO

from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

from station.acquisition.multi_capture import UnitStatus
from station.status_line import status_text

# Fewer redraws than the single line's: 32 lines redrawn 10 times a second cost more than the units.
REFRESH_PER_SECOND = 2


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
        self._progress = Progress(
            TextColumn("{task.fields[unit]}"), BarColumn(bar_width=20), TextColumn("{task.fields[status]}"),
            TimeElapsedColumn(), console=Console(file=err), transient=False,
            refresh_per_second=REFRESH_PER_SECOND,
        )
        width = max((len(p) for p in ports), default=0)
        self._width = max(width, 12)
        self._tasks: dict[str, TaskID] = {
            port: self._progress.add_task(port, total=duration_s, unit=port.ljust(self._width),
                                          status="opening")
            for port in ports
        }

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
            self._progress.update(self._tasks[unit.port], completed=unit.device_time_s,
                                  unit=unit.name.ljust(self._width), status=unit_text(unit))
