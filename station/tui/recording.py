"""A growing in-memory recording for the long-recording screens, filled from the reader thread."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from protocols.base import SAMPLE_DTYPE
from station.acquisition.recorder import Recorder
from station.tui.session import Session


class Recording:
    """Appends ``SAMPLE_DTYPE`` batches (thread-safe); :meth:`snapshot` joins them for analysis.

    With a ``path``, every batch is also streamed to that capture file by the capture recorder,
    so hours of data survive a crash of the analysis.
    """

    def __init__(self, path: Path | None = None, device: dict | None = None, port: str = "",
                 protocol: str = "") -> None:
        self._lock = threading.Lock()
        self._batches: list[np.ndarray] = []
        self._joined = np.zeros(0, SAMPLE_DTYPE)
        self.count = 0
        self.path = path
        self.recorder = Recorder(path, device=device, port=port, protocol=protocol) if path else None

    def add(self, batch: np.ndarray) -> None:
        """Keep a batch of samples (and write it to the recorder, if any)."""
        with self._lock:
            self._batches.append(batch)
            self.count += len(batch)
            if self.recorder is not None:
                self.recorder.write(batch)

    def close(self) -> None:
        """Close the capture file (safe to call twice; later batches are kept in memory only)."""
        with self._lock:
            if self.recorder is not None:
                self.recorder.close()
                self.recorder = None

    def snapshot(self) -> np.ndarray:
        """Every sample so far; joins the new batches onto the previous join (amortised)."""
        with self._lock:
            batches, self._batches = self._batches, []
        if batches:
            self._joined = np.concatenate([self._joined, *batches])
        return self._joined

    @staticmethod
    def rate_hz(samples: np.ndarray) -> float:
        """The sample rate from the median device-clock step."""
        if len(samples) < 2:
            return float("nan")
        return 1e6 / float(np.median(np.diff(samples["t_us"].astype(np.int64))))


def open_recording(session: Session, out: Path | None, kind: str) -> Recording:
    """The recording of a long-recording screen, streamed beside ``--out`` as ``<stem>-<kind>.h5``."""
    path = out.with_name(f"{out.stem}-{kind}.h5") if out is not None else None
    return Recording(path, device=session.info, port=session.name, protocol=session.device.protocol)
