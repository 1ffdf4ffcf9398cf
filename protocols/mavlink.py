"""MAVLink 1 and 2 IMU telemetry: RAW_IMU, SCALED_IMU, SCALED_IMU2/3 and HIGHRES_IMU.

MAVLink IMU messages are **processed telemetry at low rates** (an autopilot streams them at
a few to a few tens of hertz, often filtered and decimated): fit for pose and rotation
sequences (six/twelve-position, turns), not for Allan variance or noise characterisation,
which need the sensor's full-rate raw output.

The framing is read here (so a false start inside garbage never hides the good frame after
it, and each error lands in one counter); message definitions, CRC extras and payload
decoding come from pymavlink (the optional extra ``mavlink``), with the ArduPilot dialect,
a superset of the common one. Unit conversions:

- HIGHRES_IMU: m/s^2, rad/s, degC as sent, magnetic field gauss x 100 -> uT (when
  fields_updated flags xmag, ymag and zmag: bits 6-8); ``t_us`` = time_usec.
- SCALED_IMU, SCALED_IMU2, SCALED_IMU3: mG x 9.80665e-3 -> m/s^2, mrad/s x 1e-3 -> rad/s,
  cdegC x 0.01 -> degC (0 means "no temperature": NaN), magnetic field mgauss x 0.1 -> uT;
  ``t_us`` = time_boot_ms x 1000, unwrapped past 2^32 ms.
- RAW_IMU: the standard leaves the units to the sender; ArduPilot sends mG, mrad/s and mgauss
  like SCALED_IMU, the default scales here (``raw_acc_scale``, ``raw_gyro_scale``, the field as
  mgauss); ``t_us`` = time_usec.

A field of exactly (0, 0, 0) is "no magnetometer" (what an autopilot without one sends). From
the first sample with a field on, batches are ``MAG_SAMPLE_DTYPE`` (NaN where a message has none).

One IMU makes the samples: the first IMU message seen (or the first of ``source``) fixes the
message name, system, component and IMU id; other IMU messages are returned as messages and
counted in ``sources_seen``. ``seq`` counts the samples (MAVLink has no per-sample counter).

Several IMUs of one board (``protocols.instances``): after :meth:`MavlinkDecoder.decode_instances`,
the board is the system and component of the first IMU message, and each IMU instance of it is a
stream of its own: ``SCALED_IMU`` is instance 0, ``SCALED_IMU2`` 1, ``SCALED_IMU3`` 2, ``HIGHRES_IMU``
and ``RAW_IMU`` their ``id`` (the first message seen of an instance fixes which one makes its
samples). Instance 0 takes the single stream's way (its fast path, its ``seq`` and clock); each
other instance has its own ``seq``, its own unwrapped ``time_boot_ms`` and its own field flag, and
comes out in ``InstancesDecoded.instances``. Without the call, nothing of this runs.

Runs of the chosen source's IMU frames take a vectorised path once that source is fixed: frames of
one length are checked at once (header, the X.25 CRC with the message's CRC extra as per-byte
tables, the payload zero-extended to the message's full length as MAVLink 2 trims trailing zeros)
and their values read as columns; anything else (other messages or sources, signed frames, damage,
a time that steps back before the clock zero) goes the per-frame path through pymavlink, and both
give the same samples and counters (``tests/test_mavlink_fast.py``).

Why this module is long: the per-frame decoder, the vectorised path for runs of IMU frames (which
must agree with it frame for frame, so they sit side by side) and the encoder the tests and
benchmarks use are one protocol; split, each part would import the others' internals.
"""

from __future__ import annotations

import binascii
import math
import re
from bisect import bisect_left
from typing import Any

import numpy as np

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, Decoded, Message, StreamDecoderBase, has_mag
from protocols.errors import StationError
from protocols.instances import InstancesDecoded, mavlink_instance
from protocols.mag_batches import join_batches, rows_to_batch, with_mag
from protocols.units import STANDARD_GRAVITY

STX_V1 = 0xFE
STX_V2 = 0xFD
HEADER_V1 = 6
HEADER_V2 = 10
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
MILLI_G = STANDARD_GRAVITY * 1e-3
UT_PER_GAUSS = 100.0
UT_PER_MILLIGAUSS = 0.1
HIGHRES_MAG_UPDATED = 0x1C0  # fields_updated bits 6-8: xmag, ymag, zmag
_NAN3 = (math.nan, math.nan, math.nan)

IMU_MESSAGES = ("HIGHRES_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3", "RAW_IMU")
_STX = re.compile(rb"[\xfd\xfe]")
_UNDATED = ()  # what _imu_row returns for an IMU message it cannot place in time
_ROUTED = (None,)  # what _imu_row returns for a sample it gave to another instance's stream


class MavlinkUnavailable(StationError):
    """pymavlink is not installed: the MAVLink protocol needs the ``mavlink`` extra (exit 4)."""


def load_dialect() -> Any:
    """The pymavlink ArduPilot dialect module (MAVLink 2 capable), or ``MavlinkUnavailable``."""
    try:
        from pymavlink.dialects.v20 import ardupilotmega
    except ImportError:
        raise MavlinkUnavailable(
            "the MAVLink protocol needs pymavlink: pip install 'imu-station[mavlink]'") from None
    return ardupilotmega


def pymavlink_available() -> bool:
    """True when pymavlink is installed (the ``mavlink`` extra), so the MAVLink decoder can run."""
    try:
        load_dialect()
    except MavlinkUnavailable:
        return False
    return True


class MavlinkDecoder(StreamDecoderBase):
    """Incremental decoder of MAVLink 1/2 frames; IMU messages of one source become samples.

    ``source`` picks the IMU message (one of ``IMU_MESSAGES``); None takes the first one seen.
    ``messages_seen`` counts every decoded message by name, ``sources_seen`` the IMU sources
    as ``"NAME sys/comp id"``.
    """

    name = "mavlink"

    def __init__(self, source: str | None = None, raw_acc_scale: float = MILLI_G,
                 raw_gyro_scale: float = 1e-3) -> None:
        super().__init__()
        if source is not None and source not in IMU_MESSAGES:
            raise ValueError(f"unknown MAVLink IMU message {source!r}; use one of {', '.join(IMU_MESSAGES)}")
        self._dialect = load_dialect()
        self._mav = self._dialect.MAVLink(None)
        self._map = self._dialect.mavlink_map
        self.source = source
        self.raw_acc_scale = raw_acc_scale
        self.raw_gyro_scale = raw_gyro_scale
        self.messages_seen: dict[str, int] = {}
        self.sources_seen: dict[str, int] = {}
        self._key: tuple | None = None
        self._count = 0
        self._boot_ms: int | None = None  # unwrapped time_boot_ms
        self._mag = False  # a field came: batches are MAG_SAMPLE_DTYPE from then on
        # decode_instances(): the instances 1.. of the board (system, component) by instance; None: one IMU
        self._streams: dict[int, _InstanceStream] | None = None
        self._board: tuple[int, int] | None = None

    def decode_instances(self) -> None:
        """Decode every IMU instance of the board as a stream of its own (module docstring): from now on
        ``feed`` and ``flush`` return :class:`~protocols.instances.InstancesDecoded`, instance 0's samples
        in ``samples``. Call it before the first ``feed``.

        Raises
        ------
        ValueError
            With ``source``, which picks one message (hence one instance), or after samples were decoded.
        """
        if self.source is not None:
            raise ValueError(f"mavlink:{self.source} picks one IMU message; several instances are told apart "
                             "by their messages: leave the message out")
        if self._key is not None:
            raise ValueError("decode_instances() comes before the first samples")
        if self._streams is None:
            self._streams = {}

    @property
    def instance(self) -> int | None:
        """The IMU instance ``samples`` are of (None until the first IMU message)."""
        key = self._key
        return None if key is None else mavlink_instance(key[0], key[3])

    @property
    def instances_seen(self) -> dict[int, int]:
        """IMU instances of the board seen so far, with their frames (the board: the system and component
        of the samples, or of the first IMU message with :meth:`decode_instances`)."""
        key = self._key
        board = self._board if key is None else (key[1], key[2])
        seen: dict[int, int] = {}
        # a copy first: the reader thread may add a source while another thread asks
        for label, count in dict(self.sources_seen).items():
            name, ids, _, imu_id = label.split()
            system, component = (int(v) for v in ids.split("/"))
            if board is None or board == (system, component):
                instance = mavlink_instance(name, int(imu_id))
                seen[instance] = max(seen.get(instance, 0), count)
        return dict(sorted(seen.items()))

    # -------------------------------------------------------------- framing

    def _frame_length(self, pos: int) -> int:
        """Length of the frame announced at ``pos``: 0 if not a frame start, -1 if incomplete."""
        buf = self._buf
        avail = len(buf) - pos
        if buf[pos] == STX_V1:
            if avail < 2:
                return -1
            return HEADER_V1 + buf[pos + 1] + 2
        if avail < 3:
            return -1
        incompat = buf[pos + 2]
        if incompat & ~IFLAG_SIGNED:
            return 0
        return HEADER_V2 + buf[pos + 1] + 2 + (SIGNATURE_LEN if incompat & IFLAG_SIGNED else 0)

    def _msg_id(self, pos: int) -> int:
        buf = self._buf
        if buf[pos] == STX_V1:
            return buf[pos + 5]
        return buf[pos + 7] | (buf[pos + 8] << 8) | (buf[pos + 9] << 16)

    def _crc_ok(self, pos: int, length: int) -> bool | None:
        """CRC check of a complete frame; None when the message id is unknown (no CRC extra)."""
        buf = self._buf
        msgtype = self._map.get(self._msg_id(pos))
        if msgtype is None:
            return None
        sig = SIGNATURE_LEN if buf[pos] == STX_V2 and buf[pos + 2] & IFLAG_SIGNED else 0
        end = pos + length - sig
        crc = buf[end - 2] | (buf[end - 1] << 8)
        body = bytearray(buf[pos + 1 : end - 2])
        body.append(msgtype.crc_extra)
        return _x25(body) == crc

    def _valid_frame_inside(self, start: int, end: int, final: bool = True) -> bool | None:
        """Whether a complete frame with a good CRC starts in ``buf[start:end]``; None (not ``final``)
        while a frame starting there is not complete yet: the answer must not depend on how the
        stream was cut into reads."""
        for m in _STX.finditer(self._buf, start, end):
            p = m.start()
            length = self._frame_length(p)
            if length < 0 or (length > 0 and p + length > len(self._buf)):
                if not final:
                    return None
                continue
            if length > 0 and self._crc_ok(p, length):
                return True
        return False

    def feed(self, data: bytes) -> Decoded:
        """Decode ``data`` after what is buffered (``StreamDecoderBase.feed``)."""
        return self._decode(data, final=False)

    def _decode(self, data: bytes, final: bool) -> Decoded:
        buf = self._buf
        buf += data
        self._win: _FastWindow | None = None  # slot positions hold until the buffer is cut
        rows: list[tuple] = []
        batches: list[np.ndarray] = []  # MAG_SAMPLE_DTYPE runs of the fast path, rows before each
        messages: list[Message] = []
        stats = self.stats
        pos = 0
        while True:
            if self._key is not None and pos < len(buf) and buf[pos] in (STX_V1, STX_V2):
                run, used = self._fast_run(pos)
                if used:
                    if rows:
                        batches.append(rows_to_batch(rows, True))
                        rows = []
                    batches.append(run)
                    pos += used
                    continue
            m = _STX.search(buf, pos)
            if m is None:
                if len(buf) > pos:
                    stats.garbage_bytes += len(buf) - pos
                    stats.resyncs += 1
                pos = len(buf)
                break
            if m.start() > pos:
                stats.garbage_bytes += m.start() - pos
                stats.resyncs += 1
                pos = m.start()
            length = self._frame_length(pos)
            if length == 0:
                pos = self._skip(pos)
                continue
            if length < 0 or pos + length > len(buf):
                break
            if self._msg_id(pos) not in self._map:
                # Unknown message: no CRC extra to check it with. Believe it only when the next
                # frame starts right after it (or the stream ends there) and no good frame
                # starts inside it.
                after = pos + length
                if after == len(buf) and not final:
                    break
                inside = self._valid_frame_inside(pos + 1, after, final)
                if inside is None:
                    break
                if (after < len(buf) and buf[after] not in (STX_V1, STX_V2)) or inside:
                    pos = self._skip(pos)
                    continue
                stats.frames += 1
                stats.unknown_ids += 1
                messages.append(Message(self._msg_id(pos), bytes(buf[pos:after])))
                pos = after
                continue
            # The CRC first, in C (pymavlink's decode would check it too, in Python): a damaged frame
            # is known without decoding it (nor copying it).
            crc_good = not (self._win is not None and self._win.crc_failed(pos)) and self._crc_ok(pos, length)
            msg = None
            if crc_good:
                frame = bytearray(buf[pos : pos + length])
                try:
                    msg = self._mav.decode(frame)
                except self._dialect.MAVError:
                    stats.bad_payloads += 1
                    pos += length
                    continue
            if msg is None:
                inside = self._valid_frame_inside(pos + 1, pos + length, final)
                if inside is None:
                    break
                if inside:
                    stats.truncated += 1
                    pos = self._skip(pos)
                else:
                    stats.crc_errors += 1
                    pos = self._skip(pos)
                continue
            pos += length
            name = msg.get_type()
            self.messages_seen[name] = self.messages_seen.get(name, 0) + 1
            row = self._imu_row(msg, name) if name in IMU_MESSAGES else None
            if row is _UNDATED:
                stats.bad_payloads += 1
                continue
            stats.frames += 1
            if row is None:
                messages.append(Message(msg.get_msgId(), bytes(frame)))
            elif row is not _ROUTED:
                rows.append(row)
        self._win = None
        if pos:
            del buf[:pos]
        if batches:
            if rows:
                batches.append(rows_to_batch(rows, True))
            samples = self._joined(batches)
        else:
            samples = rows_to_batch(rows, self._mag)
        stats.samples += len(samples)
        if self._streams is None:
            return Decoded(samples, messages)
        return InstancesDecoded(samples, messages, self._instance_batches())

    def _joined(self, batches: list[np.ndarray]) -> np.ndarray:
        """The batches of one read (fast runs, rows between them) as one: ``MAG_SAMPLE_DTYPE`` once the
        stream has carried a field, else ``SAMPLE_DTYPE``."""
        dtype = MAG_SAMPLE_DTYPE if self._mag else SAMPLE_DTYPE
        parts = [b if b.dtype == dtype else with_mag(b) if self._mag else _without_mag(b)
                 for b in batches if len(b)]
        if len(parts) < 2:
            return parts[0] if parts else np.zeros(0, dtype)
        void = np.dtype((np.void, dtype.itemsize))  # raw records: numpy's structured concatenate costs more
        return np.concatenate([b.view(void) for b in parts]).view(dtype)

    def _instance_batches(self) -> dict[int, np.ndarray]:
        """The samples each other instance completed since the last call (counted as samples)."""
        assert self._streams is not None
        out = {}
        for instance, stream in self._streams.items():
            if stream.rows:
                out[instance] = rows_to_batch(stream.rows, stream._mag)
                stream.rows = []
                self.stats.samples += len(out[instance])
        return out

    def _skip(self, pos: int) -> int:
        """Drop the frame start at ``pos``: resume at the next one (counted as garbage)."""
        self.stats.resyncs += 1
        m = _STX.search(self._buf, pos + 1)
        nxt = len(self._buf) if m is None else m.start()
        self.stats.garbage_bytes += nxt - pos
        return nxt

    def flush(self) -> Decoded:
        """End of stream: an unfinished frame is truncated; what follows its start is decoded."""
        out = self._decode(b"", final=True)
        batches, messages, outs = [out.samples], list(out.messages), [out]
        while self._buf:
            self.stats.truncated += 1
            del self._buf[: self._skip(0)]
            out = self._decode(b"", final=True)
            batches.append(out.samples)
            messages += out.messages
            outs.append(out)
        samples = join_batches(batches)
        samples = with_mag(samples) if self._mag else samples
        if self._streams is None:
            return Decoded(samples, messages)
        parts: dict[int, list[np.ndarray]] = {}
        for part in outs:
            for instance, batch in getattr(part, "instances", {}).items():
                parts.setdefault(instance, []).append(batch)
        instances = {k: join_batches(b) for k, b in parts.items()}
        instances = {k: with_mag(b) if self._streams[k]._mag else b for k, b in instances.items()}
        return InstancesDecoded(samples, messages, instances)

    # -------------------------------------------------------------- fast path

    def _fast_run(self, pos: int) -> tuple[np.ndarray, int]:
        """Samples of the run of frames at ``pos`` that the per-frame path would turn into samples of the
        chosen source without a second look: unsigned, of its message, system, component and IMU id,
        of one length (a payload at most the message's full length), a good CRC, dated. Checked on
        all frames at once; the run ends at the first other frame, which the per-frame path takes, but
        for a quiet bad frame (``_FastWindow``), which the run steps over, counted as the per-frame
        path counts it."""
        key = self._key
        assert key is not None
        name, system, component, imu_id = key
        win = self._win
        if win is None or not win.covers(pos):
            buf = self._buf
            v1 = buf[pos] == STX_V1
            avail = len(buf) - pos
            if avail < HEADER_V2 or avail < buf[pos + 1] + (HEADER_V1 + 2 if v1 else HEADER_V2 + 2):
                return _EMPTY_MAG, 0  # not a whole frame yet: the per-frame path waits for it
            msg_id = _fast_spec(self._dialect, name).msg_id
            if (buf[pos + 5] != msg_id) if v1 else (buf[pos + 2] != 0 or buf[pos + 7] != msg_id & 0xFF):
                return _EMPTY_MAG, 0  # not a frame of the message (a false start in a damaged one): no arrays
            found = self._check_window(pos)
            if found is None:  # no run here (a false start): the window stays for the slots after
                return _EMPTY_MAG, 0
            win = self._win = found
        size = win.size
        i = (pos - win.base) // size
        j = win.checked
        if win.bad:
            k = bisect_left(win.bad, i)
            if k < len(win.bad):
                j = win.bad[k]
        if j <= i:
            return _EMPTY_MAG, 0
        quiet = win.quiet
        a = b = 0
        keep: slice | np.ndarray = slice(i, j)
        if quiet:
            a, b = bisect_left(quiet, i), bisect_left(quiet, j)
            if b > a:
                kept = np.ones(j - i, dtype=bool)
                kept[[q - i for q in quiet[a:b]]] = False
                keep = kept.nonzero()[0] + i
        if name == "HIGHRES_IMU" or name == "RAW_IMU":
            # Every slot's values once per window: a run is a slice of them (the kept slots with quiet ones).
            if win.out is None:
                win.out, field = self._values(win.msg, name)
                win.field = field if _ANY(field) else None
            out = win.out[keep]
            has_field = win.field is not None and bool(_ANY(win.field[keep]))
        else:
            msg = win.msg[keep]
            out, field = self._values(msg, name)
            ms = msg["time_boot_ms"].astype(np.int64)
            prev = ms[0] if self._boot_ms is None else self._boot_ms
            steps = ((np.diff(ms, prepend=prev) + 2**31) & 0xFFFFFFFF) - 2**31
            if self._boot_ms is None:
                steps[0] = ms[0]
                prev = 0
            boot = prev + np.cumsum(steps)
            if (boot < 0).any():  # dated before the stream's clock zero: the run ends before that frame
                stop = int(np.argmax(boot < 0))
                if stop < 1:
                    return _EMPTY_MAG, 0
                field, boot, out = field[:stop], boot[:stop], out[:stop]
                j = i + stop if isinstance(keep, slice) else int(keep[stop])
                b = bisect_left(quiet, j) if quiet else 0
            self._boot_ms = int(boot[-1])
            out["t_us"] = boot * 1000
            has_field = bool(field.any())
        if b > a:  # the quiet bad frames stepped over
            stats = self.stats
            stats.crc_errors += b - a
            stats.resyncs += sum(win.quiet_resyncs[a:b])
            stats.garbage_bytes += (b - a) * size
        n = len(out)
        out["seq"] = np.arange(self._count, self._count + n, dtype=np.uint64)  # wraps to 32 bits as stored
        self._count += n
        if has_field:
            self._mag = True
        self.messages_seen[name] = self.messages_seen.get(name, 0) + n
        label = f"{name} {system}/{component} id {imu_id}"
        self.sources_seen[label] = self.sources_seen.get(label, 0) + n
        self.stats.frames += n
        return out, (j - i) * size

    def _values(self, msg: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Samples of IMU messages ``msg`` but ``seq`` (and ``t_us`` of those dated by ``time_boot_ms``),
        and which carry a field: ``SAMPLE_DTYPE`` when none does and the stream has carried none yet."""
        spec = _fast_spec(self._dialect, name)
        n = len(msg)
        raw = msg.view(np.uint8).reshape(n, spec.size)
        acc_scale: float | None
        gyro_scale: float | None
        if name == "HIGHRES_IMU":
            acc_scale = gyro_scale = None
            field = (msg["fields_updated"] & HIGHRES_MAG_UPDATED) == HIGHRES_MAG_UPDATED
            mag_scale = UT_PER_GAUSS
        else:
            if name == "RAW_IMU":
                acc_scale, gyro_scale = self.raw_acc_scale, self.raw_gyro_scale
            else:
                acc_scale, gyro_scale = MILLI_G, 1e-3
            field = (msg["xmag"] != 0) | (msg["ymag"] != 0) | (msg["zmag"] != 0)
            mag_scale = UT_PER_MILLIGAUSS
        any_field = bool(_ANY(field))
        out = np.empty(n, dtype=MAG_SAMPLE_DTYPE if any_field or self._mag else SAMPLE_DTYPE)
        block = raw[:, spec.block_at : spec.block_at + 9 * spec.block_type.itemsize]
        if acc_scale is None:
            # HIGHRES_IMU: time_usec and the six float32 axes are the sample's t_us, acc and gyro as they
            # lie in memory (SAMPLE_DTYPE's bytes 4-36): one copy.
            out.view(np.uint8).reshape(n, out.itemsize)[:, 4:36] = raw[:, :32]
            out["temp"] = msg["temperature"]
            if any_field:
                with np.errstate(invalid="ignore"):  # a slot the run leaves out may hold a signalling NaN
                    mag = block[:, 24:36].view(np.float32).astype(np.float64) * mag_scale  # as Python floats
                out["mag"] = mag if _ALL(field) else np.where(field[:, None], mag, np.nan)
            elif self._mag:
                out["mag"] = np.nan
            return out, field
        if spec.has_time_usec:
            out["t_us"] = msg["time_usec"]
        cdeg = msg["temperature"].astype(np.float64) if "temperature" in (spec.dtype.names or ()) \
            else np.zeros(n)
        out["temp"] = np.where(cdeg != 0, cdeg * 0.01, np.nan)
        # xacc .. zmag are nine consecutive values of one type: one block, in double then rounded to
        # float32 (as the per-frame path's Python floats).
        values = block.view(spec.block_type).astype(np.float64)
        values *= np.array([acc_scale] * 3 + [gyro_scale] * 3 + [mag_scale] * 3)
        out["acc"] = values[:, 0:3]
        out["gyro"] = values[:, 3:6]
        if any_field:
            out["mag"] = values[:, 6:9] if _ALL(field) else np.where(field[:, None], values[:, 6:9], np.nan)
        elif self._mag:
            out["mag"] = np.nan
        return out, field

    def _check_window(self, pos: int) -> _FastWindow | None:
        """Frame slots of the length announced at ``pos`` checked at once (header, CRC, IMU id): the
        window, or None when no frame of the chosen source can start there."""
        buf = self._buf
        key = self._key
        assert key is not None
        name, system, component, imu_id = key
        v1 = buf[pos] == STX_V1
        avail = len(buf) - pos
        if avail < HEADER_V2:
            return None
        spec = _fast_spec(self._dialect, name)
        plen = buf[pos + 1]
        size = (HEADER_V1 if v1 else HEADER_V2) + plen + 2
        count = min(avail // size, _FAST_WINDOW)
        if count < 1 or plen > spec.size:
            return None
        nxt, at = pos + size, 5 if v1 else 7  # the next slot; where a frame's message id (its low byte) is
        if count > 1 and (buf[nxt] != buf[pos] or buf[nxt + 1] != plen or buf[nxt + at] != buf[pos + at]):
            # A lone frame of the source between others (a board's IMU instances interleaved: SCALED_IMU,
            # SCALED_IMU2, SCALED_IMU3, ...): the per-frame path takes it for a third of what a window's
            # arrays cost.
            return None
        kind = (v1, plen, system, component, name)
        lay = _LAYOUTS.get(kind)
        if lay is None:
            lay = _LAYOUTS[kind] = _FrameLayout(v1, plen, system, component, spec)
        frames = np.frombuffer(buf, dtype=lay.dtype, count=count, offset=pos)
        ok = (frames["h8"] & lay.mask8) == lay.expect8
        if not v1:
            ok &= frames["h2"] == lay.expect2
        n = count if _ALL(ok) else int(np.argmin(ok))
        if n < 1:
            return None
        if n < count:
            frames = frames[:n]
        crc = np.bitwise_xor.reduce(lay.table.take(frames["crc_bytes"] + lay.offsets), axis=1) ^ lay.base
        good = crc == frames["crc"]
        if lay.trimmed:  # MAVLink 2 trims the payload's trailing zeros: put them back
            msg = np.zeros(n, dtype=spec.dtype)
            msg.view(np.uint8).reshape(n, spec.size)[:, :plen] = frames["payload"]
        else:
            msg = frames["payload"].copy()
        del frames  # the window keeps no view of the buffer
        crc_bad = [] if _ALL(good) else (~good).nonzero()[0].tolist()
        bad = crc_bad
        if spec.has_id:
            ours = msg["id"] == imu_id
            if not _ALL(ours):
                good &= ours
                bad = np.flatnonzero(~good).tolist()
        quiet, resyncs = [], []
        for slot in crc_bad:
            found = self._quiet_resyncs(pos + slot * size, size) if slot + 1 < n else 0
            if found:
                quiet.append(slot)
                resyncs.append(found)
        if quiet:
            stepped = set(quiet)
            bad = [slot for slot in bad if slot not in stepped]
        return _FastWindow(pos, size, n, bad, crc_bad, quiet, resyncs, msg)

    def _quiet_resyncs(self, pos: int, size: int) -> int:
        """The resyncs the per-frame path counts for the bad frame of ``size`` bytes at ``pos`` (another
        frame right after it) when no start inside it announces a frame (:meth:`_frame_length` 0 at each:
        MAVLink 2 with unknown incompatibility flags), so that the path reads no length there nor waits for
        more bytes: one for the frame and one a start. 0 when a start inside may be read as a frame."""
        starts = [m.start() for m in _STX.finditer(self._buf, pos + 1, pos + size)]
        return 0 if any(self._frame_length(at) for at in starts) else 1 + len(starts)

    # -------------------------------------------------------------- IMU messages

    def _imu_row(self, msg: Any, name: str) -> tuple | None:
        """The sample of an IMU message of the chosen source; None for another source's;
        ``_UNDATED`` when its time_boot_ms steps back past the stream's first."""
        header = msg.get_header()
        imu_id = msg.id if "id" in msg.get_fieldnames() else 0  # SCALED_IMU* have no IMU id field
        key = (name, header.srcSystem, header.srcComponent, imu_id)
        label = f"{name} {key[1]}/{key[2]} id {key[3]}"
        self.sources_seen[label] = self.sources_seen.get(label, 0) + 1
        if self._key is None and self._streams is None and (self.source is None or self.source == name):
            self._key = key
        if key != self._key:
            return None if self._streams is None else self._instance_row(msg, name, key)
        return self._row(msg, name, self)

    def _instance_row(self, msg: Any, name: str, key: tuple) -> tuple | None:
        """With :meth:`decode_instances`: a sample of another instance's stream goes to it (``_ROUTED``);
        instance 0's first message fixes the single stream's key; None for another board's message or
        another message of an instance that has one."""
        assert self._streams is not None
        board = (key[1], key[2])
        if self._board is None:
            self._board = board
        if board != self._board:
            return None
        instance = mavlink_instance(name, key[3])
        if instance == 0:
            if self._key is not None:
                return None
            self._key = key
            return self._row(msg, name, self)
        stream = self._streams.get(instance)
        if stream is None:
            stream = self._streams[instance] = _InstanceStream(key)
        elif stream.key != key:
            return None
        row = self._row(msg, name, stream)
        if row is _UNDATED:
            return row
        stream.rows.append(row)
        return _ROUTED

    def _row(self, msg: Any, name: str, stream: MavlinkDecoder | _InstanceStream) -> tuple:
        """The sample of an IMU message of ``stream`` (the decoder itself for the single stream, whose state
        the fast path shares); ``_UNDATED`` when its time_boot_ms steps back past the stream's first."""
        if name == "HIGHRES_IMU":
            acc = (msg.xacc, msg.yacc, msg.zacc)
            gyro = (msg.xgyro, msg.ygyro, msg.zgyro)
            temp = float(msg.temperature)
            t_us = int(msg.time_usec)
            has_field = (int(msg.fields_updated) & HIGHRES_MAG_UPDATED) == HIGHRES_MAG_UPDATED
            mag_scale = UT_PER_GAUSS
        else:
            if name == "RAW_IMU":
                acc_scale, gyro_scale = self.raw_acc_scale, self.raw_gyro_scale
                t_us = int(msg.time_usec)
            else:
                acc_scale, gyro_scale = MILLI_G, 1e-3
                boot_ms = _unwrap_boot_ms(stream, int(msg.time_boot_ms))
                if boot_ms is None:
                    return _UNDATED
                t_us = boot_ms * 1000
            acc = (msg.xacc * acc_scale, msg.yacc * acc_scale, msg.zacc * acc_scale)
            gyro = (msg.xgyro * gyro_scale, msg.ygyro * gyro_scale, msg.zgyro * gyro_scale)
            cdeg = getattr(msg, "temperature", 0)
            temp = cdeg * 0.01 if cdeg else math.nan
            has_field = (msg.xmag, msg.ymag, msg.zmag) != (0, 0, 0)
            mag_scale = UT_PER_MILLIGAUSS
        seq = stream._count & 0xFFFFFFFF
        stream._count += 1
        if not has_field:
            return (seq, t_us, acc, gyro, temp, _NAN3)
        stream._mag = True
        field = (msg.xmag * mag_scale, msg.ymag * mag_scale, msg.zmag * mag_scale)
        return (seq, t_us, acc, gyro, temp, field)


class _InstanceStream:
    """The state of one more IMU instance's samples (what the decoder keeps for its single stream): the
    source's key, the sample count, the unwrapped time_boot_ms, whether a field came, the rows of a feed."""

    __slots__ = ("key", "_count", "_boot_ms", "_mag", "rows")

    def __init__(self, key: tuple) -> None:
        self.key = key
        self._count = 0
        self._boot_ms: int | None = None
        self._mag = False
        self.rows: list[tuple] = []


def _unwrap_boot_ms(stream: MavlinkDecoder | _InstanceStream, ms: int) -> int | None:
    """time_boot_ms of ``stream`` unwrapped past 2^32 ms by a signed step from its last sample's: a frame
    dated a little earlier (a replay) steps back, not 49.7 days forward. None: it would fall before the
    stream's clock zero."""
    if stream._boot_ms is None:
        stream._boot_ms = ms
        return ms
    unwrapped = stream._boot_ms + (((ms - stream._boot_ms + 2**31) & 0xFFFFFFFF) - 2**31)
    if unwrapped < 0:
        return None
    stream._boot_ms = unwrapped
    return unwrapped


# ---------------------------------------------------------------------------------- fast path


class _FastWindow:
    """Frame slots of one length from ``base`` checked at once; ``bad`` lists the slots (below
    ``checked``) that are not good frames of the source, and the per-frame path takes, ``crc_bad``
    those whose CRC failed. ``quiet`` are bad slots a run steps over: a CRC failed, another slot after
    it, and no start inside that the per-frame path would read as a frame (only MAVLink 2 starts with
    unknown incompatibility flags: ``MavlinkDecoder._quiet_resyncs``), so that path would count a CRC
    error, the frame's bytes as garbage and ``quiet_resyncs`` resyncs, nothing else. Runs from any slot
    are then slices, so a damaged frame costs the next run no second check. Copies of the payloads: no
    buffer view."""

    __slots__ = ("base", "size", "checked", "bad", "crc_bad", "quiet", "quiet_resyncs", "msg", "out", "field")

    def __init__(self, base: int, size: int, checked: int, bad: list[int], crc_bad: list[int],
                 quiet: list[int], quiet_resyncs: list[int], msg: np.ndarray) -> None:
        self.base, self.size, self.checked, self.bad, self.crc_bad = base, size, checked, bad, crc_bad
        self.quiet, self.quiet_resyncs, self.msg = quiet, quiet_resyncs, msg
        # Samples of every slot (HIGHRES_IMU, RAW_IMU: no state but seq), made at the first run, and
        # which slots carry a field (None: none does); runs of a window are slices of these.
        self.out: np.ndarray | None = None
        self.field: np.ndarray | None = None

    def crc_failed(self, pos: int) -> bool:
        """Whether ``pos`` is a checked slot whose frame's CRC is wrong (known without a second look)."""
        if not self.crc_bad or not self.covers(pos):
            return False
        i = (pos - self.base) // self.size
        k = bisect_left(self.crc_bad, i)
        return k < len(self.crc_bad) and self.crc_bad[k] == i

    def covers(self, pos: int) -> bool:
        """Whether ``pos`` is a checked slot."""
        off = pos - self.base
        return off >= 0 and off % self.size == 0 and off // self.size < self.checked


_FAST_WINDOW = 512  # frames a fast run checks at once
_ALL = np.logical_and.reduce  # ndarray.all without its Python wrapper: a few microseconds a read
_ANY = np.logical_or.reduce
_EMPTY_MAG = np.zeros(0, MAG_SAMPLE_DTYPE)
_STRUCT_TYPES = {"Q": "<u8", "q": "<i8", "I": "<u4", "i": "<i4", "H": "<u2", "h": "<i2", "B": "u1",
                 "b": "i1", "f": "<f4", "d": "<f8"}


class _FastSpec:
    """An IMU message for the fast path: its full payload as a record, its CRC extra."""

    def __init__(self, msgtype: Any) -> None:
        fmt = msgtype.unpacker.format
        fmt = fmt.decode() if isinstance(fmt, bytes) else fmt
        codes = fmt.lstrip("<")
        names = list(msgtype.ordered_fieldnames)
        if len(codes) != len(names) or any(c not in _STRUCT_TYPES for c in codes):
            raise ValueError(f"{msgtype.msgname}: no fast path for the format {fmt}")
        self.dtype = np.dtype([(n, _STRUCT_TYPES[c]) for n, c in zip(names, codes, strict=True)])
        self.size = msgtype.unpacker.size
        assert self.dtype.itemsize == self.size
        self.crc_extra = msgtype.crc_extra
        self.has_id = "id" in msgtype.fieldnames
        self.has_time_usec = "time_usec" in msgtype.fieldnames
        first = names.index("xacc")
        if names[first : first + 9] != [a + q for q in ("acc", "gyro", "mag") for a in "xyz"]:
            raise ValueError(f"{msgtype.msgname}: no fast path, its axes are not one block")
        fields: Any = self.dtype.fields
        self.block_at = int(fields["xacc"][1])
        self.block_type = self.dtype["xacc"]
        self.msg_id = msgtype.id


class _FrameLayout:
    """Frames of one kind (MAVLink 1 or 2, payload length, system, component, message) read as records:
    ``h8`` (bytes 0-7) and, MAVLink 2, ``h2`` (8-9) the header words a frame of a run has (masked: all
    but the sequence and compatibility flags), ``crc_bytes`` the bytes under the CRC, ``crc`` the CRC
    sent, ``payload`` the message (its bytes when trimmed); the CRC as per-byte tables
    (:func:`_crc_tables`)."""

    def __init__(self, v1: bool, plen: int, system: int, component: int, spec: _FastSpec) -> None:
        header = HEADER_V1 if v1 else HEADER_V2
        mid = spec.msg_id
        expect = {0: STX_V1, 1: plen, 3: system, 4: component, 5: mid & 0xFF} if v1 else \
            {0: STX_V2, 1: plen, 2: 0, 5: system, 6: component, 7: mid & 0xFF}
        self.mask8 = np.uint64(sum(0xFF << 8 * i for i in expect))
        self.expect8 = np.uint64(sum(v << 8 * i for i, v in expect.items()))
        self.expect2 = np.uint16(mid >> 8)  # MAVLink 2: the message id's upper bytes
        self.trimmed = plen < spec.size
        fields = {"h8": ("<u8", 0), "crc_bytes": (("u1", (header - 1 + plen,)), 1),
                  "payload": (("u1", (plen,)) if self.trimmed else spec.dtype, header),
                  "crc": ("<u2", header + plen)}
        if not v1:
            fields["h2"] = ("<u2", 8)
        self.dtype = np.dtype({"names": list(fields), "formats": [f for f, _ in fields.values()],
                               "offsets": [at for _, at in fields.values()], "itemsize": header + plen + 2})
        self.base, self.table, offsets = _crc_tables(header, plen, spec.crc_extra)
        # uint8 + uint16 stays 16 bits: a third of the intp sum's bytes
        self.offsets = offsets.astype(np.uint16 if len(self.table) <= 1 << 16 else np.intp)


_SPECS: dict[str, _FastSpec] = {}
_LAYOUTS: dict[tuple[bool, int, int, int, str], _FrameLayout] = {}  # by (v1, plen, system, component, name)


def _fast_spec(dialect: Any, name: str) -> _FastSpec:
    spec = _SPECS.get(name)
    if spec is None:
        msgtype = next(t for t in dialect.mavlink_map.values() if t.msgname == name)
        spec = _SPECS[name] = _FastSpec(msgtype)
    return spec


_X25_TABLE = np.zeros(256, dtype=np.uint16)
for _b in range(256):
    _t = _b ^ ((_b << 4) & 0xFF)
    _X25_TABLE[_b] = ((_t << 8) ^ (_t << 3) ^ (_t >> 4)) & 0xFFFF


def _x25_rows(rows: np.ndarray) -> np.ndarray:
    """The X.25 CRC (MAVLink's CRC-16/MCRF4XX) of every row of a 2-D uint8 array, a column at a time."""
    crc = np.full(rows.shape[0], 0xFFFF, dtype=np.uint16)
    for col in range(rows.shape[1]):
        crc = (crc >> 8) ^ _X25_TABLE[(crc ^ rows[:, col]) & 0xFF]
    return crc


_X25_LIST = [int(v) for v in _X25_TABLE]
_REVERSED_BITS = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))  # each byte's bits reversed


def _x25(data: bytes | bytearray) -> int:
    """The X.25 CRC of ``data`` (as pymavlink's ``x25crc``), in C.

    X.25 (CRC-16/MCRF4XX) is CRC-16/CCITT reflected, with an init (0xFFFF) that reads the same
    reversed: so it is the CCITT CRC of the bytes with their bits reversed, itself reversed, and the
    standard library's ``binascii.crc_hqx`` computes that in C (checked against :func:`_x25_bytewise`).
    """
    crc = binascii.crc_hqx(bytes(data).translate(_REVERSED_BITS), 0xFFFF)
    return (_REVERSED_BITS[crc & 0xFF] << 8) | _REVERSED_BITS[crc >> 8]


def _x25_bytewise(data: bytes | bytearray) -> int:
    """The X.25 CRC a table look-up a byte: the reference of :func:`_x25`."""
    crc = 0xFFFF
    table = _X25_LIST
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


_CRC_TABLES: dict[tuple[int, int, int], tuple[int, np.ndarray, np.ndarray]] = {}


def _crc_tables(header: int, plen: int, crc_extra: int) -> tuple[int, np.ndarray, np.ndarray]:
    """The X.25 CRC of a frame (the bytes after STX, then the CRC extra) as a sum of per-byte tables.

    The CRC is affine in the message bits: crc(m) = crc(0 + extra) ^ XOR_i T[i, m_i], with
    T[i, v] = crc(e_i(v) + 0) ^ crc(0) (e_i(v): byte v at position i, the extra's byte zero). A run
    of frames is then one table look-up per byte and an XOR reduction, for all frames at once.
    """
    key = (header, plen, crc_extra)
    found = _CRC_TABLES.get(key)
    if found is None:
        n = header - 1 + plen  # the bytes after STX under the CRC
        rows = np.zeros((n, 256, n + 1), dtype=np.uint8)
        for i in range(n):
            rows[i, :, i] = np.arange(256)
        zero = np.zeros((1, n + 1), dtype=np.uint8)
        tables = _x25_rows(rows.reshape(-1, n + 1)).reshape(n, 256) ^ _x25_rows(zero)[0]
        zero[0, n] = crc_extra
        found = (int(_x25_rows(zero)[0]), tables.ravel(), (np.arange(n) * 256).astype(np.intp))
        _CRC_TABLES[key] = found
    return found


def _without_mag(samples: np.ndarray) -> np.ndarray:
    """``MAG_SAMPLE_DTYPE`` samples as ``SAMPLE_DTYPE`` (a stream that has carried no field)."""
    # SAMPLE_DTYPE is MAG_SAMPLE_DTYPE's first bytes: a copy of those.
    raw = samples.view(np.uint8).reshape(len(samples), MAG_SAMPLE_DTYPE.itemsize)
    return np.ascontiguousarray(raw[:, : SAMPLE_DTYPE.itemsize]).view(SAMPLE_DTYPE)[:, 0]


# ---------------------------------------------------------------------------------- encoder


def _i16(values) -> list[int]:
    return [max(-32768, min(32767, round(float(v)))) for v in values]


def encode_samples(samples: np.ndarray, message: str = "HIGHRES_IMU", system: int = 1, component: int = 1,
                   mavlink1: bool = False, heartbeat_every: int = 0, imu_id: int = 0) -> bytes:
    """MAVLink frames of one IMU message per ``SAMPLE_DTYPE`` record, as an autopilot sends them:
    with the field of ``MAG_SAMPLE_DTYPE`` records (gauss or mgauss), else none (zeros, not flagged).

    ``heartbeat_every`` > 0 puts a HEARTBEAT before every that many samples (and the first);
    ``imu_id`` is the ``id`` of HIGHRES_IMU and RAW_IMU (the SCALED_IMU messages have none).
    """
    if message not in IMU_MESSAGES:
        raise ValueError(f"unknown MAVLink IMU message {message!r}; use one of {', '.join(IMU_MESSAGES)}")
    dialect = load_dialect()
    mav = dialect.MAVLink(None, srcSystem=system, srcComponent=component)
    out = bytearray()

    def pack(msg: Any) -> None:
        out.extend(msg.pack(mav, force_mavlink1=mavlink1))
        mav.seq = (mav.seq + 1) % 256

    with_mag = has_mag(samples)
    for i, s in enumerate(np.asarray(samples, dtype=MAG_SAMPLE_DTYPE if with_mag else SAMPLE_DTYPE)):
        if heartbeat_every and i % heartbeat_every == 0:
            pack(mav.heartbeat_encode(dialect.MAV_TYPE_QUADROTOR, dialect.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                      0, 0, 0))
        acc, gyro, temp, t_us = s["acc"], s["gyro"], float(s["temp"]), int(s["t_us"])
        known = math.isfinite(temp)
        field = s["mag"].astype(float) if with_mag and np.isfinite(s["mag"]).all() else None
        if message == "HIGHRES_IMU":
            updated = 0x1FFF if known else 0x0FFF  # bit 12: temperature
            gauss = (0.0, 0.0, 0.0) if field is None else tuple(field / UT_PER_GAUSS)
            if field is None:
                updated &= ~HIGHRES_MAG_UPDATED
            pack(mav.highres_imu_encode(t_us, *map(float, acc), *map(float, gyro), *gauss, 1013.25,
                                        0.0, 0.0, temp if known else 0.0, updated, imu_id))
            continue
        a = _i16(acc / MILLI_G)
        g = _i16(gyro * 1000.0)
        m = [0, 0, 0] if field is None else _i16(field / UT_PER_MILLIGAUSS)
        cdeg = (round(temp * 100) or 1) if known else 0  # 0 means "no temperature"; 0.00 degC is sent as 1
        if message == "RAW_IMU":
            pack(mav.raw_imu_encode(t_us, *a, *g, *m, imu_id, cdeg))
        else:
            encode = getattr(mav, message.lower() + "_encode")
            pack(encode((t_us // 1000) & 0xFFFFFFFF, *a, *g, *m, cdeg))
    return bytes(out)

