"""Feeding a stream decoder the way a serial port does: in ragged chunks."""

from __future__ import annotations

import numpy as np

from protocols.base import Message, StreamDecoderBase
from protocols.mag_batches import join_batches


def feed_ragged(decoder: StreamDecoderBase, data: bytes, seed: int,
                max_chunk: int) -> tuple[np.ndarray, list[Message]]:
    """Feed ``data`` in random chunks of 1..max_chunk bytes, then flush: all samples and messages."""
    rng = np.random.default_rng(seed)
    samples, messages, pos = [], [], 0
    while pos < len(data):
        n = int(rng.integers(1, max_chunk + 1))
        out = decoder.feed(data[pos : pos + n])
        samples.append(out.samples)
        messages += out.messages
        pos += n
    out = decoder.flush()
    samples.append(out.samples)
    messages += out.messages
    return join_batches(samples), messages  # a nine-axis stream's batches before its first field are six-axis


def feed_in_chunks(decoder: StreamDecoderBase, data: bytes,
                   chunk: int) -> tuple[list[np.ndarray], list[Message]]:
    """Feed ``data`` in chunks of ``chunk`` bytes, then flush: every batch (in order) and the messages."""
    batches, messages = [], []
    for pos in range(0, len(data), chunk):
        out = decoder.feed(data[pos : pos + chunk])
        batches.append(out.samples)
        messages += out.messages
    out = decoder.flush()
    batches.append(out.samples)
    messages += out.messages
    return batches, messages
