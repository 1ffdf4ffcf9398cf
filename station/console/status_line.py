"""The live status line a capture shows on the terminal (rich), for ``capture`` and the demo."""

from __future__ import annotations

from collections.abc import Callable
from typing import IO

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from drivers import LinkStats


def status_text(stats: LinkStats, rows: int) -> str:
    """Rate, samples, damaged frames and lost samples, as the status line shows them.

    Parameters
    ----------
    stats : LinkStats
        The link statistics so far.
    rows : int
        Samples written.

    Returns
    -------
    str
    """
    return (f"{stats.rate_hz:7.1f} Hz  {rows} samples  {stats.errors} errors  {stats.lost} lost"
            + (f"  {stats.overflow_drops} dropped" if stats.overflow_drops else ""))


class CaptureStatusLine:
    """A live line on ``err``: progress (with a duration), rate, samples, errors, lost.

    Entering it starts the display and gives :meth:`update`, the capture's ``on_status``.

    Parameters
    ----------
    err : text stream
        Where the line is drawn.
    duration_s : float, optional
        The capture's length in device seconds, for the progress bar.
    """

    def __init__(self, err: IO[str], duration_s: float | None):
        self._progress = Progress(
            TextColumn("capturing"), BarColumn(), TextColumn("{task.fields[status]}"), TimeElapsedColumn(),
            console=Console(file=err), transient=False,
        )
        self._task = self._progress.add_task("capture", total=duration_s, status="waiting for samples")

    def __enter__(self) -> Callable[[LinkStats, int, float], None]:
        self._progress.start()
        return self.update

    def __exit__(self, *exc: object) -> None:
        self._progress.stop()

    def update(self, stats: LinkStats, rows: int, device_time_s: float) -> None:
        """Show the capture's state: ``device_time_s`` recorded, ``rows`` written.

        Parameters
        ----------
        stats : LinkStats
            The link statistics so far.
        rows : int
            Samples written.
        device_time_s : float
            Device seconds recorded.
        """
        self._progress.update(self._task, completed=device_time_s, status=status_text(stats, rows))
