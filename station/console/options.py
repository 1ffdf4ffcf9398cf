"""Command-line options the commands share, defined and validated once.

Every numeric option is range-checked where it is parsed: a value outside its range is a usage
error (exit 4) whose one line names the option, the value and the range, e.g.
``argument --baud: 99999999999 is outside the allowed range, 50..12000000 (bit/s)``.

Why this module is long: it is the one place every shared option is defined, parsed and range-checked
(ports, protocols, outputs, the record database, the lab instruments, a log's IMU instance), so that
the commands say the same thing the same way; split by topic it would scatter the ranges and messages
the tests read from one table.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from protocols.errors import StationError

# The names --help shows, kept here so that `COMMAND --help` loads neither the drivers nor the
# decoders (numpy, pyserial); tests/test_cli_startup.py checks that they are the registries' own.
DEFAULT_BAUDRATE = 921_600
"""``drivers.DEFAULT_BAUDRATE``."""
PROTOCOLS = ("ascii", "auto", "mavlink", "native", "xsens")
"""The keys of ``protocols.registry.DECODERS``, sorted."""
PROTOCOL_OPTIONS = ("ascii", "xsens", "mavlink", "frame")
"""The keys of ``protocols.registry.DECODER_OPTIONS``."""
EXPORT_FORMATS = ("c", "bin", "json", "yaml", "px4", "ardupilot")
"""``station.export.writers.FORMATS``."""
EXPORT_MAX_INSTANCE = {"px4": 3, "ardupilot": 2}
"""``station.export.writers.MAX_INSTANCE``: the highest sensor instance each autopilot has parameters for."""
RECORD_OUTCOMES = ("PASS", "FAIL", "ABORTED", "TIMEOUT", "ERROR")
"""``station.factory.records.OUTCOMES``: the outcomes a run record can have."""
SIM_SCENARIOS = ("still", "chamber", "six-position", "twelve-position", "six-position-static", "handheld",
                 "mag-sphere", "mag-desk")
"""``mocks.device.SCENARIOS``: how the simulated unit moves."""
SIM_ENCODERS = ("ascii", "mavlink", "mavlink-raw", "mavlink-scaled", "motioncal", "native", "vnymr", "xsens",
                "xsens-fp1632")
"""``mocks.device.ENCODERS`` (with ``mocks.encoders_extra``), sorted: the simulated unit's wire formats."""

MIN_BAUD = 50
"""The slowest standard line speed (B50)."""
MAX_BAUD = 12_000_000
"""The fastest USB-serial bridges (FTDI's high-speed parts) run at 12 Mbit/s."""
MAX_SEED = 2**32 - 1
"""numpy's random generators take seeds of 0..2^32-1."""
MAX_DURATION_S = 366 * 86_400.0
"""The longest recording an option may ask for: a year (long Allan records run for days)."""
MAX_RATE_HZ = 0xFFFF
"""The fastest output rate a unit can be set to (SET_RATE carries a 16-bit number of Hz)."""
MIN_GRAVITY, MAX_GRAVITY = 9.7, 9.9
"""Gravity anywhere a station stands is 9.78..9.84 m/s^2; the bounds leave room for a local survey."""
DEFAULT_DB = "imu-station-records.sqlite"
"""The factory's record database when neither --db nor $IMU_STATION_DB names one."""


def _format(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def describe_range(low: float | None, high: float | None, *, low_open: bool = False, unit: str = "") -> str:
    """The allowed range as the messages say it: ``50..12000000 (bit/s)``, ``above 0 up to 20``.

    Parameters
    ----------
    low, high : float, optional
        The bounds; None leaves that side unbounded.
    low_open : bool
        ``low`` itself is refused (a positive quantity).
    unit : str
        The unit, shown in parentheses.
    """
    if low is not None and high is not None:
        text = f"{_format(low)}..{_format(high)}"
        if low_open:
            text = f"above {_format(low)} up to {_format(high)}"
    elif low is not None:
        text = f"above {_format(low)}" if low_open else f"at least {_format(low)}"
    elif high is not None:
        text = f"at most {_format(high)}"
    else:
        text = "a finite number"
    return text + (f" ({unit})" if unit else "")


def _parse_int(text: str) -> int:
    """Decimal (leading zeros allowed, as int() takes them) or 0x hex."""
    try:
        return int(text)
    except ValueError:
        return int(text, 0)


def number(kind: type[int] | type[float] = float, low: float | None = None, high: float | None = None, *,
           low_open: bool = False, unit: str = "") -> Callable[[str], Any]:
    """An argparse ``type`` that parses a finite ``kind`` and refuses it outside ``low``..``high``.

    Parameters
    ----------
    kind : type
        ``int`` (decimal or 0x hex) or ``float``.
    low, high : float, optional
        Inclusive bounds (``low`` exclusive with ``low_open``); None leaves that side open.
    low_open : bool
        Refuse ``low`` itself.
    unit : str
        Unit named in the message.

    Returns
    -------
    callable
        ``str -> kind``, raising ``argparse.ArgumentTypeError`` with the allowed range.
    """
    allowed = describe_range(low, high, low_open=low_open, unit=unit)

    def parse(text: str) -> Any:
        try:
            value = _parse_int(text) if kind is int else float(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}: give {allowed}") from None
        try:
            check_range("", value, low, high, low_open=low_open, unit=unit)
        except StationError:
            raise argparse.ArgumentTypeError(f"{text} is outside the allowed range, {allowed}") from None
        return value

    parse.__name__ = kind.__name__
    return parse


def check_range(option: str, value: float, low: float | None = None, high: float | None = None, *,
                low_open: bool = False, unit: str = "", what: str = "") -> None:
    """Refuse an option's value outside its range after parsing, with the message :func:`number` gives.

    For options whose range depends on another option, or that a command checks once the
    parser is done (its usage error is then a returned exit 4 rather than argparse's exit).

    Parameters
    ----------
    option : str
        The option as the user typed it (``--speed``).
    value : float
        Its parsed value.
    low, high, low_open, unit
        The range, as for :func:`number`.
    what : str
        What the value is, for the message (``a factor``).

    Raises
    ------
    StationError
        ``value`` is not finite or is outside the range (exit 4).
    """
    if not math.isfinite(value) or (low is not None and (value <= low if low_open else value < low)) \
            or (high is not None and value > high):
        raise StationError(f"{option} {_format(value)}: give {what + ' ' if what else ''}"
                           f"{describe_range(low, high, low_open=low_open, unit=unit)}")


def positive(unit: str = "", high: float | None = None) -> Callable[[str], float]:
    """A float above 0 (and at most ``high``), e.g. a duration, a rate or a time constant.

    Parameters
    ----------
    unit : str
        Unit named in the message.
    high : float, optional
        Upper bound, inclusive.

    Returns
    -------
    callable
        An argparse ``type`` (see :func:`number`).
    """
    return number(float, 0.0, high, low_open=True, unit=unit)


SEED = number(int, 0, MAX_SEED)
"""A random seed of the simulated unit."""
DURATION_S = positive("s", MAX_DURATION_S)
"""A length of recording in seconds."""
MAX_SPEED = 100.0
"""The fastest a simulated unit's clock runs against the wall clock (demo, simulate, tui --simulate):
beyond it the pty and the host's decoding, not the simulated unit, set the pace."""
SPEED = number(float, 0.0, MAX_SPEED, low_open=True)
"""``--speed X``: the simulated unit's clock X times the wall clock."""
BAUD = number(int, MIN_BAUD, MAX_BAUD, unit="bit/s")
"""A serial line speed."""
RATE_HZ = positive("Hz", MAX_RATE_HZ)
"""A sample rate a unit runs at."""
GRAVITY = number(float, MIN_GRAVITY, MAX_GRAVITY, unit="m/s^2")
"""Local gravity."""
NOISE_EXPORT_FORMATS = ("kalibr", "vins", "orbslam3", "openvins", "ekf2", "ekf3")
"""The estimators' noise files: ``export`` formats and ``allan`` options of the same names
(``station.export.writers.NOISE_FORMATS``, kept here so that --help loads no writer;
tests/test_estimator_noise.py checks the two agree)."""
INFLATE = number(float, 1.0, 1000.0)
"""``--inflate K``: the factor every noise value written for an estimator is multiplied by."""
EKF_RATE_HZ = number(float, 1.0, 10000.0, unit="Hz")
"""``--ekf-rate``: the rate of an autopilot EKF's prediction step."""


def protocol(text: str) -> str:
    """Validate ``--protocol NAME[:OPTION]``: a known decoder, an option it takes, its library there.

    Parameters
    ----------
    text : str
        The option's value, e.g. ``native``, ``auto``, ``xsens:hr`` or ``ascii:@50``.

    Returns
    -------
    str
        ``text`` unchanged.

    Raises
    ------
    argparse.ArgumentTypeError
        An unknown protocol, an option it does not take or cannot read, or a protocol whose
        library is not installed (MAVLink without pymavlink).
    """
    from protocols.registry import DECODER_OPTIONS, DECODERS, make_decoder
    from station.frames import reader  # noqa: F401  (installs the reader of --protocol frame:FILE.yaml)

    name = text.partition(":")[0]
    if name not in DECODERS and name not in DECODER_OPTIONS:
        raise argparse.ArgumentTypeError(f"unknown protocol {name!r}; known: {', '.join(sorted(DECODERS))}, "
                                         "frame:FILE.yaml")
    if name not in DECODERS and text == name:
        raise argparse.ArgumentTypeError(f"{name} needs its description file: {name}:FILE.yaml")
    try:
        make_decoder(text)
    except (ValueError, StationError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def port(text: str) -> str:
    """Validate ``--port``: a device path or a pyserial URL; ``sim://`` loads the simulated unit.

    Parameters
    ----------
    text : str
        The option's value.

    Returns
    -------
    str
        ``text`` unchanged, once pyserial knows the ``sim://`` scheme when it is one.

    Raises
    ------
    argparse.ArgumentTypeError
        An empty port name, or a ``sim://`` URL with an unknown or out-of-range option.
    """
    if not text.strip():
        raise argparse.ArgumentTypeError("give a device path (/dev/ttyUSB0) or a pyserial URL (sim://)")
    if text.startswith("sim://"):
        from mocks import register_sim_url  # the simulated unit, loaded only when asked for
        from mocks.protocol_sim import parse_sim_url

        try:
            parse_sim_url(text)  # its options are checked here, as every option is
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        register_sim_url()
    return text


def add_port_options(parser: argparse.ArgumentParser, *, required: bool = True,
                     port_group: argparse._ActionsContainer | None = None, port_help: str | None = None,
                     protocol_option: bool = True, baud: bool = True, repeat: bool = False) -> None:
    """Add ``--port``, ``--protocol`` and ``--baud``, the same for every command that opens a unit.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    required : bool
        ``--port`` must be given.
    port_group : argparse group, optional
        Where ``--port`` goes instead of ``parser`` (a mutually exclusive group with ``--simulate``).
    port_help : str, optional
        The help of ``--port`` when it differs from the usual one.
    protocol_option : bool
        Add ``--protocol`` too.
    baud : bool
        Add ``--baud`` too.
    repeat : bool
        ``--port`` may be given several times; the namespace holds the list.
    """
    (port_group or parser).add_argument(
        "--port", required=required, type=port, metavar="PORT", action="append" if repeat else "store",
        help=port_help or "serial device path (/dev/ttyUSB0, a pty), or pyserial URL (sim://, loop://)")
    if protocol_option:
        add_protocol_option(parser)
    if baud:
        parser.add_argument("--baud", type=BAUD, default=DEFAULT_BAUDRATE, metavar="BIT/S",
                            help=f"line speed of a real serial port, {describe_range(MIN_BAUD, MAX_BAUD)} "
                                 f"(default: {DEFAULT_BAUDRATE})")


def add_protocol_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--protocol NAME[:OPTION]``, validated by :func:`protocol` (default: native).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    """
    parser.add_argument("--protocol", default="native", type=protocol, metavar="NAME[:OPTION]",
                        help=f"wire protocol of the unit: {', '.join(PROTOCOLS)} (default: native); "
                             f"auto: recognise it from the first bytes. {', '.join(PROTOCOL_OPTIONS)} take "
                             f"an option: xsens:hr (the high-rate packets), mavlink:SCALED_IMU2 (which IMU "
                             f"message), ascii:COLUMNS@HZ, frame:FILE.yaml (a board's own frames described "
                             f"in YAML)")


def add_output_option(parser: argparse.ArgumentParser, *, required: bool = False, dest: str = "output",
                      metavar: str = "FILE", help: str = "file to write", **kwargs: Any) -> None:
    """Add ``-o``/``--output`` with its alias ``--out``, as a ``Path``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    required : bool
        The option must be given.
    dest : str
        Attribute of the parsed namespace.
    metavar, help : str
        As for ``add_argument``.
    **kwargs
        Passed on to ``add_argument`` (a default).
    """
    kwargs.setdefault("type", Path)
    parser.add_argument("-o", "--output", "--out", dest=dest, required=required, metavar=metavar, help=help,
                        **kwargs)


MAX_LOG_INSTANCE = 255
"""The largest IMU instance a log can name (ULog multi_id and DataFlash IMU.I are one byte)."""


def add_instance_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--instance N``: the IMU of a PX4 ULog (multi_id) or ArduPilot DataFlash log (IMU.I) to read.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    """
    parser.add_argument("--instance", type=number(int, 0, MAX_LOG_INSTANCE), metavar="N",
                        help="the IMU of a PX4 (.ulg) or ArduPilot (.bin) log, 0-based as the autopilot "
                             "numbers them (PX4 multi_id, ArduPilot IMU.I); needed when the log has several "
                             "(the command lists them)")


def serial_number(text: str) -> str:
    """Validate ``--serial``: a unit's serial as it would report it, 1 to 64 visible characters."""
    serial = text.strip()
    if not serial or len(serial) > 64 or not serial.isprintable():
        raise argparse.ArgumentTypeError("give the unit's serial, 1 to 64 visible characters")
    return serial


def add_replace_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--replace`` (start the parameter file afresh) and ``--serial`` (name the capture's unit).

    Without them a command merges its section into an existing file of the same unit and refuses
    (exit 4) a file holding another unit's results, and a file naming a unit when the capture names
    none (``station.export.params.file.open_for_unit``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    """
    parser.add_argument("--replace", action="store_true",
                        help="start the parameter file afresh, dropping its sections (needed to write "
                             "over a file that holds another unit's results)")
    parser.add_argument("--serial", type=serial_number, metavar="SN",
                        help="the serial of the unit the capture came from, for a capture that names none "
                             "(a capture CSV without '# serial:' metadata); needed to merge its results "
                             "into a parameter file that names a unit; refused if the capture names another")


def add_db_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--db``, the factory's record database (see :func:`db_url`).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    """
    parser.add_argument("--db", default=None, metavar="URL",
                        help="record database: a SQLite file path (default $IMU_STATION_DB or "
                             f"{DEFAULT_DB}) or postgresql://user@host/dbname")


def db_url(args: argparse.Namespace) -> str:
    """The record database: ``--db``, else ``$IMU_STATION_DB``, else :data:`DEFAULT_DB`.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (``db``).

    Returns
    -------
    str
        A SQLite file path or a ``postgresql://`` URL.
    """
    return args.db or os.environ.get("IMU_STATION_DB") or DEFAULT_DB


def files_root(args: argparse.Namespace, url: str) -> Path:
    """Where attachments go: --files, else beside a SQLite database, else ./imu-station-files.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (``files``).
    url : str
        The record database (:func:`db_url`).
    """
    if args.files is not None:
        return Path(args.files)
    if "://" in url and not url.startswith("sqlite:///"):
        return Path("imu-station-files")
    db = Path(url.removeprefix("sqlite:///"))
    return db.with_name(db.stem + "-files")


# ---- lab instruments the station drives by URL (station.instruments) ----------------------------

SUPPLY_MAX_V = 12.0
"""``--supply-max-v`` by default: an IMU's input range rarely goes further; more must be asked for."""
SUPPLY_MAX_A = 1.0
"""``--supply-max-a`` by default."""
SUPPLY_OFF_S = 2.0
"""``--supply-off`` by default (``station.instruments.power_cycle.OFF_S``)."""
TABLE_MOUNTS = ("+z", "-z", "+x", "-x", "+y", "-y")
"""The unit axes that can lie along a table's (inner) axis."""
MAX_TABLE_RATE_DPS = 1000.0
"""The fastest rate tables (an AC1120-class ACUTROL)."""
MAX_TABLE_ACCEL_DPS2 = 10_000.0
"""Far beyond what a table carrying an IMU is asked for."""
TABLE_ACCEL_DPS2 = 100.0
"""``--table-accel`` by default (``MountedTable``'s)."""


def add_supply_options(parser: argparse.ArgumentParser, *, help: str) -> None:
    """Add ``--supply URL`` and its settings, limits and off time, the same for every command that
    power-cycles the unit through a bench supply (``station.instruments.power_cycle``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    help : str
        What ``--supply`` does in this command.
    """
    parser.add_argument("--supply", metavar="URL", help=help)
    parser.add_argument("--supply-volts", type=number(float, 0.0, 1000.0), default=None, metavar="V",
                        help="the supply's voltage with --supply (default: as the supply is set)")
    parser.add_argument("--supply-amps", type=number(float, 0.0, 100.0), default=None, metavar="A",
                        help="the supply's current limit with --supply (default: as the supply is set)")
    parser.add_argument("--supply-max-v", type=number(float, 0.0, 1000.0), default=SUPPLY_MAX_V, metavar="V",
                        help=f"refuse a --supply-volts above this (default {SUPPLY_MAX_V:g})")
    parser.add_argument("--supply-max-a", type=number(float, 0.0, 100.0), default=SUPPLY_MAX_A, metavar="A",
                        help=f"refuse a --supply-amps above this (default {SUPPLY_MAX_A:g})")
    parser.add_argument("--supply-off", type=number(float, 0.05, 600.0), default=SUPPLY_OFF_S, metavar="S",
                        help="seconds the supply's output stays off at each power cycle "
                             f"(default {SUPPLY_OFF_S:g})")


def check_supply_options(args: argparse.Namespace) -> None:
    """Refuse supply settings without ``--supply``, or beyond their own limits, before anything opens.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options of :func:`add_supply_options`.

    Raises
    ------
    StationError
        ``--supply-volts`` or ``--supply-amps`` without ``--supply``, or above ``--supply-max-v`` or
        ``--supply-max-a`` (exit 4).
    """
    if args.supply is None and (args.supply_volts is not None or args.supply_amps is not None):
        raise StationError("--supply-volts and --supply-amps go with --supply URL")
    if args.supply_volts is not None:
        check_range("--supply-volts", args.supply_volts, 0.0, args.supply_max_v, unit="V",
                    what="a voltage within --supply-max-v,")
    if args.supply_amps is not None:
        check_range("--supply-amps", args.supply_amps, 0.0, args.supply_max_a, unit="A",
                    what="a current within --supply-max-a,")


def add_table_options(parser: argparse.ArgumentParser, *, help: str) -> None:
    """Add ``--table URL`` (a lab rate table, ``station.instruments.mounted_table``), the unit's mount
    on it and its rate and acceleration limits.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    help : str
        What ``--table`` does in this command.
    """
    parser.add_argument("--table", metavar="URL", help=help)
    parser.add_argument("--table-mount", default="+z", choices=TABLE_MOUNTS, metavar="AXIS",
                        help="the unit's axis along the table's (inner) axis: "
                             f"{', '.join(TABLE_MOUNTS)} (default +z)")
    parser.add_argument("--table-max-rate", type=positive("deg/s", MAX_TABLE_RATE_DPS), default=None,
                        metavar="DPS", help="refuse to turn the table faster than this (default: the table's "
                                            "own limit); a three-axis tilt keeps its peak within it too")
    parser.add_argument("--table-accel", type=positive("deg/s^2", MAX_TABLE_ACCEL_DPS2),
                        default=TABLE_ACCEL_DPS2, metavar="ACCEL",
                        help=f"the table's acceleration in deg/s^2, and the most it may be set to "
                             f"(default {TABLE_ACCEL_DPS2:g})")
