"""Reading a live device in tests: collect its sample batches up to a count or a deadline."""

from __future__ import annotations

import time

import numpy as np

from protocols.base import SAMPLE_DTYPE


def read_samples(dev, n: int, timeout: float) -> np.ndarray:
    """Samples read from ``dev`` until at least ``n`` came or ``timeout`` seconds passed."""
    got, count = [], 0
    deadline = time.monotonic() + timeout
    while count < n and time.monotonic() < deadline:
        batch = dev.read(0.1)
        got.append(batch)
        count += len(batch)
    return np.concatenate(got) if got else np.zeros(0, SAMPLE_DTYPE)
