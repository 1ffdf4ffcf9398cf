"""Simulated units whose device clock misbehaves: encoders to register in ``mocks.device.ENCODERS``
(with ``monkeypatch.setitem``: the table is global, and the CLI's help lists what it holds)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from protocols import native

HOUR_US = 3_600_000_000


def wild_clock(every: int, at: int) -> Callable[[np.ndarray], bytes]:
    """An encoder of the unit's frames with the samples whose ``seq % every == at`` dated an hour
    ahead (their checksums are good)."""

    def encode(samples: np.ndarray) -> bytes:
        s = samples.copy()
        s["t_us"][s["seq"] % every == at] += HOUR_US
        return native.encode_samples(s)

    return encode


def restarting_clock(restart_seq: int, period_us: int = 5000) -> Callable[[np.ndarray], bytes]:
    """An encoder of the unit's frames as if it restarted at ``restart_seq``: its clock back to 1 ms,
    its counter back to 0."""

    def encode(samples: np.ndarray) -> bytes:
        s = samples.copy()
        after = s["seq"] >= restart_seq
        s["t_us"][after] -= restart_seq * period_us - 1000
        s["seq"][after] -= restart_seq
        return native.encode_samples(s)

    return encode
