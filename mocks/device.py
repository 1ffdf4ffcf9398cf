"""The simulated device: a state machine fed host bytes, producing samples for elapsed time.

It speaks the native protocol (``shared/specs/native-protocol.md``): it streams from power-up,
answers GET_INFO with DEVICE_INFO, SET_RATE / START_STREAM / STOP_STREAM with ACK, RESTART with
ACK and a restart as at power-up (``seq`` and ``t_us`` from 0, the power-up rate, the turn-on biases
of :meth:`mocks.truth.UnitTruth.turned_on`; ACK status 1 when built ``restartable=False``), and
unknown commands with ACK status 1. Time is the device clock in seconds since power-up, given
by whoever serves the device (a pty thread, the ``sim://`` port): ``produce(t)`` returns every
sample due at or before t; sample k is due at its own timestamp (an absolute schedule).

What the unit feels comes from a scenario (a list of rig segments, looped or held at the end;
the ``chamber`` scenario also sweeps its temperature, ``mocks.chamber.scenario_sweep``)
and can be driven live with :meth:`SimDevice.set_pose`, :meth:`SimDevice.rotate` and
:meth:`SimDevice.command`: the hook a simulated operator or turntable uses.

Sample encoders are pluggable: ``ENCODERS[name](samples) -> bytes`` for a batch of
``SAMPLE_DTYPE`` records; other wire protocols register theirs here. An encoder whose frames
all have one size also registers it in ``FRAME_SIZES``, so faults can cut a batch into frames
without encoding sample by sample.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable, Sequence

import numpy as np

from mocks.chamber import ChamberSweep, scenario_sweep
from mocks.mag_sessions import desk_session, sphere_session
from mocks.rig import (
    Move,
    Rotation,
    Segment,
    Static,
    Timeline,
    UnitSampler,
    handheld_session,
    sequence_segments,
)
from mocks.truth import UnitTruth
from protocols import native
from protocols.base import SAMPLE_DTYPE, has_mag

ENCODERS: dict[str, Callable[[np.ndarray], bytes]] = {"native": native.encode_samples}
FRAME_SIZES: dict[str, int] = {"native": native.SAMPLE_FRAME_SIZE}

MIN_RATE_HZ = 1
MAX_RATE_HZ = 4000


def _still() -> list[Segment]:
    return [Static("+z", 1.0)]


# name -> (segments for a seed, loop). "still" holds +z forever (labelled +z throughout), and so does
# "chamber", whose temperature sweeps (SimDevice takes its programme).
SCENARIOS: dict[str, tuple[Callable[[int], list[Segment]], bool]] = {
    "still": (lambda seed: _still(), False),
    "chamber": (lambda seed: _still(), False),
    "six-position": (lambda seed: sequence_segments("six-position"), True),
    "twelve-position": (lambda seed: sequence_segments("twelve-position"), True),
    "six-position-static": (lambda seed: sequence_segments("six-position", rotations=False), True),
    "handheld": (lambda seed: handheld_session(n_poses=20, seed=seed, hold_s=3.0, initial_still_s=10.0),
                 True),
    "mag-sphere": (lambda seed: sphere_session(seed=seed), True),
    "mag-desk": (lambda seed: desk_session(seed=seed), True),
}


HELD_STILL = ("still", "chamber")


def scenario_timeline(scenario: str | Sequence[Segment], seed: int = 0, loop: bool | None = None) -> Timeline:
    """The motion of a named scenario (``SCENARIOS``) or of a list of segments.

    Parameters
    ----------
    scenario : str or sequence of Segment
    seed : int
        Seed of the random attitudes (hand-held scenarios).
    loop : bool, optional
        Repeat the motion; default the scenario's own choice.

    Returns
    -------
    Timeline

    Raises
    ------
    ValueError
        An unknown scenario name.
    """
    if isinstance(scenario, str):
        if scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
        make, default_loop = SCENARIOS[scenario]
        segments = make(seed)
        if scenario in HELD_STILL:
            timeline = Timeline(segments, loop=False)
            timeline.pieces[-1].label = "+z"
            return timeline
        return Timeline(segments, loop=default_loop if loop is None else loop)
    return Timeline(list(scenario), loop=bool(loop))


class SimDevice:
    """The simulated unit behind a serial link. Thread-safe: one lock around the state.

    Times given to :meth:`produce` and returned by :meth:`next_due_s` and the live-motion methods are
    the server's clock since the first power-up; after a RESTART the unit's own clock (``t_us``)
    starts again from 0 at the restart.

    Parameters
    ----------
    truth : the unit (default ``UnitTruth.random(seed)``).
    seed : seeds the unit (when ``truth`` is None), the noise and the hand-held scenario.
    rate_hz : sample rate at power-up.
    scenario : a name of ``SCENARIOS`` or a list of rig segments.
    loop : repeat the scenario (default: per scenario; lists hold their last pose).
    temperature : a temperature profile over device time (default 25 degC; for the ``chamber``
        scenario, the profile of ``chamber``).
    encoder : name in ``ENCODERS`` of the sample wire format.
    temp_noise_degc : standard deviation of the temperature sensor's noise.
    chamber : the programme of the ``chamber`` scenario (default ``mocks.chamber.scenario_sweep()``).
    restartable : False: RESTART is answered ACK status 1, as by a unit that cannot restart itself.
    """

    def __init__(self, truth: UnitTruth | None = None, *, seed: int = 0, rate_hz: float = 200.0,
                 scenario: str | Sequence[Segment] = "still", loop: bool | None = None,
                 temperature: Callable[[np.ndarray], np.ndarray] | None = None,
                 encoder: str = "native", temp_noise_degc: float = 0.01, chamber: ChamberSweep | None = None,
                 restartable: bool = True):
        if chamber is not None and scenario != "chamber":
            raise ValueError(f"a chamber programme needs the chamber scenario, not {scenario!r}")
        if scenario == "chamber" and temperature is None:
            temperature = (chamber or scenario_sweep()).profile()
        if encoder not in ENCODERS:
            raise ValueError(f"unknown encoder {encoder!r}; known: {', '.join(ENCODERS)}")
        if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
            raise ValueError(f"rate {rate_hz} Hz is outside {MIN_RATE_HZ}..{MAX_RATE_HZ} Hz")
        self.truth = truth if truth is not None else UnitTruth.random(seed)
        self.encoder_name = encoder
        self.encode_samples = ENCODERS[encoder]
        self.timeline = scenario_timeline(scenario, seed, loop)
        self.sampler = UnitSampler(self.truth, self.timeline, rate_hz, seed, temperature, temp_noise_degc)
        # The temperature as a function of server time: every power-up reads it at its own clock's offset.
        self._server_temperature = self.sampler.temperature
        self.streaming = True
        self.seq = 0
        self.commands: dict[str, int] = {}
        self.restartable = restartable
        self.restarts = 0
        self.powered = True  # a bench supply's output (power()); off: silent, deaf, no samples
        self.base_truth = self.truth  # the unit at its first power-up; self.truth is the current turn-on's
        self._seed = seed
        self._power_up_rate = rate_hz
        self._epoch_s = 0.0  # server time of the last restart: the unit's clock is the server's minus this
        self._decoder = native.NativeDecoder()
        self._lock = threading.RLock()

    @property
    def rate_hz(self) -> float:
        """The sample rate now (SET_RATE changes it)."""
        return self.sampler.rate_hz

    def info(self) -> dict[str, object]:
        """What GET_INFO answers: the unit's identity and its rate."""
        rate = self.rate_hz
        return self.truth.device_info(int(rate) if float(rate).is_integer() else rate)

    def next_due_s(self) -> float:
        """Device time at which the next sample is due."""
        with self._lock:
            return self._epoch_s + self.sampler.time_of(self.sampler.count)

    # --- host commands -----------------------------------------------------------------

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host in; the device's answers out (frames, in command order).

        Parameters
        ----------
        data : bytes
            Bytes from the host (native-protocol commands, possibly split anywhere).

        Returns
        -------
        bytes
            The encoded answers.
        """
        with self._lock:
            if not self.powered:
                return b""  # an unpowered unit hears nothing: the bytes are lost, as on a real link
            decoded = self._decoder.feed(data)
            return b"".join(self._answer(m.msg_id, m.payload) for m in decoded.messages)

    def _answer(self, msg_id: int, payload: bytes) -> bytes:
        name = {native.GET_INFO: "GET_INFO", native.SET_RATE: "SET_RATE", native.START_STREAM: "START_STREAM",
                native.STOP_STREAM: "STOP_STREAM", native.RESTART: "RESTART"}.get(msg_id, f"0x{msg_id:02x}")
        self.commands[name] = self.commands.get(name, 0) + 1
        if msg_id == native.GET_INFO:
            return native.encode_device_info(self.info())
        if msg_id == native.SET_RATE:
            if len(payload) != 2:
                return native.encode_ack(msg_id, native.ACK_BAD_ARGUMENT)
            (rate,) = struct.unpack("<H", payload)
            if not MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
                return native.encode_ack(msg_id, native.ACK_BAD_ARGUMENT)
            self.sampler.set_rate(rate)
            return native.encode_ack(msg_id)
        if msg_id in (native.START_STREAM, native.STOP_STREAM):
            self.streaming = msg_id == native.START_STREAM
            return native.encode_ack(msg_id)
        if msg_id == native.RESTART:
            if not self.restartable:
                return native.encode_ack(msg_id, native.ACK_UNKNOWN)
            self._restart()
            return native.encode_ack(msg_id)
        if msg_id in (native.IMU_SAMPLE, native.IMU_MAG_SAMPLE, native.DEVICE_INFO, native.ACK):
            return b""  # device-to-host messages echoed back by the host: not commands
        return native.encode_ack(msg_id, native.ACK_UNKNOWN)

    def _restart(self) -> None:
        """Power up again where the unit is: same attitude and step label, held; new turn-on biases,
        new noise, the power-up rate, streaming, seq and the unit's clock from 0."""
        local = self.sampler.time_of(self.sampler.count)
        attitude = self.timeline.attitude_at(local)
        label = str(self.timeline.evaluate(np.array([local]), [])[2][0])
        temperature = self._server_temperature
        epoch = self._epoch_s + local
        self.restarts += 1
        self.truth = self.base_truth.turned_on(self.restarts, self._seed)
        self.timeline = Timeline([], loop=False, r_start=attitude)
        self.timeline.pieces[-1].label = label
        self.sampler = UnitSampler(self.truth, self.timeline, self._power_up_rate,
                                   self._seed * 7919 + self.restarts,
                                   lambda t: np.asarray(temperature(np.asarray(t) + epoch), float),
                                   self.sampler.temp_noise_degc)
        self._epoch_s = epoch
        self.streaming = True
        self.seq = 0

    def power(self, on: bool) -> None:
        """The supply's output (``mocks.instruments``): off, the unit is silent (no samples, no answers to
        commands); on, it boots as after a RESTART (new turn-on biases, seq and its clock from 0). Switching
        to the state it is already in does nothing.

        Parameters
        ----------
        on : bool
            The output's new state.
        """
        with self._lock:
            if on == self.powered:
                return
            self.powered = on
            if on:
                # Half a command heard before the power went is gone with the unit's RAM.
                self._decoder = native.NativeDecoder()
                self._restart()

    # --- samples ---------------------------------------------------------------------------

    def produce(self, t_s: float) -> np.ndarray:
        """Every sample due at or before ``t_s`` (``SAMPLE_DTYPE``). While streaming is stopped the
        unit still runs (time, motion and noise go on) but nothing is returned and seq holds; while
        unpowered (:meth:`power`) likewise, and the next power-up starts its clock from there.

        Parameters
        ----------
        t_s : float
            Device time, s.

        Returns
        -------
        ndarray of SAMPLE_DTYPE
        """
        with self._lock:
            n = self.sampler.due_count(t_s - self._epoch_s)
            if n == 0:
                return np.zeros(0, dtype=SAMPLE_DTYPE)
            rec = self.sampler.next(n)
            self.timeline.prune(float(rec.t[0]))
            if not self.streaming or not self.powered:
                return np.zeros(0, dtype=SAMPLE_DTYPE)
            samples = rec.samples()
            samples["seq"] = (self.seq + np.arange(n)) % (1 << 32)
            self.seq = (self.seq + n) % (1 << 32)
            return samples

    def encode_frames(self, samples: np.ndarray) -> list[bytes]:
        """One encoded frame per sample (for fault injection, which works frame by frame).

        Parameters
        ----------
        samples : ndarray of SAMPLE_DTYPE

        Returns
        -------
        list of bytes
        """
        # A nine-axis batch has frames of another size (IMU_MAG_SAMPLE): encoded one by one.
        size = None if has_mag(samples) else FRAME_SIZES.get(self.encoder_name)
        if size is None:
            return [self.encode_samples(samples[i : i + 1]) for i in range(len(samples))]
        data = self.encode_samples(samples)
        return [data[i : i + size] for i in range(0, len(data), size)]

    # --- live motion -------------------------------------------------------------------------

    def command(self, segments: Sequence[Segment]) -> float:
        """Drive the unit with ``segments`` from the next sample on, then hold; returns the device
        time at which they end.

        Parameters
        ----------
        segments : sequence of Segment

        Returns
        -------
        float
            Device time, s.
        """
        with self._lock:
            return self._epoch_s + self.timeline.command(segments, self.sampler.time_of(self.sampler.count))

    def set_pose(self, pose: str, move_s: float = 2.0, label: str | None = None) -> float:
        """Move the unit smoothly to ``pose`` ("+x", "-z", "+x+y") and hold it there.

        Parameters
        ----------
        pose : str
        move_s : float
            Seconds of the move.
        label : str, optional
            Step label of the held samples.

        Returns
        -------
        float
            Device time (s) at which the move and a one-second hold end.
        """
        return self.command([Move(move_s), Static(pose, 1.0, label=label)])

    def rotate(self, axis: str, angle_deg: float = 360.0, rate_dps: float = 90.0,
               settle_s: float = 1.0) -> float:
        """Turn about the body ``axis`` held vertical (a move first puts the axis up).

        Parameters
        ----------
        axis : str
            ``+x``, ``-z``, ...
        angle_deg, rate_dps : float
        settle_s : float
            Seconds still after the turn.

        Returns
        -------
        float
            Device time (s) at which the turn and settling end.
        """
        return self.command([Rotation(axis, angle_deg, rate_dps, settle_s)])

    # --- live temperature ----------------------------------------------------------------------

    def follow_temperature(self, plant: Callable[[np.ndarray], np.ndarray]) -> None:
        """Read the unit's temperature from ``plant`` from now on: a live profile of server time
        (a climatic chamber's plant, ``mocks.instruments.chamber_plant.ChamberPlant``, whose clock is
        this device's), which commands to the chamber change while the unit streams.

        Parameters
        ----------
        plant : callable
            Temperature (degC) of server times (s), vectorised; times only grow.
        """
        with self._lock:
            epoch = self._epoch_s
            self._server_temperature = plant
            # The sampler's clock restarts with the unit; the plant's is the server's.
            self.sampler.temperature = plant if epoch == 0 else (
                lambda t: np.asarray(plant(np.asarray(t) + epoch), float))
