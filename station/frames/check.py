"""Checking a frame description against a unit (``imu-station frame check``): decoded values, frame and
error rates, and the values that look wrong, so a user gets scales and byte order right in minutes.

:class:`FrameCheck` keeps the latest samples and the link's counters; :meth:`FrameCheck.report`
summarises them and flags what a unit on a bench should not show:

- lying still (``|a|`` steady within 1 %, whatever its scale), ``|a|`` far from g: a wrong
  accelerometer scale (the factor to apply is named), or g units left unconverted; moving, an
  ``|a|`` no hand can give (below g/2 or above 2 g on average) is flagged the same way;
- lying still, rates far from zero: a wrong gyroscope scale or degrees left unconverted;
- values that jump by a large part of their range from one sample to the next: the byte order,
  or a field at the wrong offset;
- a temperature outside -40..125 degC, and no frame at all (the sync, length or checksum);
- most frames failing the description's checksum: the checksum that fits them instead (the
  decoder's diagnosis, ``protocols.frame_checksum_fit``); the values of the few frames that passed
  by chance are then not judged (their jumps are the frames lost between them, not the byte order).

Rates and the duration count the samples lost, from the counter (``seq``, or the clock's steps): a
unit that sent 872 frames of which 866 failed ran 872 periods, not 6.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from drivers import LinkStats, open_device
from protocols.base import SAMPLE_DTYPE, StreamDecoderBase
from protocols.units import STANDARD_GRAVITY

WINDOW = 2000  # latest samples the values are taken over
STILL_SPREAD = 0.01  # of |a|: a steadier |a| (robust spread) means the unit lies still
ACC_TOLERANCE = 0.05  # of g
GYRO_ZERO = 0.1  # rad/s: a still unit's rates are within this of zero (a MEMS bias is far less)
JUMPY = 0.25  # a value whose median step exceeds this share of its spread jumps at random
COLUMNS = ("seq", "t", "ax", "ay", "az", "gx", "gy", "gz", "temp")


@dataclass
class ValueRow:
    """One value's latest, mean, spread and range over the window."""

    name: str
    last: float
    mean: float
    std: float
    low: float
    high: float


@dataclass
class CheckReport:
    """What :meth:`FrameCheck.report` found."""

    frames: int
    errors: int
    garbage_bytes: int
    seconds: float
    rows: list[ValueRow] = field(default_factory=list)
    acc_norm: float = float("nan")
    still: bool = False
    flags: list[str] = field(default_factory=list)
    lost: int = 0

    @property
    def frame_rate(self) -> float:
        """Good frames a second."""
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    @property
    def sent_rate(self) -> float:
        """Samples a second the unit sent: the good frames and those lost, by the counter."""
        return (self.frames + self.lost) / self.seconds if self.seconds > 0 else 0.0

    @property
    def error_rate(self) -> float:
        """Damaged frames a second of wall time."""
        return self.errors / self.seconds if self.seconds > 0 else 0.0


def _columns(samples: np.ndarray) -> dict[str, np.ndarray]:
    return {"seq": samples["seq"].astype(np.float64), "t": samples["t_us"].astype(np.float64) / 1e6,
            **{n: samples["acc"][:, i].astype(np.float64) for i, n in enumerate(("ax", "ay", "az"))},
            **{n: samples["gyro"][:, i].astype(np.float64) for i, n in enumerate(("gx", "gy", "gz"))},
            "temp": samples["temp"].astype(np.float64)}


class FrameCheck:
    """The latest samples of a unit and its counters, summarised on demand."""

    def __init__(self, window: int = WINDOW):
        self.window = window
        self._samples = np.zeros(0, dtype=SAMPLE_DTYPE)

    def add(self, samples: np.ndarray) -> None:
        """Keep ``samples`` (a batch of ``SAMPLE_DTYPE``), dropping the oldest beyond the window.

        Parameters
        ----------
        samples : numpy.ndarray
            The batch just decoded.
        """
        if len(samples):
            self._samples = np.concatenate([self._samples, samples])[-self.window :]

    def report(self, frames: int, errors: int, garbage_bytes: int, seconds: float, lost: int = 0,
               problem: str | None = None) -> CheckReport:
        """The values over the window and the flags they raise.

        Parameters
        ----------
        frames, errors, garbage_bytes : int
            The link's counters so far: good frames, damaged frames, bytes skipped.
        seconds : float
            Time the check covers (wall clock, or the unit's for a file), for the rates.
        lost : int
            Samples missing from the counter.
        problem : str, optional
            The decoder's diagnosis of the stream as a whole (most frames fail their checksum): the
            one flag, the values then being a few frames that passed by chance.

        Returns
        -------
        CheckReport
        """
        out = CheckReport(frames, errors, garbage_bytes, seconds, lost=lost)
        s = self._samples
        if problem:
            out.flags.append(problem)
        if not len(s):
            if problem:
                return out
            out.flags.append("no frame decoded: check the sync, the length and the checksum (imu-station "
                             "frame guess proposes them from a raw capture)")
            return out
        with np.errstate(invalid="ignore", over="ignore"):
            for name, values in _columns(s).items():
                finite = values[np.isfinite(values)]
                if not len(finite):
                    out.rows.append(ValueRow(name, float(values[-1]), *(float("nan"),) * 4))
                    continue
                out.rows.append(ValueRow(name, float(values[-1]), float(finite.mean()), float(finite.std()),
                                         float(finite.min()), float(finite.max())))
            flags = _flags(s, out)
            if not problem:
                out.flags += flags
        return out


def _flags(s: np.ndarray, out: CheckReport) -> list[str]:
    flags = []
    acc = s["acc"].astype(np.float64)
    gyro = s["gyro"].astype(np.float64)
    norm = np.linalg.norm(acc, axis=1)
    out.acc_norm = float(np.nanmean(norm))
    median = float(np.nanmedian(norm))
    spread = 1.4826 * float(np.nanmedian(np.abs(norm - median)))  # a stray frame does not make it move
    out.still = len(s) >= 10 and median > 0 and spread < STILL_SPREAD * median
    rows = {r.name: r for r in out.rows}
    for name in ("ax", "ay", "az", "gx", "gy", "gz"):
        values = _columns(s)[name]
        spread = float(np.nanmax(values) - np.nanmin(values)) if len(values) > 2 else 0.0
        if spread > 0 and float(np.nanmedian(np.abs(np.diff(values)))) > JUMPY * spread \
                and abs(rows[name].mean) < rows[name].std:
            flags.append(f"{name} jumps at random between samples (median step "
                         f"{float(np.nanmedian(np.abs(np.diff(values)))):.3g} of a {spread:.3g} range): "
                         "the byte order or the field's offset?")
    ratio = out.acc_norm / STANDARD_GRAVITY
    if (out.still and abs(ratio - 1.0) > ACC_TOLERANCE) or not 0.5 <= ratio <= 2.0:
        hint = ""
        if abs(out.acc_norm - 1.0) < ACC_TOLERANCE:
            hint = ": values in g; multiply the accelerometer scales by 9.80665"
        elif ratio > 0:
            hint = f": multiply the accelerometer scales by {1 / ratio:.4g}"
        state = "while the unit lies still" if out.still else "on average"
        flags.append(f"|a| is {out.acc_norm:.4g} m/s^2 {state}, {ratio:.3g} g{hint}")
    if out.still:
        mean_rate = np.abs(np.nanmean(gyro, axis=0))
        if float(mean_rate.max()) > GYRO_ZERO:
            axis = "xyz"[int(mean_rate.argmax())]
            flags.append(f"g{axis} averages {float(mean_rate.max()):.3f} rad/s while the unit lies still: "
                         "the gyroscope scale (rad/s per count; deg/s need x0.01745) or its offset?")
    temp = rows["temp"]
    if np.isfinite(temp.mean) and not -40.0 <= temp.mean <= 125.0:
        flags.append(f"temp averages {temp.mean:.1f} degC, outside -40..125: its scale or offset?")
    return flags


def check_bytes(decoder: StreamDecoderBase, raw: bytes, chunk: int = 4096) -> CheckReport:
    """Check a raw capture: decode it in chunks as a port delivers them; rates are per second of the
    unit's clock (the file has no wall time).

    Parameters
    ----------
    decoder : StreamDecoderBase
        The description's decoder (``station.frames.reader.load_decoder``).
    raw : bytes
        The capture's bytes.
    chunk : int
        Bytes per ``feed``.

    Returns
    -------
    CheckReport
    """
    check = FrameCheck()
    first: np.ndarray | None = None  # the first and last samples decoded
    last: np.ndarray | None = None
    for pos in range(0, len(raw), chunk):
        samples = decoder.feed(raw[pos : pos + chunk]).samples
        check.add(samples)
        if len(samples):
            first = samples[0] if first is None else first
            last = samples[-1]
    check.add(decoder.flush().samples)
    stats = decoder.stats
    seconds, lost = 0.0, 0
    if first is not None and last is not None:
        span = (float(last["t_us"]) - float(first["t_us"])) / 1e6
        # the counter says how many samples the unit sent from the first good frame to the last
        sent = max(int(last["seq"]) - int(first["seq"]) + 1, stats.frames)
        lost = sent - stats.frames
        seconds = span * sent / (sent - 1) if sent > 1 else 0.0
    return check.report(stats.frames, stats.errors, stats.garbage_bytes, seconds, lost,
                        getattr(decoder, "problem", None))


def watch_port(port: str, protocol: str, baudrate: int, duration_s: float | None, every_s: float,
               show: Callable[[CheckReport], None]) -> CheckReport:
    """Read a unit and hand a fresh report to ``show`` every ``every_s`` until ``duration_s`` (or Ctrl-C).

    Parameters
    ----------
    port, protocol : str
        As ``--port`` and ``--protocol`` give them (``frame:FILE.yaml``).
    baudrate : int
        Line speed.
    duration_s : float, optional
        How long to watch; None until interrupted.
    every_s : float
        Seconds between reports.
    show : callable
        Receives each report (the command draws it).

    Returns
    -------
    CheckReport
        The last report.

    Raises
    ------
    DriverError
        The port cannot be opened or is lost.
    """
    check = FrameCheck()
    start = time.monotonic()
    with open_device(port, protocol=protocol, baudrate=baudrate) as device:
        report = None
        next_show = start + every_s
        try:
            while duration_s is None or time.monotonic() - start < duration_s:
                check.add(device.read(timeout=min(every_s, 0.1)))
                if time.monotonic() >= next_show:
                    report = _port_report(check, device.stats, start, _problem(device))
                    show(report)
                    next_show += every_s
        except KeyboardInterrupt:
            pass
        report = _port_report(check, device.stats, start, _problem(device))
    show(report)
    return report


def _problem(device: object) -> str | None:
    # a serial device reports its frame decoder's diagnosis; other devices have none
    return getattr(device, "decoder_problem", None)


def _port_report(check: FrameCheck, stats: LinkStats, start: float, problem: str | None) -> CheckReport:
    return check.report(stats.samples, stats.errors, stats.garbage_bytes, time.monotonic() - start,
                        stats.lost, problem)
