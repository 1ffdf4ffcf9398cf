"""Every stream decoder with an encoder of its good frames: the table the fuzz tests and
``benchmarks/fuzz.py`` run over. A new decoder is one line in :data:`CASES`.

Each case says what its framing can promise when good frames are interleaved with garbage
(``guarantee``), and ``fit_garbage`` turns arbitrary garbage into garbage within that promise:

- native and MAVLink (16-bit CRCs): any garbage; a false frame start in it is believed only
  when its CRC passes, once in 65,536 false starts, which these tests do not meet;
- Xsens (an 8-bit checksum, passed by chance once in 256): any garbage; a false start whose
  checksum passes is believed only when no valid frame starts inside the span it claims, or
  when MTData2 items and what follows speak for it (``protocols/xsens.py``), so a good frame
  may be lost only when it lies in such a span and holds a chance frame of its own
  (``xsens_allowed_losses`` names those);
- text lines: CSV lines, garbage that ends with a line end; garbage with no line end glues
  itself to the next line, which then cannot be read (it has nothing to resynchronise on but
  the line end). VectorNav sentences (``$VN`` and a checksum) and MotionCal lines (``Raw:``,
  ``Uni:`` and nine numbers) are found after glued garbage: any garbage shorter than a line's
  limit.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np
from frame_helpers import SPEC_EXAMPLE, plain_frames

from protocols import ascii_lines, mavlink, native, xsens
from protocols.ascii_lines import AsciiDecoder
from protocols.base import SAMPLE_DTYPE, StreamDecoderBase
from protocols.detect import AutoDecoder
from protocols.frame import FrameDecoder
from protocols.frame_description import FrameDescription, describe
from protocols.mag_batches import join_batches, with_mag
from protocols.native import NativeDecoder
from protocols.xsens import XsensDecoder


def _any_garbage(garbage: bytes) -> bytes:
    return garbage


def _line_garbage(garbage: bytes) -> bytes:
    return garbage + b"\n" if garbage and not garbage.endswith((b"\n", b"\r")) else garbage


def _xsens_frames(samples: np.ndarray, **options) -> list[bytes]:
    return [xsens.encode_samples(samples[i : i + 1], **options) for i in range(len(samples))]


def _xsens_hr_frames(samples: np.ndarray) -> list[bytes]:
    """AccelerationHR / RateOfTurnHR packets, as an MTi-600 sends them at 1 kHz."""
    frames = []
    for s in samples:
        payload = xsens.encode_item(xsens.PACKET_COUNTER, struct.pack(">H", int(s["seq"]) & 0xFFFF))
        ticks = (int(s["t_us"]) // 100) & 0xFFFFFFFF
        payload += xsens.encode_item(xsens.SAMPLE_TIME_FINE, struct.pack(">I", ticks))
        payload += xsens.encode_item(xsens.ACCELERATION_HR, struct.pack(">3f", *map(float, s["acc"])))
        payload += xsens.encode_item(xsens.RATE_OF_TURN_HR, struct.pack(">3f", *map(float, s["gyro"])))
        frames.append(xsens.encode_frame(xsens.MID_MTDATA2, payload))
    return frames


def _native_frames(samples: np.ndarray) -> list[bytes]:
    data = native.encode_samples(samples)
    size = native.SAMPLE_FRAME_SIZE
    return [data[i : i + size] for i in range(0, len(data), size)]


def nine_axis(samples: np.ndarray) -> np.ndarray:
    """The samples of a unit with a magnetometer: a field of about 50 uT, different in each sample."""
    out = with_mag(samples).copy()
    out["mag"] = samples["acc"] * 4.0 + np.array([10.0, -20.0, 30.0])
    return out


def _native_mag_frames(samples: np.ndarray) -> list[bytes]:
    data = native.encode_samples(nine_axis(samples))
    size = native.MAG_FRAME_SIZE
    return [data[i : i + size] for i in range(0, len(data), size)]


def _xsens_mag_frames(samples: np.ndarray) -> list[bytes]:
    return _xsens_frames(nine_axis(samples), field_ut=50.0)


def _mavlink_mag_frames(samples: np.ndarray, message: str) -> list[bytes]:
    return _mavlink_frames(nine_axis(samples), message)


_MAG_COLUMNS = ascii_lines.DEFAULT_COLUMNS + ",mx:mG,my:mG,mz:mG"


def _line_mag_frames(samples: np.ndarray) -> list[bytes]:
    mag = nine_axis(samples)
    return [ascii_lines.encode_csv(mag[i : i + 1], _MAG_COLUMNS) for i in range(len(mag))]


def _mavlink_frames(samples: np.ndarray, message: str) -> list[bytes]:
    return [mavlink.encode_samples(samples[i : i + 1], message) for i in range(len(samples))]


def _frame_frames(desc: FrameDescription, samples: np.ndarray) -> list[bytes]:
    data = plain_frames(desc, samples)
    return [data[i : i + desc.length] for i in range(0, len(data), desc.length)]


def _line_frames(samples: np.ndarray, kind: str) -> list[bytes]:
    return [ascii_lines.encode_samples(samples[i : i + 1], kind) for i in range(len(samples))]


def _line_mag_lines(samples: np.ndarray, kind: str) -> list[bytes]:
    return _line_frames(nine_axis(samples), kind)


@dataclass(frozen=True)
class Case:
    """One decoder under fuzzing: how to make it, its good frames, and the garbage it survives."""

    name: str
    decoder: Callable[[], StreamDecoderBase]
    frames: Callable[[np.ndarray], list[bytes]]  # one encoded frame per sample
    fit_garbage: Callable[[bytes], bytes]
    sync: bytes  # the bytes that start a frame, for sync-rich noise
    guarantee: str
    needs_pymavlink: bool = False
    lines: bool = False  # text lines, one sample a line
    # Which good frames the guarantee allows to lose, given the stream as (bytes, is_good) pieces.
    allowed_losses: Callable[[list[tuple[bytes, bool]]], set[int]] = lambda pieces: set()


_BINARY = "any garbage between good frames: every good frame comes out"
_XSENS = ("any garbage: every good MTData2 frame comes out, unless it lies inside a false start whose "
          "8-bit checksum passes and a frame start inside it passes its checksum too")
_LINES = "garbage that ends with a line end: every good line comes out"
_SENTENCES = "any garbage (under 512 bytes without a line end): every checksummed sentence comes out"
_TAGGED = "any garbage (under 512 bytes without a line end): every tagged sample line comes out"


def _xsens_losses(pieces: list[tuple[bytes, bool]]) -> set[int]:
    return xsens_allowed_losses(pieces)

CASES: list[Case] = [
    Case("native", NativeDecoder, _native_frames, _any_garbage, native.SYNC, _BINARY),
    Case("xsens-float32", XsensDecoder, _xsens_frames, _any_garbage, xsens.SYNC, _XSENS,
         allowed_losses=_xsens_losses),
    Case("xsens-fp1220", XsensDecoder, partial(_xsens_frames, precision="fp1220"), _any_garbage, xsens.SYNC,
         _XSENS, allowed_losses=_xsens_losses),
    Case("xsens-fp1632", XsensDecoder, partial(_xsens_frames, precision="fp1632"), _any_garbage, xsens.SYNC,
         _XSENS, allowed_losses=_xsens_losses),
    Case("xsens-float64", XsensDecoder, partial(_xsens_frames, precision="float64"), _any_garbage,
         xsens.SYNC, _XSENS),
    Case("xsens-hr", partial(XsensDecoder, source="hr"), _xsens_hr_frames, _any_garbage, xsens.SYNC, _XSENS,
         allowed_losses=_xsens_losses),
    Case("mavlink-highres", mavlink.MavlinkDecoder, partial(_mavlink_frames, message="HIGHRES_IMU"),
         _any_garbage, b"\xfd", _BINARY, needs_pymavlink=True),
    Case("mavlink-scaled", mavlink.MavlinkDecoder, partial(_mavlink_frames, message="SCALED_IMU"),
         _any_garbage, b"\xfd", _BINARY, needs_pymavlink=True),
    Case("ascii-csv", AsciiDecoder, partial(_line_frames, kind="csv"), _line_garbage, b"\n", _LINES,
         lines=True),
    # MotionCal and VectorNav lines always carry a field: nine-axis streams
    Case("ascii-motioncal-mag", AsciiDecoder, partial(_line_mag_lines, kind="motioncal"), _any_garbage,
         b"Raw:", _TAGGED, lines=True),
    Case("ascii-vectornav-mag", AsciiDecoder, partial(_line_mag_lines, kind="vnymr"), _any_garbage,
         b"$VNYMR,", _SENTENCES, lines=True),
    Case("auto-native", AutoDecoder, _native_frames, _any_garbage, native.SYNC, _BINARY),
    Case("frame", partial(FrameDecoder, describe(SPEC_EXAMPLE)),
         partial(_frame_frames, describe(SPEC_EXAMPLE)), _any_garbage, b"\xaa\x55", _BINARY),
    Case("auto-xsens", AutoDecoder, _xsens_frames, _any_garbage, xsens.SYNC, _XSENS,
         allowed_losses=_xsens_losses),
    # Nine-axis units: the same framing, sample records that carry the magnetic field.
    Case("native-mag", NativeDecoder, _native_mag_frames, _any_garbage, native.SYNC, _BINARY),
    Case("xsens-mag", partial(XsensDecoder, field_ut=50.0), _xsens_mag_frames, _any_garbage, xsens.SYNC,
         _XSENS, allowed_losses=_xsens_losses),
    Case("mavlink-scaled-mag", mavlink.MavlinkDecoder, partial(_mavlink_mag_frames, message="SCALED_IMU"),
         _any_garbage, b"\xfd", _BINARY, needs_pymavlink=True),
    Case("ascii-csv-mag", partial(AsciiDecoder, _MAG_COLUMNS), _line_mag_frames, _line_garbage, b"\n", _LINES,
         lines=True),
]


def available_cases() -> list[Case]:
    """The cases this environment can run (MAVLink needs pymavlink)."""
    return [c for c in CASES if not c.needs_pymavlink or mavlink.pymavlink_available()]


def make_samples(n: int, seed: int = 0, rate_hz: float = 200.0) -> np.ndarray:
    """Plausible samples at ``rate_hz``, with times that are whole 100 us ticks (Xsens)."""
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.round(np.arange(n) * 1e6 / rate_hz / 100) * 100 + 10_000
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25 + rng.normal(0, 0.5, n)
    return s


def feed_chunks(decoder: StreamDecoderBase, data: bytes, cuts: list[int]) -> np.ndarray:
    """Feed ``data`` cut at ``cuts`` (sorted positions), flush, and return every sample."""
    out, start = [], 0
    for cut in [*cuts, len(data)]:
        if cut > start:
            out.append(decoder.feed(data[start:cut]).samples)
            start = cut
    out.append(decoder.flush().samples)
    return join_batches(out)  # a nine-axis stream's batches before its first field are six-axis


def sample_keys(samples: np.ndarray) -> list[bytes]:
    """What identifies a sample whatever the decoder did with its time: acc and gyro, bit for bit."""
    return [bytes(a.tobytes() + g.tobytes()) for a, g in zip(samples["acc"], samples["gyro"], strict=True)]


def lost_frames(case: Case, good: list[bytes], got: np.ndarray) -> list[int]:
    """Indices of the ``good`` frames whose sample is not among ``got``.

    What each good frame decodes to is found by decoding it alone, so precision and unit
    conversions are those of the decoder itself.
    """
    alone = case.decoder()
    wanted = sample_keys(feed_chunks(alone, b"".join(good), []))
    have: dict[bytes, int] = {}
    for key in sample_keys(got):
        have[key] = have.get(key, 0) + 1
    lost = []
    for i, key in enumerate(wanted):
        if have.get(key, 0):
            have[key] -= 1
        else:
            lost.append(i)
    return lost


def _xsens_frame_end(data: bytes, p: int) -> int:
    """End of the checksum-valid Xbus frame at ``p``, or 0 when there is none."""
    if data[p : p + 2] != xsens.SYNC or p + 4 > len(data):
        return 0
    length, header = data[p + 3], 4
    if length == 0xFF:
        if p + 6 > len(data):
            return 0
        length, header = (data[p + 4] << 8) | data[p + 5], 6
    end = p + header + length + 1
    return end if end <= len(data) and not sum(data[p + 1 : end]) & 0xFF else 0


def xsens_allowed_losses(pieces: list[tuple[bytes, bool]]) -> set[int]:
    """Good Xsens frames the stated exception allows to lose in a stream of (bytes, is_good) pieces.

    A good frame may be lost when it starts inside the span of a false start (``FA FF`` in
    garbage, or inside a good frame) whose checksum passes, and a frame start inside the good
    frame itself passes its checksum too (a chance frame in its payload).
    """
    data = b"".join(p for p, _ in pieces)
    starts, good_index, pos = {}, 0, 0
    for piece, is_good in pieces:
        if is_good:
            starts[pos] = good_index
            good_index += 1
        pos += len(piece)
    valid = {}
    p = data.find(xsens.SYNC)
    while p >= 0:
        end = _xsens_frame_end(data, p)
        if end:
            valid[p] = end
        p = data.find(xsens.SYNC, p + 1)
    allowed: set[int] = set()
    for p, end in valid.items():
        if p in starts:
            continue
        for s, i in starts.items():
            if p < s < end and s in valid and any(s < q < valid[s] for q in valid):
                allowed.add(i)
    return allowed
