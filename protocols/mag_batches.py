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


def rows_to_batch(rows: list[tuple], with_field: bool) -> np.ndarray:
    """Sample rows ``(seq, t_us, acc, gyro, temp, mag)`` of a decoder as one batch.

    ``with_field``: the stream has carried a field, so the batch is ``MAG_SAMPLE_DTYPE``;
    otherwise ``SAMPLE_DTYPE`` and the sixth element (NaN) is dropped. Rows of five elements
    (a decoder that reads no field) make ``SAMPLE_DTYPE`` batches.
    """
    if with_field:
        return np.array(rows, dtype=MAG_SAMPLE_DTYPE) if rows else np.zeros(0, MAG_SAMPLE_DTYPE)
    if not rows:
        return EMPTY_SAMPLES
    return np.array([r[:5] for r in rows] if len(rows[0]) > 5 else rows, dtype=SAMPLE_DTYPE)
