"""Fault injection on the device's byte stream, frame by frame, seeded and reproducible.

Per frame, with the probabilities of :class:`FaultSpec` (one draw of each kind per frame, from
streams consumed in frame order, so the faults do not depend on how frames come in blocks):

- ``drop``: the frame is not sent;
- ``truncate``: only a random prefix of 1 .. len-3 bytes is sent (at least three bytes are
  missing, so the bytes that follow complete it by chance with probability 2^-24 at most);
- ``bitflip``: one random bit of the frame is flipped;
- ``garbage``: 1 .. ``garbage_max`` random bytes are sent before the frame;
- ``stall``: output pauses ``stall_s`` before the frame (the server holds it, then bursts);
- ``disconnect_after_bytes`` / ``disconnect_after_s``: the link ends after that many bytes of
  output, or seconds since serving began (a frame cut by it is not intact).

drop, truncate and bitflip exclude each other (in that order of precedence); garbage and
stalls combine with anything. The injector reports exactly which frames it left intact:
``intact_indices`` (frame numbers in the order frames were given, from 0) and, with
``record=True``, their bytes, so end-to-end tests can require every intact frame, in order,
bit-exact, and nothing else. (A damaged frame still passes a 16-bit CRC with probability
about 2^-16: a rare exception any receiver shares; the seeds make every run repeatable.)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields

import numpy as np

_INTEGER_FIELDS = ("garbage_max", "disconnect_after_bytes", "seed")
MAX_GARBAGE_BYTES = 65_536
MAX_STALL_S = 60.0


@dataclass
class FaultSpec:
    """What goes wrong on the link. Probabilities are per frame."""

    garbage: float = 0.0
    garbage_max: int = 16
    bitflip: float = 0.0
    truncate: float = 0.0
    drop: float = 0.0
    stall: float = 0.0
    stall_s: float = 0.2
    disconnect_after_bytes: int | None = None
    disconnect_after_s: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("garbage", "bitflip", "truncate", "drop", "stall"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault {name}={p}: a probability per frame must be in [0, 1]")
        if self.drop + self.truncate + self.bitflip > 1.0:
            raise ValueError("drop + truncate + bitflip must not exceed 1 (they exclude each other)")
        if not 1 <= self.garbage_max <= MAX_GARBAGE_BYTES:
            raise ValueError(f"garbage_max must be 1..{MAX_GARBAGE_BYTES} bytes")
        if not 0.0 <= self.stall_s <= MAX_STALL_S:
            raise ValueError(f"stall_s must be 0..{MAX_STALL_S:g} s")
        if self.disconnect_after_bytes is not None and self.disconnect_after_bytes < 0:
            raise ValueError("disconnect_after_bytes must be at least 0")
        if self.disconnect_after_s is not None and not 0.0 <= self.disconnect_after_s < float("inf"):
            raise ValueError("disconnect_after_s must be finite and at least 0 s")
        if not 0 <= self.seed <= 2**32 - 1:
            raise ValueError("seed must be 0..4294967295")

    @property
    def per_frame(self) -> bool:
        """True when any per-frame fault (garbage, bit flip, truncation, drop, stall) can happen."""
        return any((self.garbage, self.bitflip, self.truncate, self.drop, self.stall))

    @property
    def active(self) -> bool:
        """True when any fault is set, per-frame or a disconnection."""
        ends = (self.disconnect_after_bytes, self.disconnect_after_s)
        return self.per_frame or any(e is not None for e in ends)

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """``"garbage=0.01,bitflip=0.001,stall=0.01,stall_s=0.5,disconnect_after_s=3,seed=2"``.

        Short names ``disconnect_bytes`` and ``disconnect_s`` are accepted too; "" is no fault.

        Parameters
        ----------
        text : str

        Returns
        -------
        FaultSpec

        Raises
        ------
        ValueError
            An unknown name or a value that is not a number.
        """
        aliases = {"disconnect_bytes": "disconnect_after_bytes", "disconnect_s": "disconnect_after_s"}
        kinds = {f.name: f for f in fields(cls)}
        values: dict[str, object] = {}
        for item in filter(None, (part.strip() for part in text.split(","))):
            key, sep, raw = item.partition("=")
            key = aliases.get(key.strip(), key.strip())
            if not sep or key not in kinds:
                known = ", ".join([*kinds, *aliases])
                raise ValueError(f"fault {item!r}: expected NAME=VALUE with NAME one of {known}")
            try:
                values[key] = int(raw) if key in _INTEGER_FIELDS else float(raw)
            except ValueError:
                raise ValueError(f"fault {key}={raw!r}: the value is not a number") from None
        return cls(**values)  # type: ignore[arg-type]

    def describe(self) -> str:
        """The spec as :meth:`parse` reads it, the fields that differ from the defaults only ("none")."""
        defaults = FaultSpec()
        parts = [f"{k}={v}" for k, v in asdict(self).items() if v != getattr(defaults, k)]
        return ",".join(parts) if parts else "none"


@dataclass
class FaultCounts:
    """What the injector did so far: frames seen, intact, dropped, truncated, bit-flipped; garbage, stalls."""

    frames: int = 0
    intact: int = 0
    dropped: int = 0
    truncated: int = 0
    bitflips: int = 0
    garbage_runs: int = 0
    garbage_bytes: int = 0
    stalls: int = 0
    bytes_out: int = 0


@dataclass
class FaultOutput:
    """The bytes to send for one call, the stall before them, and whether the link ends after."""

    data: bytes
    stall_s: float = 0.0
    disconnect: bool = False
    intact: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


class FaultInjector:
    """Applies a :class:`FaultSpec` to frames as they leave the device."""

    def __init__(self, spec: FaultSpec, record: bool = False):
        self.spec = spec
        self.record = record
        self.counts = FaultCounts()
        self.disconnected = False
        decide, garbage = np.random.SeedSequence([int(spec.seed), 0xFA17]).spawn(2)
        self._rng_decide = np.random.default_rng(decide)
        self._rng_garbage = np.random.default_rng(garbage)
        self._intact: list[np.ndarray] = []
        self._intact_frames: list[bytes] = []

    def intact_indices(self) -> np.ndarray:
        """Numbers of the frames sent whole and unchanged, in order (0 = first frame given)."""
        return np.concatenate(self._intact) if self._intact else np.zeros(0, dtype=np.int64)

    def intact_frames(self) -> list[bytes]:
        """The frames that went out intact, in order (for a test's reference).

        Raises
        ------
        ValueError
            The injector was made with ``record=False``.
        """
        if not self.record:
            raise ValueError("the injector was made with record=False; it kept no frame bytes")
        return list(self._intact_frames)

    def apply(self, frames: Sequence[bytes], protected: Sequence[bool] | None = None) -> FaultOutput:
        """Faults for the next ``frames``; ``protected`` frames (e.g. command answers) get no
        per-frame fault but still count, and can still be cut by a disconnect.

        Parameters
        ----------
        frames : sequence of bytes
        protected : sequence of bool, optional

        Returns
        -------
        FaultOutput
        """
        n = len(frames)
        first = self.counts.frames
        self.counts.frames += n
        if self.disconnected or n == 0:
            return FaultOutput(b"", 0.0, self.disconnected, np.zeros(n, bool))
        spec = self.spec
        # Five uniforms per frame, drawn whatever the spec, so faults do not depend on blocking.
        u = self._rng_decide.random((n, 5))
        kind = np.zeros(n, dtype=np.int8)  # 0 none, 1 drop, 2 truncate, 3 bitflip
        kind[u[:, 0] < spec.drop + spec.truncate + spec.bitflip] = 3
        kind[u[:, 0] < spec.drop + spec.truncate] = 2
        kind[u[:, 0] < spec.drop] = 1
        garbage = u[:, 1] < spec.garbage
        stall = u[:, 4] < spec.stall
        if protected is not None:
            keep = np.asarray(protected, bool)
            kind[keep] = 0
            garbage[keep] = False
            stall[keep] = False
        intact = kind == 0
        stall_s = float(np.count_nonzero(stall)) * spec.stall_s
        self.counts.stalls += int(np.count_nonzero(stall))
        ends = np.zeros(n, dtype=np.int64)  # where each frame's bytes end in the output
        if not spec.per_frame:
            chunks = list(frames)
            ends[:] = np.cumsum([len(f) for f in frames])
        else:
            chunks = []
            pos = 0
            lengths = 1 + (u[:, 2] * spec.garbage_max).astype(int)
            for i, frame in enumerate(frames):
                if garbage[i]:
                    junk = self._rng_garbage.integers(0, 256, lengths[i], dtype=np.uint8).tobytes()
                    chunks.append(junk)
                    pos += len(junk)
                    self.counts.garbage_runs += 1
                    self.counts.garbage_bytes += len(junk)
                k = kind[i]
                if k == 0:
                    out = frame
                elif k == 1:
                    out = b""
                    self.counts.dropped += 1
                elif k == 2:
                    out = frame[: 1 + int(u[i, 3] * max(len(frame) - 3, 1))]
                    self.counts.truncated += 1
                else:
                    bit = int(u[i, 3] * len(frame) * 8)
                    flipped = bytearray(frame)
                    flipped[bit // 8] ^= 1 << (bit % 8)
                    out = bytes(flipped)
                    self.counts.bitflips += 1
                chunks.append(out)
                pos += len(out)
                ends[i] = pos
        data = b"".join(chunks)
        limit = self.spec.disconnect_after_bytes
        if limit is not None and self.counts.bytes_out + len(data) >= limit:
            room = limit - self.counts.bytes_out
            data = data[:room]
            intact &= ends <= room
            self.disconnected = True
        self.counts.bytes_out += len(data)
        self.counts.intact += int(np.count_nonzero(intact))
        self._intact.append(first + np.flatnonzero(intact))
        if self.record:
            self._intact_frames.extend(f for f, ok in zip(frames, intact, strict=True) if ok)
        return FaultOutput(data, stall_s, self.disconnected, intact)

    def end_link(self) -> None:
        """The link ended for another reason (``disconnect_after_s``): nothing more goes out."""
        self.disconnected = True
