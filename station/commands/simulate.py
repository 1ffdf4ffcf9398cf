"""``imu-station simulate``: a simulated unit on a pseudo-terminal, until Ctrl-C."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from station.console.options import (
    DURATION_S,
    MAX_SPEED,
    SEED,
    SIM_ENCODERS,
    SIM_SCENARIOS,
    SPEED,
    add_output_option,
    check_range,
)
from station.errors import ExitCode, StationError

if TYPE_CHECKING:
    from mocks.chamber import ChamberSweep
    from mocks.instruments.bench import SimulatedBench
    from mocks.magnetometer import MagTruth
    from mocks.pty_server import PtyServer
    from mocks.truth import UnitTruth

SERVED_RATE_HZ = 200
LOG_RATE_HZ = 10  # mocks.autopilot_sweep.LOG_RATE_HZ (not imported: --help loads no numpy)
LOG_FORMATS = ("ulog", "dataflash")  # mocks.autopilot_sweep.LOG_FORMATS

NAME = "simulate"
HELP = "serve a simulated unit on a pseudo-terminal (a serial port path any tool can open)"
DESCRIPTION = """\
Serve a simulated IMU on a pseudo-terminal, as a real unit on a serial port: it speaks the native
protocol, streams from power-up on an absolute schedule (no drift), and answers GET_INFO, SET_RATE,
START_STREAM and STOP_STREAM. The unit's intrinsics, noise and motion come from --seed and
--scenario; the same seed gives the same unit and the same bytes. Faults can be injected on the
link. --speed X runs the device clock X times faster than the wall clock (the timestamps keep the
unit's rate; a long sequence takes 1/X of the time). It prints the port path and runs until Ctrl-C
(exit 0), --duration, or a disconnect fault, then prints a summary.

scenarios: still (lying flat, +z up), six-position, twelve-position (the capture-csv sequences
with their rotations, looped), six-position-static (no rotations), handheld (imu_tk-style random
poses, looped), chamber (lying flat, +z up, in a climatic chamber: from -20 up to +60 degC and
back at 1 degC/min with 10 min soaks, 3 h of device clock, then held at -20 degC; the unit's
thermal bias follows; --chamber changes the programme), mag-sphere (turned by hand through
attitudes that cover the sphere, still a moment at each), mag-desk (turned on a desk, z axis within
45 deg of up, still at each pose): the two magnetometer calibration sessions, for a unit with --mag.

--mag makes a nine-axis unit: a magnetometer with hard and soft iron, turned a degree or two
against the accelerometer, sending IMU_MAG_SAMPLE frames; --mag field=UT,dip=DEG,declination=DEG
sets the local Earth field (default 50 uT, dip 60 deg, declination 0).

faults (probabilities per frame, comma separated): garbage=P, bitflip=P, truncate=P, drop=P,
stall=P with stall_s=S, garbage_max=N, disconnect_bytes=N, disconnect_s=S, seed=N.

--log-format ulog|dataflash -o FILE writes a flight controller's log instead of serving a port:
a board of three IMU instances of different truths (instance 0 a cubic thermal bias, 1 a cubic with
strong dT terms, 2 a cubic with a mild dT term; different biases and noise) taken through a chamber
programme (--scenario chamber): from t_min up to t_max and back, with soaks, still and z up.
ulog is PX4's (sensor_accel, sensor_gyro, sensor_baro, the board's parameters), dataflash
ArduPilot's .bin (IMU and PARM messages). For logs the programme's defaults are
t_min=-20,t_max=60,rate_c_per_min=3,soak_s=300 and --rate defaults to 10 Hz (ArduPilot's
tempcal_IMU.py takes time growing with the square of the samples per IMU).

--instruments also serves a simulated bench on loopback TCP, coupled to the unit, and prints each
instrument's URL (votsch://, acutrol://, scpi:// on 127.0.0.1) for `imu-station instrument URL`,
--chamber/--table/--supply and plans: a Voetsch simserv chamber whose air the unit sits in (a
setpoint warms or cools the unit, at --speed), an ACUTROL rate table the unit is mounted on (+z up;
its turns are the unit's), a SCPI bench supply powering the unit (output on at 5 V at start;
off silences the unit, on boots it anew). --instruments chamber,supply serves only those. The
sim://chamber|table|supply names reach them only inside one process (run --simulate): from
another process give the printed URLs."""
EPILOG = """\
examples:
  imu-station simulate --seed 3 --rate 400 --link /tmp/imu
  imu-station simulate --scenario six-position --faults garbage=0.01,drop=0.001
  imu-station simulate --scenario twelve-position --speed 10
  imu-station simulate --scenario chamber --chamber t_min=0,t_max=40,rate_c_per_min=2 --speed 100
  imu-station simulate --mag field=48,dip=64 --scenario mag-desk
  imu-station simulate --scenario chamber --log-format ulog -o sweep.ulg
  imu-station simulate --scenario chamber --log-format dataflash --chamber rate_c_per_min=2 -o sweep.bin
  imu-station simulate --instruments --speed 20
  imu-station instrument votsch://127.0.0.1:PORT --setpoint 40 --start   (a URL it printed)
  imu-station capture --port /tmp/imu --duration 10 -o still.csv   (in another terminal)"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the simulate command's options to ``parser``."""
    parser.add_argument("--seed", type=SEED, default=0, help="unit, noise and scenario seed (default: 0)")
    parser.add_argument("--rate", type=int, default=None, metavar="HZ",
                        help=f"sample rate at power-up (default: {SERVED_RATE_HZ}; {LOG_RATE_HZ} with "
                             "--log-format)")
    parser.add_argument("--scenario", default="still", choices=SIM_SCENARIOS,
                        help="how the unit moves (default: still)")
    parser.add_argument("--chamber", default="", metavar="SPEC",
                        help="programme of --scenario chamber: t_min=C,t_max=C,rate_c_per_min=R,soak_s=S, "
                             "any of them (default: t_min=-20,t_max=60,rate_c_per_min=1,soak_s=600; "
                             "with --log-format rate_c_per_min=3,soak_s=300)")
    parser.add_argument("--mag", nargs="?", const="mag=1", default="", metavar="SPEC",
                        help="a unit with a magnetometer; SPEC sets the local field and the rig's heading: "
                             "field=UT,dip=DEG,declination=DEG,heading=DEG, any of them (default: "
                             "field=50,dip=60,declination=0,heading=0)")
    parser.add_argument("--hold", action="store_true",
                        help="hold the last pose at the end of the scenario instead of looping it")
    parser.add_argument("--grade", default="mems", choices=["mems", "tactical"],
                        help="intrinsics and noise of the random unit (default: mems)")
    parser.add_argument("--ideal", action="store_true", help="an ideal unit: identity intrinsics, no noise")
    parser.add_argument("--protocol", default="native", choices=SIM_ENCODERS,
                        help="wire format of the samples (default: native)")
    parser.add_argument("--faults", default="", metavar="SPEC",
                        help="link faults, e.g. garbage=0.01,drop=0.001 (default: none)")
    parser.add_argument("--link", type=Path, metavar="PATH",
                        help="also make a symlink at PATH to the port (removed at exit)")
    parser.add_argument("--speed", type=SPEED, default=1.0, metavar="X",
                        help=f"device clock runs X times faster than the wall clock, at most {MAX_SPEED:g} "
                             "(default: 1)")
    parser.add_argument("--duration", type=DURATION_S, metavar="S",
                        help="stop after S seconds of wall clock (default: until Ctrl-C)")
    parser.add_argument("--log-format", choices=LOG_FORMATS, default=None,
                        help="write a flight controller's log of a three-IMU board (with --scenario chamber "
                             "and -o) instead of serving a port: ulog (PX4) or dataflash (ArduPilot .bin)")
    add_output_option(parser, metavar="FILE", help="with --log-format: the log to write (.ulg / .bin)")
    parser.add_argument("--instruments", nargs="?", const="all", default="", metavar="KINDS",
                        help="also serve a simulated chamber, rate table and bench supply coupled to the "
                             "unit, on loopback TCP, and print their URLs; KINDS picks some: "
                             "chamber,table,supply (default: all three)")


def run(args: argparse.Namespace) -> int:
    """Serve the simulated unit until Ctrl-C, SIGTERM, --duration or a disconnect fault."""
    import mocks.encoders_extra  # noqa: F401  (registers the xsens, mavlink and text encoders)
    from mocks.chamber import parse_chamber_spec
    from mocks.device import MAX_RATE_HZ, MIN_RATE_HZ, SimDevice
    from mocks.faults import FaultSpec
    from mocks.instruments.bench import parse_kinds, simulated_bench
    from mocks.pty_server import PtyServer
    from mocks.truth import UnitTruth

    if args.log_format is not None or args.output is not None:
        return _write_log(args)
    rate = SERVED_RATE_HZ if args.rate is None else args.rate
    try:
        faults = FaultSpec.parse(args.faults)
    except ValueError as exc:
        raise StationError(f"--faults {args.faults!r}: {exc}") from None
    chamber = None
    if args.scenario == "chamber":
        try:
            chamber = parse_chamber_spec(args.chamber)
        except ValueError as exc:
            raise StationError(f"--chamber {args.chamber!r}: {exc}") from None
    elif args.chamber:
        raise StationError(f"--chamber applies to --scenario chamber only, not {args.scenario}")
    check_range("--rate", rate, MIN_RATE_HZ, MAX_RATE_HZ, unit="Hz, the simulated unit's rates")
    kinds: tuple[str, ...] = ()
    if args.instruments:
        try:
            kinds = parse_kinds(args.instruments)
        except ValueError as exc:
            raise StationError(f"--instruments {args.instruments!r}: {exc}") from None
        if "chamber" in kinds and args.scenario == "chamber":
            raise StationError("--instruments serves a chamber whose air sets the unit's temperature; "
                               "--scenario chamber has its own programme: choose one (e.g. --instruments "
                               "table,supply)")
    if args.link is not None and os.path.lexists(args.link) and not args.link.is_symlink():
        raise StationError(f"--link {args.link}: a file that is not a symlink is there; choose another path")
    truth = UnitTruth.ideal() if args.ideal else UnitTruth.random(args.seed, grade=args.grade)
    truth.mag, heading = _magnetometer(args.mag, args.seed)
    truth.heading_deg = heading
    device = SimDevice(truth, seed=args.seed, rate_hz=rate, scenario=args.scenario,
                       loop=False if args.hold else None, encoder=args.protocol, chamber=chamber)
    server = PtyServer(device, faults=faults, link=args.link, speed=args.speed)

    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    bench: SimulatedBench | None = None
    try:
        server.start()
        # The bench runs on the served unit's device clock: at --speed X its chamber warms the unit X times
        # faster.
        serving = simulated_bench(device, server.device_time_s, kinds) if kinds else contextlib.nullcontext()
        with serving as bench:
            _announce(args, server, truth, faults.describe(), chamber, bench)
            try:
                _wait(server, stop, args.duration)
            except KeyboardInterrupt:
                pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        server.stop()
    _summary(server)
    if bench is not None:
        print(f"instruments: {bench.describe()}")
    return ExitCode.OK


def _announce(args: argparse.Namespace, server: PtyServer, truth: UnitTruth, faults: str,
              chamber: ChamberSweep | None, bench: SimulatedBench | None) -> None:
    """Print what is served: the unit, its port, the bench's URLs."""
    from mocks.chamber import describe_scenario
    from station.common.text import printable

    speed = f", speed x{args.speed:g}" if args.speed != 1 else ""
    rate = SERVED_RATE_HZ if args.rate is None else args.rate
    print(f"simulated unit {printable(truth.serial)} ({printable(truth.model)}), {rate} Hz, "
          f"scenario {args.scenario}, faults {faults}{speed}")
    if chamber is not None:
        print(f"chamber: {describe_scenario(chamber)}")
    if truth.mag is not None:
        earth = truth.mag.field
        print(f"magnetometer: local field {earth.magnitude_ut:g} uT, dip {earth.dip_deg:g} deg, "
              f"declination {earth.declination_deg:g} deg")
    print(f"port: {server.port_path}")
    if args.link is not None:
        print(f"link: {printable(args.link)} -> {server.port_path}")
    if bench is not None:
        for kind, url in bench.urls.items():
            print(f"{kind}: {url}")
        print("instruments: coupled to the unit; open them by these URLs (sim://KIND names them only "
              "inside one process)")
    print("press Ctrl-C to stop", flush=True)


# Options of a served unit that a written log has no use for, with the value that means "not given".
_SERVING_ONLY = (("--faults", "faults", ""), ("--link", "link", None), ("--speed", "speed", 1.0),
                 ("--duration", "duration", None), ("--instruments", "instruments", ""), ("--mag", "mag", ""),
                 ("--hold", "hold", False), ("--protocol", "protocol", "native"),
                 ("--grade", "grade", "mems"))
MAX_LOG_RATE_HZ = 1000  # a chamber log at 1 kHz is already hundreds of MB


def _write_log(args: argparse.Namespace) -> int:
    """``--log-format``: simulate the three-IMU board through the chamber and write its log."""
    from mocks.autopilot_sweep import LOG_SUFFIXES, parse_log_sweep, simulate_board_log
    from mocks.chamber import describe_scenario
    from station.common.text import PATH_CHARS, printable

    if args.log_format is None or args.output is None:
        raise StationError("a log needs both --log-format ulog|dataflash and -o FILE")
    if args.scenario != "chamber":
        raise StationError(f"--log-format writes a chamber sweep: give --scenario chamber, not "
                           f"{args.scenario}")
    given = [flag for flag, dest, unset in _SERVING_ONLY if getattr(args, dest) != unset]
    if given:
        raise StationError(f"{', '.join(given)}: for a served unit only, not with --log-format")
    rate = LOG_RATE_HZ if args.rate is None else args.rate
    check_range("--rate", rate, 1, MAX_LOG_RATE_HZ, unit="Hz, for a log")
    try:
        sweep = parse_log_sweep(args.chamber)
    except ValueError as exc:
        raise StationError(f"--chamber {args.chamber!r}: {exc}") from None
    output = Path(args.output)
    if output.is_dir():
        raise StationError(f"-o {printable(output, PATH_CHARS)} is a directory; give a file name "
                           f"(e.g. sweep{LOG_SUFFIXES[args.log_format]})")
    try:
        imus, runs = simulate_board_log(output, args.log_format, seed=args.seed, sweep=sweep, rate_hz=rate,
                                        noise=not args.ideal)
    except OSError as exc:
        raise StationError(f"cannot write {printable(output, PATH_CHARS)}: {exc.strerror or exc}") from None
    kind = "PX4 ULog" if args.log_format == "ulog" else "ArduPilot DataFlash log"
    n = len(runs[0].recording.t)
    print(f"wrote {printable(output, PATH_CHARS)}: {kind}, {len(imus)} IMU instances, {n} samples each at "
          f"{rate:g} Hz{', noise-free' if args.ideal else ''}, seed {args.seed}")
    print(f"chamber: {describe_scenario(sweep).split(', then held')[0]}")
    for imu, run in zip(imus, runs, strict=True):
        temp = run.recording.temp_true
        print(f"  instance {imu.instance}: accel id {imu.accel_id}, gyro id {imu.gyro_id}, thermal truth "
              f"{imu.kind}, {temp.min():.1f}..{temp.max():.1f} degC")
    return ExitCode.OK


def _magnetometer(spec: str, seed: int) -> tuple[MagTruth | None, float]:
    """The magnetometer of ``--mag SPEC`` (comma-separated key=value; None without --mag) and the
    rig's heading (deg from true north) the spec gives, 0 by default."""
    from mocks.magnetometer import mag_from_options

    if not spec:
        return None, 0.0
    options = dict(part.partition("=")[::2] for part in spec.split(",") if part.strip())
    options = {k.strip(): v.strip() for k, v in options.items()}
    options.setdefault("mag", "1")
    try:
        heading = float(options.pop("heading", "0"))
        if not -360.0 <= heading <= 360.0:
            raise ValueError(f"heading {heading:g} is outside -360..360 deg")
        return mag_from_options(options, seed), heading
    except ValueError as exc:
        raise StationError(f"--mag {spec!r}: {exc}; give field=UT,dip=DEG,declination=DEG,heading=DEG") \
            from None


def _wait(server: PtyServer, stop: threading.Event, duration: float | None) -> None:
    status = sys.stderr.isatty()
    while not stop.is_set():
        if server.wait_closed(0.5):
            break
        elapsed = server.elapsed_s()
        if status:
            s = server.stats
            host = "host connected" if server.host_connected else "no host"
            print(f"\r{elapsed:8.1f} s  {s.samples} samples  {s.samples_sent} sent  {host}   ",
                  end="", file=sys.stderr, flush=True)
        if duration is not None and elapsed >= duration:
            break
    if status:
        print(file=sys.stderr)


def _summary(server: PtyServer) -> None:
    s = server.stats
    clock = f" ({s.device_time_s:.1f} s of device clock, x{server.speed:g})" if server.speed != 1 else ""
    per = "/s of device clock" if server.speed != 1 else "/s"
    print(f"ran {s.elapsed_s:.1f} s{clock}: {s.samples} samples ({s.rate_hz:.1f}{per}), "
          f"{s.samples_sent} sent to a host, {s.samples_unheard} with no host, "
          f"{s.samples_overrun} dropped (host not reading), "
          f"{s.bytes_written} bytes written")
    commands = ", ".join(f"{k} x{v}" for k, v in sorted(s.commands.items())) or "none"
    print(f"host opened the port {s.host_opens} time(s); commands: {commands}; "
          f"blocks late by more than one period: {s.late_blocks} (worst {s.max_lateness_s * 1e3:.1f} ms)")
    if server.injector is not None:
        c = server.injector.counts
        print(f"faults: {c.frames} frames, {c.intact} intact, {c.dropped} dropped, {c.truncated} truncated, "
              f"{c.bitflips} bit flips, {c.garbage_runs} garbage runs ({c.garbage_bytes} bytes), "
              f"{c.stalls} stalls")
    if s.disconnected:
        print("the link was disconnected by the fault injector")
