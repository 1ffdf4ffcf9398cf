"""Sample batches with and without a magnetometer, joined.

A decoder returns ``MAG_SAMPLE_DTYPE`` batches for a unit that reports a magnetometer and
``SAMPLE_DTYPE`` otherwise. Numpy cannot concatenate the two structured types, so code that
joins batches of one stream (a decoder's frames, a capture's chunks) goes through
:func:`join_batches`, which widens the six-axis ones with NaN fields.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from protocols.base import EMPTY_SAMPLES, MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, has_mag


def with_mag(samples: np.ndarray) -> np.ndarray:
    """``samples`` as ``MAG_SAMPLE_DTYPE``: unchanged when they carry a field, else a copy with NaN mag."""
    if has_mag(samples):
        return samples
    out = np.empty(len(samples), dtype=MAG_SAMPLE_DTYPE)
    for name in SAMPLE_DTYPE.names or ():
        out[name] = samples[name]
    out["mag"] = np.nan
    return out


def join_batches(batches: Sequence[np.ndarray]) -> np.ndarray:
    """One batch from several in order: ``MAG_SAMPLE_DTYPE`` when any carries a field, else ``SAMPLE_DTYPE``.

    Empty batches are left out, so an empty six-axis batch never widens a nine-axis stream.
    """
    batches = [b for b in batches if len(b)]
    if not batches:
        return EMPTY_SAMPLES
    if len(batches) == 1:
        return batches[0]
    if any(has_mag(b) for b in batches):
        return np.concatenate([with_mag(b) for b in batches])
    return np.concatenate(batches)
