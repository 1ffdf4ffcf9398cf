"""Which protocol a unit speaks, from the first bytes it sends, with what was found in words.

Every known decoder reads the same bytes; the one that finds checksummed frames (or, for text,
sample lines) without errors wins. Binary protocols are recognised by their frames even when
those carry no inertial data (the explanation then says what the unit should be told to send);
text lines must hold samples. The result names the protocol, says why, and hands over the
decoder that read the bytes, so no sample of them is lost.

``Detector`` does it on a stream read piece by piece (each candidate reads every piece once);
on a heavily damaged link it still decides once enough bytes leave one protocol clearly ahead,
and when it cannot it says how many bytes it saw, what each protocol found in them, and what
to try. ``AutoDecoder`` (registered as ``auto``) does this inside the stream: once a protocol
is recognised, that protocol's decoder, which read every byte since the first, goes on.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from protocols.ascii_lines import AsciiDecoder
from protocols.base import Decoded, DecoderStats, Message, StreamDecoderBase
from protocols.mag_batches import join_batches
from protocols.mavlink import MavlinkDecoder, pymavlink_available
from protocols.native import DEVICE_INFO, NativeDecoder
from protocols.xsens import MESSAGE_NAMES, XsensDecoder

MIN_FRAMES = 3  # checksummed frames that make a binary protocol certain
MIN_LINES = 3  # sample lines that make a text protocol certain
ENOUGH_BYTES = 4096  # after this many bytes without a protocol, say what the bytes look like
MIN_DAMAGED_FRAMES = 8  # good frames that decide on a damaged link, past ENOUGH_BYTES
LOOK_BYTES = 1024  # the first bytes kept to describe what an unknown stream looks like


@dataclass
class Detection:
    """What :func:`detect` found.

    ``protocol`` is a name of ``protocols.registry.DECODERS`` or None; ``explanation`` says what
    was found (or not) for the user; ``decoder`` is the decoder that already read the bytes and
    ``decoded`` what it returned, so the caller can go on from there without losing a sample.
    """

    protocol: str | None
    explanation: str
    samples: int = 0
    rate_hz: float = float("nan")
    decoder: StreamDecoderBase | None = None
    decoded: Decoded = field(default_factory=Decoded)
    need_more: bool = False  # nothing yet, but too few bytes to say so


def _candidates() -> list[tuple[str, StreamDecoderBase]]:
    found: list[tuple[str, StreamDecoderBase]] = [("native", NativeDecoder()), ("xsens", XsensDecoder())]
    if pymavlink_available():
        found.append(("mavlink", MavlinkDecoder()))
    found.append(("ascii", AsciiDecoder()))
    return found


def _rate(samples: np.ndarray) -> float:
    """Sample rate from the time steps between samples ``seq`` says are neighbours: the smallest
    seq step that is common (a quarter as frequent as the most frequent, at least), as steps
    across lost samples would make a damaged link look slower, and Xsens packets of the other
    rate take seq values between samples."""
    if len(samples) < 2:
        return float("nan")
    dt = np.diff(samples["t_us"].astype(np.int64))
    seq = samples["seq"].astype(np.uint32)
    dseq = (seq[1:] - seq[:-1]).astype(np.int64)  # u32 arithmetic: the step modulo 2^32
    ok = (dt > 0) & (dseq > 0)
    if not ok.any():
        return float("nan")
    steps, counts = np.unique(dseq[ok], return_counts=True)
    usual = dt[ok & (dseq == steps[counts * 4 >= counts.max()].min())]
    return 1e6 / float(np.median(usual))


def _damage(stats: DecoderStats) -> str:
    return "no damaged frames" if stats.errors == 0 else f"{stats.errors} damaged frames"


def _describe(name: str, dec: StreamDecoderBase, out: Decoded, nbytes: int) -> str:
    n = len(out.samples)
    rate = _rate(out.samples)
    at = f" at about {rate:.0f} Hz" if np.isfinite(rate) else ""
    stats = dec.stats
    if name == "native":
        infos = sum(m.msg_id == DEVICE_INFO for m in out.messages)
        extra = f" and {infos} DEVICE_INFO" if infos else ""
        return (f"native protocol: {n} IMU_SAMPLE frames{extra}{at} in {nbytes} bytes, {_damage(stats)}")
    if name == "xsens":
        assert isinstance(dec, XsensDecoder)
        items = ", ".join(sorted(dec.items_seen))
        packets = dec.message_ids_seen.get(0x36, 0)
        others = ", ".join(f"{MESSAGE_NAMES.get(k, hex(k))} x{v}"
                           for k, v in sorted(dec.message_ids_seen.items()) if k != 0x36)
        text = f"Xsens Xbus: {packets} MTData2 packets ({items or 'no items'})"
        if others:
            text += f" and {others}"
        text += f", {n} inertial samples{at}, {_damage(stats)}"
        if dec.other_source_packets:
            other = "normal-rate" if dec.source == "hr" else "high-rate (AccelerationHR/RateOfTurnHR)"
            text += f"; {dec.other_source_packets} {other} packets not used (xsens:normal or xsens:hr " \
                    f"chooses)"
        if n == 0:
            text += ("; none carries Acceleration, RateOfTurn, DeltaV or DeltaQ: add them to the output "
                     "configuration (MT Manager, or SetOutputConfiguration)")
        return text
    if name == "mavlink":
        assert isinstance(dec, MavlinkDecoder)
        seen = ", ".join(f"{k} x{v}" for k, v in sorted(dec.messages_seen.items()))
        text = f"MAVLink: {stats.frames} messages ({seen})"
        if n:
            text += f"; samples from {next(iter(dec.sources_seen))}{at}"
        else:
            text += ("; no IMU message: ask the autopilot to stream RAW_IMU, SCALED_IMU or HIGHRES_IMU "
                     "(MAV_CMD_SET_MESSAGE_INTERVAL, or ArduPilot's SRx_RAW_SENS)")
        text += f", {_damage(stats)}; MAVLink IMU telemetry is processed and low-rate: fine for " \
                f"positions and rotations, not for Allan variance"
        return text
    assert isinstance(dec, AsciiDecoder)
    kinds = ", ".join(f"{v} {k}" for k, v in sorted(dec.kinds_seen.items()))
    text = f"text lines: {kinds}; {n} samples"
    if "csv" in dec.kinds_seen:
        text += f" read as columns {dec.columns.describe()}"
    if dec.clock_lines:
        return text + f"{at}, {_damage(stats)}"
    return text + (f", {_damage(stats)}; the lines carry no clock: samples are timed at the nominal "
                   f"{dec.rate_hz:g} Hz (give the unit's rate if it differs)")


def _looks_like_mavlink(data: bytes) -> bool:
    """Three MAVLink 2 frame starts in a row, each where the previous frame's length ends."""
    for start in range(min(len(data), 300)):
        pos, hops = start, 0
        while pos + 2 < len(data) and data[pos] == 0xFD and data[pos + 2] in (0, 1):
            pos += 12 + data[pos + 1] + (13 if data[pos + 2] else 0)
            hops += 1
            if hops == 3:
                return True
    return False


def _look_of(data: bytes) -> str:
    printable = sum(32 <= b < 127 or b in (9, 10, 13) for b in data)
    if printable >= 0.95 * len(data):
        first = data.decode("ascii", "replace").strip().splitlines()[:2]
        return "text, starting " + " | ".join(repr(line[:60]) for line in first)
    return "binary, starting " + data[:24].hex(" ")


def _certain(name: str, dec: StreamDecoderBase, samples: int) -> bool:
    stats = dec.stats
    if name == "ascii":
        return samples >= MIN_LINES and stats.errors <= samples // 4
    return stats.frames >= MIN_FRAMES and stats.errors <= stats.frames // 4


def _evidence(name: str, dec: StreamDecoderBase, samples: int) -> int:
    """Good frames that speak for ``name``: sample lines for text, checksummed frames for binary."""
    return samples if name == "ascii" else dec.stats.frames


class _Candidate:
    """One protocol's decoder reading the stream, with what it returned so far."""

    def __init__(self, name: str, decoder: StreamDecoderBase, max_messages: int):
        self.name = name
        self.decoder = decoder
        self._batches: list[np.ndarray] = []
        self._samples = 0
        self._messages: deque[Message] = deque(maxlen=max_messages)

    def feed(self, data: bytes) -> None:
        self._add(self.decoder.feed(data))

    def flush(self) -> None:
        self._add(self.decoder.flush())

    def _add(self, out: Decoded) -> None:
        if len(out.samples):
            self._batches.append(out.samples)
            self._samples += len(out.samples)
        self._messages.extend(out.messages)

    @property
    def samples(self) -> int:
        return self._samples

    def decoded(self) -> Decoded:
        samples = join_batches(self._batches)
        return Decoded(samples, list(self._messages))


class Detector:
    """Recognises the protocol of a stream read piece by piece, losing none of its bytes.

    Every candidate decoder reads each piece once and keeps what it returned, so the one
    chosen hands over every sample of the bytes seen. A protocol is chosen when its frames are
    certain (``MIN_FRAMES`` checksummed frames, or ``MIN_LINES`` sample lines, with at most a
    quarter as many damaged ones). On a heavily damaged link that rule may never hold: after
    ``ENOUGH_BYTES``, a protocol with ``MIN_DAMAGED_FRAMES`` good frames and more of them than
    any other is chosen anyway, and the explanation says how damaged the link is.
    ``max_messages`` bounds the messages each candidate keeps while undecided (the oldest go).
    """

    def __init__(self, max_messages: int = 1024) -> None:
        self.nbytes = 0
        self._head = bytearray()  # the first bytes, to describe what they look like
        self._candidates = [_Candidate(name, dec, max_messages) for name, dec in _candidates()]

    def feed(self, data: bytes) -> None:
        """Give ``data`` to every candidate decoder, which keeps what it returns."""
        self.nbytes += len(data)
        if len(self._head) < LOOK_BYTES:
            self._head += data[: LOOK_BYTES - len(self._head)]
        for candidate in self._candidates:
            candidate.feed(data)

    def detection(self, final: bool = False) -> Detection:
        """The protocol recognised so far, or why none is. ``final``: the stream ended; the
        candidate with the most samples wins however few (no sample of it is lost)."""
        if final:
            for candidate in self._candidates:
                candidate.flush()
        choice = self._choice(final)
        if choice is not None:
            return self._chosen(*choice)
        ranked = sorted(self._candidates, key=lambda c: -_evidence(c.name, c.decoder, c.samples))
        head = bytes(self._head)
        if not pymavlink_available() and _looks_like_mavlink(head):
            return Detection(None, "the bytes look like MAVLink 2 frames, but pymavlink is not installed: "
                                   "pip install 'imu-station[mavlink]'")
        if self.nbytes < ENOUGH_BYTES and not final:
            return Detection(None, f"no protocol recognised yet in {self.nbytes} bytes", need_more=True)
        found = "; ".join(f"{c.name}: {_evidence(c.name, c.decoder, c.samples)} good "
                          f"{'sample lines' if c.name == 'ascii' else 'frames'} and {c.decoder.stats.errors} "
                          f"damaged" for c in ranked if _evidence(c.name, c.decoder, c.samples)
                          or c.decoder.stats.errors)
        text = (f"no known protocol (native, xsens, mavlink, ascii) in {self.nbytes} bytes; they look "
                f"{_look_of(head)}")
        if found:
            text += (f"; what each protocol found: {found}; too few good frames to be sure: if the unit "
                     f"speaks one of these, the link is damaged (check the cable, the baud rate and "
                     f"for electrical noise) or name it with --protocol NAME")
        else:
            text += "; check the baud rate, or name the protocol with --protocol"
        return Detection(None, text)

    def decided(self) -> bool:
        """Whether :meth:`detection` would name a protocol now (cheap: no explanation made)."""
        return self._choice(final=False) is not None

    def _choice(self, final: bool) -> tuple[_Candidate, str] | None:
        """The candidate to choose and a note on why (empty when certain), or None."""
        certain = [c for c in self._candidates if _certain(c.name, c.decoder, c.samples)]
        if certain:
            return max(certain, key=lambda c: c.samples), ""
        ranked = sorted(self._candidates, key=lambda c: -_evidence(c.name, c.decoder, c.samples))
        best = _evidence(ranked[0].name, ranked[0].decoder, ranked[0].samples)
        second = _evidence(ranked[1].name, ranked[1].decoder, ranked[1].samples) if len(ranked) > 1 else 0
        if self.nbytes >= ENOUGH_BYTES and best >= MIN_DAMAGED_FRAMES and best > second:
            stats = ranked[0].decoder.stats
            return ranked[0], (f"chosen on a damaged link ({stats.errors} damaged frames, "
                               f"{stats.garbage_bytes} garbage bytes): check the cable and the baud rate")
        if final:
            most = max(self._candidates, key=lambda c: c.samples)
            if most.samples:
                return most, "chosen at the end of the stream, on the few samples it held"
        return None

    def _chosen(self, candidate: _Candidate, note: str) -> Detection:
        out = candidate.decoded()
        text = _describe(candidate.name, candidate.decoder, out, self.nbytes)
        if note:
            text += "; " + note
        return Detection(candidate.name, text, len(out.samples), _rate(out.samples), candidate.decoder, out)


def detect(data: bytes) -> Detection:
    """Recognise the protocol of ``data``, the first bytes a unit sent (from any point of its stream)."""
    detector = Detector()
    detector.feed(bytes(data))
    return detector.detection()


class AutoDecoder(StreamDecoderBase):
    """A decoder that recognises the protocol from the first bytes, then decodes with it.

    Until then every candidate decoder reads the bytes (a :class:`Detector`), so the one chosen
    returns every sample from the first byte on, however long recognition took; nothing is
    dropped. ``detection`` is the :class:`Detection` once made (its ``explanation`` is what to
    show the user); :meth:`explain` says what was found so far when none is yet. At the end of
    the stream, the candidate with the most samples is taken however few it has.
    ``max_messages`` bounds the non-sample messages each candidate keeps while undecided.
    """

    name = "auto"

    def __init__(self, max_messages: int = 1024) -> None:
        super().__init__()
        self.detection: Detection | None = None
        self._detector: Detector | None = Detector(max_messages)
        self._inner: StreamDecoderBase | None = None

    def feed(self, data: bytes) -> Decoded:
        """Decode ``data``: nothing until a protocol is recognised, then everything the recognised
        decoder read so far, then its output (``StreamDecoderBase.feed``)."""
        if self._inner is not None:
            return self._inner.feed(data)
        assert self._detector is not None
        self._detector.feed(data)
        self.stats.garbage_bytes += len(data)  # unexplained until a protocol is recognised
        if not self._detector.decided():
            return Decoded()
        return self._take(final=False)

    def _take(self, final: bool) -> Decoded:
        assert self._detector is not None
        found = self._detector.detection(final)
        if found.protocol is None or found.decoder is None:
            return Decoded()
        self.detection = found
        self._inner = found.decoder
        self.stats = found.decoder.stats  # it read every byte: its counters are the whole story
        self._detector = None
        return found.decoded

    def flush(self) -> Decoded:
        """End of stream: decide on what was seen if nothing was recognised yet, then flush."""
        if self._inner is not None:
            return self._inner.flush()
        return self._take(final=True)

    def explain(self) -> str:
        """What was recognised, or why nothing is yet (bytes seen, what each protocol found)."""
        if self.detection is not None:
            return self.detection.explanation
        assert self._detector is not None
        return self._detector.detection().explanation

    @property
    def protocol(self) -> str | None:
        """The recognised protocol's name, None until one is."""
        return None if self.detection is None else self.detection.protocol
