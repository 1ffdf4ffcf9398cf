"""Where the sequence runner's samples go once their step label is final.

- :class:`MemorySink`: keeps them and builds the run's :class:`~station.acquisition.capture.Capture`
  (every runner has one; the result's capture is built from it);
- :class:`RecorderSink`: streams them to a capture file through the capture recorder;
- :func:`samples_to_capture`: ``SAMPLE_DTYPE`` records as a ``Capture``, which the memory sink
  and the rate-table capture use.

They need nothing of the runner's state machine, and the rate-table capture needs
``samples_to_capture`` without the rest of the runner, so they live apart from it; they are still
importable from ``station.acquisition.runner``, as before.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from drivers.interface import Device
from protocols.base import has_mag
from protocols.mag_batches import join_batches
from station.acquisition.capture_data import Capture
from station.acquisition.recorder import Recorder


class SampleSink(Protocol):
    """Where samples go once their label is final (in memory, or streamed to a capture file)."""

    def write(self, samples: np.ndarray, label: str, link: dict[str, Any] | None = None) -> None:
        """Take a batch of samples recorded during ``label`` ("" between steps), with the link
        statistics at that time."""


class MemorySink:
    """Keeps the labelled samples and builds a :class:`Capture` of them."""

    def __init__(self) -> None:
        self._chunks: list[tuple[np.ndarray, str]] = []

    def write(self, samples: np.ndarray, label: str, link: dict[str, Any] | None = None) -> None:
        """Keep the batch and its label in memory (``link`` is not kept: :meth:`capture` takes it)."""
        if len(samples):
            self._chunks.append((samples, label))

    def __len__(self) -> int:
        return sum(len(c) for c, _ in self._chunks)

    def capture(self, device: dict[str, Any] | None = None, link: dict[str, Any] | None = None,
                source: str = "") -> Capture:
        """Everything written so far as one labelled :class:`Capture`.

        Parameters
        ----------
        device, link : dict, optional
            The unit's info and the link statistics, kept in the capture.
        source : str
            Where the samples came from.

        Returns
        -------
        Capture
        """
        samples = join_batches([c for c, _ in self._chunks])
        labels = np.empty(len(samples), dtype=object)
        i = 0
        for chunk, label in self._chunks:
            labels[i:i + len(chunk)] = label
            i += len(chunk)
        return samples_to_capture(samples, labels, device, link, source)


class RecorderSink:
    """Streams the labelled samples to a capture file through the capture recorder."""

    def __init__(self, recorder: Recorder, device: Device | None = None):
        self.recorder = recorder
        self.device = device

    def write(self, samples: np.ndarray, label: str, link: dict[str, Any] | None = None) -> None:
        """Write the batch, labelled, to the recorder's capture file, with ``link`` (by default the
        device's statistics) for the file's next flush."""
        self.recorder.step = label
        if link is None and self.device is not None:
            link = self.device.stats.as_dict()
        self.recorder.write(samples, link)


def samples_to_capture(samples: np.ndarray, labels: np.ndarray | None = None, device: dict | None = None,
                       link: dict | None = None, source: str = "") -> Capture:
    """A :class:`Capture` (SI, t in seconds of device clock) from ``SAMPLE_DTYPE`` records.

    Parameters
    ----------
    samples : ndarray of SAMPLE_DTYPE or MAG_SAMPLE_DTYPE
        With ``MAG_SAMPLE_DTYPE`` the capture's ``mag`` holds the field (uT).
    labels : ndarray of str, optional
        Step label of each sample.
    device, link : dict, optional
    source : str

    Returns
    -------
    Capture
    """
    temp = samples["temp"].astype(float)
    return Capture(
        t=samples["t_us"].astype(np.float64) * 1e-6,
        acc=samples["acc"].astype(np.float64),
        gyro=samples["gyro"].astype(np.float64),
        temp=temp if len(temp) and np.isfinite(temp).any() else None,
        step=labels,
        device=dict(device or {}),
        link=dict(link or {}),
        source=source,
        mag=samples["mag"].astype(np.float64) if has_mag(samples) else None,
    )
