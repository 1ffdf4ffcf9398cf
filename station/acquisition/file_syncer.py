"""Make files durable once a period from a thread of its own, so that a loop never waits for the disk.

``fsync`` waits for the disk: tens of milliseconds each on a busy one. A loop that serves 32
ports and syncs each unit's file once a second would leave the ports unread a third of the
time. :class:`FileSyncer` does the syncing in a thread instead; since ``fsync`` flushes a file
through any descriptor of it, the thread opens each file by its path and needs nothing of the
writer's.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

SYNC_INTERVAL_S = 1.0


class FileSyncer:
    """Sync every file in :meth:`add` every ``interval_s`` until :meth:`close` (which syncs once more).

    Parameters
    ----------
    interval_s : float
        Seconds between syncs of each file.
    """

    def __init__(self, interval_s: float = SYNC_INTERVAL_S):
        self._interval_s = interval_s
        self._paths: list[Path] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="file-syncer", daemon=True)
        self._thread.start()

    def add(self, path: Path) -> None:
        """Sync ``path`` from now on."""
        with self._lock:
            self._paths.append(path)

    def _run(self) -> None:
        while not self._stop.wait(self._interval_s):
            self.sync()

    def sync(self) -> None:
        """Sync every file now (one removed meanwhile is passed over: its capture said why)."""
        with self._lock:
            paths = list(self._paths)
        for path in paths:
            try:
                fd = os.open(path, os.O_RDONLY)
            except OSError:
                continue
            try:
                os.fsync(fd)
            except OSError:
                pass  # a disk that fails the sync fails the writer's next write, which says so
            finally:
                os.close(fd)

    def close(self) -> None:
        """Stop the thread, then sync every file a last time."""
        self._stop.set()
        self._thread.join()
        self.sync()
