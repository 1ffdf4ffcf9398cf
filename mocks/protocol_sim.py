"""``sim://`` pyserial URL handler: the simulated unit in-process, as a serial port.

After ``mocks.register_sim_url()``, ``serial.serial_for_url("sim://?seed=3&rate=200")`` returns
a port whose bytes come from a :class:`mocks.device.SimDevice`, paced by the wall clock on
the same absolute schedule as the pty server (sample k when its device time has passed since
the port was opened). Writes are host commands.

URL options (all optional)::

    seed=N            unit, noise and scenario seed (default 0)
    rate=HZ           sample rate at power-up (default 200)
    scenario=NAME     still | chamber | six-position | twelve-position | six-position-static | handheld |
                      mag-sphere | mag-desk
    t_min=C t_max=C rate_c_per_min=R soak_s=S
                      the chamber scenario's programme: from t_min up to t_max and back at R degC/min,
                      soaking S s at each end (default -20, 60, 1, 600: 3 h), then held at t_min
    loop=0|1          repeat the scenario (default: per scenario)
    mag=1             a nine-axis unit: a magnetometer (hard and soft iron, rotated against the
                      accelerometer, mocks.magnetometer) sending IMU_MAG_SAMPLE frames
    field=UT dip=DEG declination=DEG
                      the local Earth field (default 50 uT, dip 60, declination 0; implies mag=1);
                      scenario=mag-sphere or mag-desk turns the unit for a magnetometer calibration
    heading=DEG       azimuth of the rig's x axis from true north (default 0): where the horizontal
                      field and the Earth rate point in the rig's frame
    grade=mems|tactical   intrinsics of the random unit (default mems)
    ideal=1           an ideal unit (identity, no noise) instead of a random one
    speed=X           device time runs X times faster than the wall clock (default 1)
    record=1          keep intact frames and sent samples (``port.injector``, ``port.sent()``)
    faults=SPEC       a FaultSpec string, e.g. faults=garbage=0.01,drop=0.001 (URL-encode it
                      if your URL tool needs to), or the fault names directly as options:
                      garbage=P bitflip=P truncate=P drop=P stall=P stall_s=S garbage_max=N
                      disconnect_bytes=N disconnect_s=S fault_seed=N

``port.device`` is the :class:`SimDevice` (drive it live with ``set_pose``/``rotate``).
A disconnect fault makes ``read``/``write`` raise ``SerialException`` once the bytes sent
before it have been read, as a USB adapter pulled out.
"""

from __future__ import annotations

import numbers
import threading
import time
import urllib.parse
from dataclasses import dataclass

import numpy as np
from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes

from mocks.chamber import SCENARIO_DEFAULTS, ChamberSweep, sweep_from_options
from mocks.device import MAX_RATE_HZ, MIN_RATE_HZ, SCENARIOS, SimDevice
from mocks.faults import FaultInjector, FaultSpec
from mocks.magnetometer import MAG_OPTIONS, MagTruth, mag_from_options
from mocks.truth import UnitTruth

_FAULT_KEYS = {"garbage", "bitflip", "truncate", "drop", "stall", "stall_s", "garbage_max",
               "disconnect_bytes", "disconnect_s", "disconnect_after_bytes", "disconnect_after_s"}
_MAX_POLL_S = 0.05


@dataclass
class SimOptions:
    """The options of a ``sim://`` URL (see the module docstring)."""

    seed: int = 0
    rate: float = 200.0
    scenario: str = "still"
    loop: bool | None = None
    grade: str = "mems"
    ideal: bool = False
    speed: float = 1.0
    record: bool = False
    faults: FaultSpec | None = None
    chamber: ChamberSweep | None = None
    mag: MagTruth | None = None
    heading: float = 0.0


MAX_SEED = 2**32 - 1  # numpy's generators take seeds of 0..2^32-1


def parse_sim_url(url: str) -> SimOptions:
    """Options of a ``sim://`` URL; raises ValueError naming the bad option.

    Parameters
    ----------
    url : str

    Returns
    -------
    SimOptions
    """
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        raise ValueError(f"expected a URL of the form sim://?seed=N&rate=HZ..., got {url!r}")
    options = SimOptions()
    fault_parts: list[str] = []
    chamber_options: dict[str, str] = {}
    mag_options: dict[str, str] = {}
    for key, values in urllib.parse.parse_qs(parts.query, keep_blank_values=True).items():
        value = values[-1]
        try:
            if key == "seed":
                options.seed = int(value)
                if not 0 <= options.seed <= MAX_SEED:
                    raise ValueError(f"give a seed in 0..{MAX_SEED}")
            elif key == "rate":
                options.rate = float(value)
                if not MIN_RATE_HZ <= options.rate <= MAX_RATE_HZ:
                    raise ValueError(f"give a rate in {MIN_RATE_HZ}..{MAX_RATE_HZ} Hz")
            elif key == "scenario":
                if value not in SCENARIOS:
                    raise ValueError(f"unknown scenario {value!r}; known: {', '.join(SCENARIOS)}")
                options.scenario = value
            elif key in ("loop", "ideal", "record"):
                setattr(options, key, value not in ("0", "false", "no", ""))
            elif key == "grade":
                options.grade = value
            elif key == "speed":
                speed = float(value)
                if not 0 < speed < float("inf"):
                    raise ValueError("give a finite speed above 0")
                options.speed = speed
            elif key == "faults":
                fault_parts.append(value)
            elif key == "fault_seed":
                fault_parts.append(f"seed={int(value)}")
            elif key in _FAULT_KEYS:
                fault_parts.append(f"{key}={value}")
            elif key in SCENARIO_DEFAULTS:
                chamber_options[key] = value
            elif key in MAG_OPTIONS:
                mag_options[key] = value
            elif key == "heading":
                options.heading = float(value)
                if not -360.0 <= options.heading <= 360.0:
                    raise ValueError("give a heading in -360..360 deg")
            else:
                raise ValueError("unknown option")
        except ValueError as exc:
            raise ValueError(f"sim:// option {key}={value!r}: {exc}") from None
    if fault_parts:
        options.faults = FaultSpec.parse(",".join(fault_parts))
    try:
        options.mag = mag_from_options(mag_options, options.seed)
    except ValueError as exc:
        raise ValueError(f"sim:// magnetometer: {exc}") from None
    if options.scenario == "chamber":
        try:
            options.chamber = sweep_from_options(chamber_options)
        except ValueError as exc:
            raise ValueError(f"sim:// chamber scenario: {exc}") from None
    elif chamber_options:
        raise ValueError(f"sim:// options {', '.join(chamber_options)} apply to scenario=chamber only")
    return options


class Serial(SerialBase):
    """A pyserial port backed by a simulated device (see the module docstring for the URL)."""

    is_open: bool  # set by SerialBase (untyped)

    def __init__(self, *args: object, **kwargs: object):
        self.device: SimDevice | None = None
        self.injector: FaultInjector | None = None
        self.speed = 1.0
        self._record = False
        self._sent: list[np.ndarray] = []
        self._rx = bytearray()
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self._t0 = 0.0
        self._hold_until = 0.0
        self._disconnect_s: float | None = None
        super().__init__(*args, **kwargs)

    # --- SerialBase interface --------------------------------------------------------------

    def open(self) -> None:
        """Open the ``sim://`` URL: start the simulated unit of its options (pyserial's ``open``)."""
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            opts = parse_sim_url(self._port)
            truth = UnitTruth.ideal() if opts.ideal else UnitTruth.random(opts.seed, grade=opts.grade)
            truth.mag = opts.mag
            truth.heading_deg = opts.heading
            self.device = SimDevice(truth, seed=opts.seed, rate_hz=opts.rate, scenario=opts.scenario,
                                    loop=opts.loop, chamber=opts.chamber)
        except ValueError as exc:
            raise SerialException(f"cannot open {self._port!r}: {exc}") from None
        faults = opts.faults
        self.injector = FaultInjector(faults, record=opts.record) if faults and faults.active else None
        self._disconnect_s = faults.disconnect_after_s if faults else None
        self.speed = opts.speed
        self._record = opts.record
        self._reconfigure_port()
        self.is_open = True
        self._t0 = time.monotonic()

    def _reconfigure_port(self) -> None:
        if not isinstance(self._baudrate, numbers.Integral) or not 0 < int(self._baudrate) < 2**32:
            raise ValueError(f"invalid baudrate: {self._baudrate!r}")

    def close(self) -> None:
        """Close the port and wake a blocked :meth:`read`."""
        self.is_open = False
        self._cancel.set()

    @property
    def in_waiting(self) -> int:
        """Bytes the simulated unit has sent and the host has not read (none during a stall)."""
        self._check_open()
        with self._lock:
            self._pump()
            return len(self._rx) if time.monotonic() >= self._hold_until else 0

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes, waiting at most the port's timeout (pyserial's ``read``).

        Parameters
        ----------
        size : int

        Returns
        -------
        bytes
            Fewer than ``size`` on a timeout.

        Raises
        ------
        serial.SerialException
            The port is closed or the simulated unit disconnected (a ``sim://`` fault).
        """
        self._check_open()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        self._cancel.clear()
        out = bytearray()
        while self.is_open:
            with self._lock:
                self._pump()
                now = time.monotonic()
                if now >= self._hold_until and self._rx:
                    take = size - len(out)
                    out += self._rx[:take]
                    del self._rx[:take]
                if len(out) >= size:
                    break
                if self._gone():
                    if out:
                        break
                    raise SerialException("read failed: the simulated device disconnected (sim:// fault)")
                wait = max(self._hold_until - now, self._seconds_to_next_sample(), 0.0005)
            if deadline is not None:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                wait = min(wait, left)
            if self._cancel.wait(min(wait, _MAX_POLL_S)):
                break
        return bytes(out)

    def write(self, data: bytes) -> int:
        """Hand ``data`` (commands) to the simulated unit; returns the bytes written.

        Parameters
        ----------
        data : bytes

        Returns
        -------
        int

        Raises
        ------
        serial.SerialException
            The simulated unit disconnected (a ``sim://`` fault).
        """
        self._check_open()
        data = to_bytes(data)
        with self._lock:
            self._pump()
            if self._gone() or (self.injector is not None and self.injector.disconnected):
                raise SerialException("write failed: the simulated device disconnected (sim:// fault)")
            self._rx += self._device().feed(bytes(data))
        return len(data)

    def reset_input_buffer(self) -> None:
        """Drop the bytes received and not read yet."""
        self._check_open()
        with self._lock:
            self._pump()
            self._rx.clear()

    def reset_output_buffer(self) -> None:
        """Nothing to drop: writes reach the simulated unit at once."""
        self._check_open()

    @property
    def out_waiting(self) -> int:
        """Always 0: writes reach the simulated unit at once."""
        self._check_open()
        return 0

    def cancel_read(self) -> None:
        """Wake a :meth:`read` blocked in another thread."""
        self._cancel.set()

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        """Clear To Send: always asserted."""
        self._check_open()
        return True

    @property
    def dsr(self) -> bool:
        """Data Set Ready: always asserted."""
        self._check_open()
        return True

    @property
    def ri(self) -> bool:
        """Ring Indicator: never asserted."""
        self._check_open()
        return False

    @property
    def cd(self) -> bool:
        """Carrier Detect: always asserted."""
        self._check_open()
        return True

    # --- the simulation -----------------------------------------------------------------------

    def device_time_s(self) -> float:
        """The simulated unit's clock: wall time since open times the speed, s."""
        return (time.monotonic() - self._t0) * self.speed

    def sent(self) -> np.ndarray:
        """Every sample produced for the host, in order (``record=1``)."""
        from protocols.base import SAMPLE_DTYPE

        return np.concatenate(self._sent) if self._sent else np.zeros(0, dtype=SAMPLE_DTYPE)

    def _check_open(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    def _device(self) -> SimDevice:
        if self.device is None:
            raise PortNotOpenError()
        return self.device

    def _gone(self) -> bool:
        return self.injector is not None and self.injector.disconnected and not self._rx

    def _seconds_to_next_sample(self) -> float:
        return (self._device().next_due_s() - self.device_time_s()) / self.speed

    def _pump(self) -> None:
        """Move every sample due by now into the receive buffer (through the faults)."""
        now = self.device_time_s()
        if self.injector is not None and self._disconnect_s is not None and now >= self._disconnect_s:
            self.injector.end_link()
        device = self._device()
        samples = device.produce(now)
        if not len(samples):
            return
        if self._record:
            self._sent.append(samples)
        if self.injector is None:
            self._rx += device.encode_samples(samples)
            return
        out = self.injector.apply(device.encode_frames(samples))
        if out.stall_s:
            self._hold_until = max(self._hold_until, time.monotonic()) + out.stall_s
        self._rx += out.data
