"""What every protocol decoder shares: the sample record, the decode result and the error counters.

Every decoder in this package (native, and those of other vendors' protocols) has the same
incremental interface: ``feed(data) -> Decoded`` takes any chunk of bytes, however the stream
was split, and returns the samples and other messages completed by it; ``flush()`` ends the
stream (bytes left in the buffer are counted as truncated). Decoders never raise on bad input:
every kind of error becomes a counter in ``stats``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

# One IMU sample, in SI units. The layout equals the native IMU_SAMPLE payload (40 bytes,
# little-endian, packed), so native sample payloads are viewed with this dtype without copying.
SAMPLE_DTYPE = np.dtype(
    [
        ("seq", "<u4"),
        ("t_us", "<u8"),
        ("acc", "<f4", (3,)),
        ("gyro", "<f4", (3,)),
        ("temp", "<f4"),
    ]
)

EMPTY_SAMPLES = np.zeros(0, dtype=SAMPLE_DTYPE)

# One sample of a nine-axis unit: SAMPLE_DTYPE, then the magnetic field in microtesla. The layout
# equals the native IMU_MAG_SAMPLE payload (52 bytes), viewed without copying like SAMPLE_DTYPE.
# A decoder returns batches of this dtype for a unit that reports a magnetometer; NaN where a
# frame carries no field.
MAG_SAMPLE_DTYPE = np.dtype(
    [
        ("seq", "<u4"),
        ("t_us", "<u8"),
        ("acc", "<f4", (3,)),
        ("gyro", "<f4", (3,)),
        ("temp", "<f4"),
        ("mag", "<f4", (3,)),
    ]
)


def has_mag(samples: np.ndarray) -> bool:
    """Whether a sample batch carries magnetometer values (``MAG_SAMPLE_DTYPE``)."""
    return samples.dtype.names is not None and "mag" in samples.dtype.names


@dataclass(frozen=True)
class Message:
    """A decoded frame that is not a sample (device info, acknowledgement, unknown id)."""

    msg_id: int
    payload: bytes


@dataclass
class Decoded:
    """What one ``feed`` call completed: samples as one numpy batch, other messages in order."""

    samples: np.ndarray = field(default_factory=lambda: EMPTY_SAMPLES)
    messages: list[Message] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.samples) + len(self.messages)


@dataclass
class DecoderStats:
    """Counters of a decoder since it was made. Each bad input lands in exactly one error kind."""

    frames: int = 0  # good frames of any kind
    samples: int = 0  # good sample frames
    garbage_bytes: int = 0  # bytes skipped while looking for a frame start
    resyncs: int = 0  # times the decoder had to skip bytes to find the next frame
    crc_errors: int = 0  # frames whose checksum did not match
    length_errors: int = 0  # frames announcing an impossible length
    truncated: int = 0  # frames cut short by the start of another frame or the end of stream
    bad_payloads: int = 0  # good checksum but a payload the message id does not allow
    unknown_ids: int = 0  # good frames with an id this decoder does not know (still returned)
    seq_skipped: int = 0  # sequence numbers taken by good packets that carry no sample (not losses)

    @property
    def errors(self) -> int:
        """Frames that arrived damaged: CRC, length, truncation and bad payloads."""
        return self.crc_errors + self.length_errors + self.truncated + self.bad_payloads

    def as_dict(self) -> dict[str, int]:
        """Every counter by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class StreamDecoderBase:
    """Base of the incremental decoders: keeps the buffer and the counters."""

    name = "base"
    #: How the protocol is named in capture files and status lines when the option naming it is not
    #: what identifies it (a frame description: its ``name``, not its file); None: the option itself.
    label: str | None = None

    def __init__(self) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()

    def feed(self, data: bytes) -> Decoded:  # pragma: no cover - interface
        """Decode ``data`` after what is buffered: every complete frame's samples and messages.

        Parameters
        ----------
        data : the next bytes read from the link, cut anywhere.

        Returns
        -------
        Decoded
            The samples and the other messages of the frames completed by ``data``; a partial frame
            stays buffered for the next call.
        """
        raise NotImplementedError

    def _seek_sync(self, sync: bytes, pos: int) -> tuple[int, bool]:
        """Move ``pos`` to the next ``sync`` in the buffer, counting the bytes skipped as garbage.

        Returns the new position and whether a sync was found. When none is, a trailing first
        sync byte is kept for the next chunk (unless it ended a frame already consumed), and the
        position is where the next chunk's search resumes.
        """
        buf = self._buf
        start = buf.find(sync, pos)
        found = start >= 0
        if not found:
            keep = 1 if len(buf) > pos and buf.endswith(sync[:1]) else 0
            start = max(pos, len(buf) - keep)
        if start > pos:
            self.stats.garbage_bytes += start - pos
            self.stats.resyncs += 1
        return start, found

    def _skip_candidate(self, sync: bytes, pos: int) -> int:
        """Drop the sync candidate at ``pos``: resume at the next ``sync`` (the bytes between counted as
        garbage), or keep a trailing first sync byte (not the candidate's own): the second may come next."""
        self.stats.resyncs += 1
        buf = self._buf
        nxt = buf.find(sync, pos + 1)
        if nxt < 0:
            nxt = len(buf) - (1 if len(buf) - 1 > pos and buf.endswith(sync[:1]) else 0)
        self.stats.garbage_bytes += nxt - pos
        return nxt

    def flush(self) -> Decoded:
        """End of stream: whatever is left in the buffer is an incomplete frame."""
        if self._buf:
            self.stats.truncated += 1
            self.stats.garbage_bytes += len(self._buf)
            self._buf.clear()
        return Decoded()
