"""Which protocol a unit speaks, from the first bytes it sends, with what was found in words.

Every known decoder reads the same bytes; the one that finds checksummed frames (or, for text,
sample lines) without errors wins. Binary protocols are recognised by their frames even when
those carry no inertial data (the explanation then says what the unit should be told to send);
text lines must hold samples. The result names the protocol, says why, and hands over the
decoder that read the bytes, so no sample of them is lost.

``AutoDecoder`` (registered as ``auto``) does this inside the stream: it holds the first bytes
until a protocol is recognised, then decodes with that protocol's decoder from the first byte.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocols.ascii_lines import AsciiDecoder
from protocols.base import Decoded, DecoderStats, StreamDecoderBase
from protocols.mavlink import MavlinkDecoder, pymavlink_available
from protocols.native import DEVICE_INFO, NativeDecoder
from protocols.xsens import MESSAGE_NAMES, XsensDecoder

MIN_FRAMES = 3  # checksummed frames that make a binary protocol certain
MIN_LINES = 3  # sample lines that make a text protocol certain
ENOUGH_BYTES = 4096  # after this many bytes without a protocol, say what the bytes look like


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
    if len(samples) < 2:
        return float("nan")
    dt = np.diff(samples["t_us"].astype(np.int64))
    dt = dt[dt > 0]
    return 1e6 / float(np.median(dt)) if len(dt) else float("nan")


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


def detect(data: bytes) -> Detection:
    """Recognise the protocol of ``data``, the first bytes a unit sent (from any point of its stream)."""
    results = []
    for name, dec in _candidates():
        out = dec.feed(bytes(data))
        results.append((name, dec, out))
    best = None
    for name, dec, out in results:
        stats = dec.stats
        n = len(out.samples)
        if name == "ascii":
            certain = n >= MIN_LINES and stats.errors <= n // 4
        else:
            certain = stats.frames >= MIN_FRAMES and stats.errors <= stats.frames // 4
        if certain and (best is None or n > len(best[2].samples)):
            best = (name, dec, out)
    if best is not None:
        name, dec, out = best
        return Detection(name, _describe(name, dec, out, len(data)), len(out.samples), _rate(out.samples),
                         dec, out)
    if not pymavlink_available() and _looks_like_mavlink(data):
        return Detection(None, "the bytes look like MAVLink 2 frames, but pymavlink is not installed: "
                               "pip install 'imu-station[mavlink]'")
    if len(data) < ENOUGH_BYTES:
        return Detection(None, f"no protocol recognised yet in {len(data)} bytes", need_more=True)
    return Detection(None, f"no known protocol (native, xsens, mavlink, ascii) in {len(data)} bytes; "
                           f"they look {_look_of(data)}; check the baud rate, or name the protocol "
                           f"with --protocol")


class AutoDecoder(StreamDecoderBase):
    """A decoder that recognises the protocol from the first bytes, then decodes with it.

    Until then it holds the bytes (at most ``max_hold``; beyond, the oldest are dropped as
    garbage) and tries again each time a quarter more arrived. ``detection`` is the
    :class:`Detection` once made (its ``explanation`` is what to show the user).
    """

    name = "auto"

    def __init__(self, max_hold: int = 65_536) -> None:
        super().__init__()
        self.max_hold = max_hold
        self.detection: Detection | None = None
        self._inner: StreamDecoderBase | None = None
        self._new = 0  # bytes since the last attempt

    def feed(self, data: bytes) -> Decoded:
        if self._inner is not None:
            return self._inner.feed(data)
        self._buf += data
        self._new += len(data)
        if len(self._buf) > self.max_hold:
            drop = len(self._buf) - self.max_hold
            self.stats.garbage_bytes += drop
            self.stats.resyncs += 1
            del self._buf[:drop]
        if self._new < max(64, len(self._buf) // 4):
            return Decoded()
        self._new = 0
        found = detect(bytes(self._buf))
        inner = found.decoder
        if found.protocol is None or inner is None:
            return Decoded()
        self.detection = found
        self._inner = inner
        garbage_before = self.stats.garbage_bytes
        self.stats = inner.stats
        self.stats.garbage_bytes += garbage_before
        self._buf.clear()
        return found.decoded

    def flush(self) -> Decoded:
        if self._inner is not None:
            return self._inner.flush()
        if self._buf:  # the stream ended before a protocol was recognised: the bytes were garbage
            self.stats.garbage_bytes += len(self._buf)
            self._buf.clear()
        return Decoded()

    @property
    def protocol(self) -> str | None:
        return None if self.detection is None else self.detection.protocol
