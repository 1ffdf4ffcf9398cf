"""Instruments by URL: ``votsch://10.0.0.5``, ``espec:///dev/ttyUSB0``, ``scpi://10.0.0.9?channel=2``.

The scheme names the shipped description (``station/instruments/descriptions/SCHEME.yaml``);
``?description=FILE.yaml`` replaces it with the user's own. Other options set the link:
``baud`` (serial), ``unit`` (Modbus unit id), ``timeout`` (s), ``channel`` (a supply's channel),
``axes`` (a table's axes, 1 to 3, where the controller drives more than its description says).
``sim://chamber``, ``sim://table`` and ``sim://supply`` name the simulated instruments served in
this process beside the simulated unit (``imu-station simulate --instruments``, ``run --simulate``),
which register themselves here with the URL of the emulator that speaks for them.
"""

from __future__ import annotations

import dataclasses
import threading

from drivers.instruments import Instrument, Transcript, connect, parse_url
from drivers.instruments.errors import InstrumentError
from station.errors import StationError
from station.instruments.reader import load_description, shipped_descriptions

SCHEMES = {
    "votsch": ("chamber", "Voetsch / Weiss S!MPAC simserv, TCP: votsch://HOST[:2049]"),
    "espec": ("chamber", "ESPEC SH/SU, serial: espec://PORT[?baud=9600]"),
    "watlow-f4": ("chamber", "Watlow F4 controller, Modbus RTU: watlow-f4://PORT[?baud=19200&unit=1]"),
    "binder": ("chamber", "Binder MB1, Modbus TCP: binder://HOST[:502][?unit=1]"),
    "acutrol": ("table", "Acutronic ACUTROL: acutrol://HOST:PORT or acutrol://PORT"),
    "aerosmith": ("table", "Ideal Aerosmith, serial: aerosmith://PORT[?baud=9600]"),
    "scpi": ("supply", "SCPI supply: scpi://HOST[:5025][?channel=N] or scpi://PORT"),
    "korad": ("supply", "Korad / Tenma KA3005P, serial: korad://PORT"),
}
"""URL scheme -> (kind, what it speaks and how it is written); each has a shipped description."""

OPTIONS = ("description", "baud", "unit", "timeout", "channel", "axes")

_simulated: dict[str, str] = {}
_simulated_lock = threading.Lock()


def register_simulated(kind: str, url: str | None) -> None:
    """Make ``sim://KIND`` name the emulator at ``url`` (None: no longer)."""
    with _simulated_lock:
        if url is None:
            _simulated.pop(kind, None)
        else:
            _simulated[kind] = url


def _number(url: str, options: dict[str, str], key: str, low: float, high: float) -> float | None:
    if key not in options:
        return None
    try:
        value = float(options[key])
    except ValueError:
        value = float("nan")
    if not low <= value <= high:
        raise StationError(f"{url}: ?{key}={options[key]} is not a number in {low:g}..{high:g}")
    return value


def open_instrument(url: str, transcript: Transcript | None = None, kind: str | None = None) -> Instrument:
    """Open the instrument ``url`` names.

    Parameters
    ----------
    url : str
        ``SCHEME://TARGET[?options]`` (see the module docstring).
    transcript : Transcript, optional
        Where every command and reply is written.
    kind : str, optional
        ``chamber``, ``table`` or ``supply``: refuse an instrument of another kind (a plan's
        ``chamber:`` naming a supply).

    Returns
    -------
    Instrument

    Raises
    ------
    StationError
        An unknown scheme or option, a description that cannot be read (exit 4), or an instrument
        that cannot be reached (exit 3).
    """
    scheme, target, options = parse_url(url)
    if scheme == "sim":
        with _simulated_lock:
            served = _simulated.get(target)
        if served is None:
            raise InstrumentError(f"{url}: no simulated {target or 'instrument'} runs in this process; "
                                  "use --simulate, or serve one with `imu-station simulate --instruments` "
                                  "and give the URL it prints", url)
        instrument = open_instrument(served, transcript, kind)
        instrument.url = url
        return instrument
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise StationError(f"{url}: unknown option ?{unknown[0]}=; known: {', '.join(OPTIONS)}")
    if scheme not in SCHEMES and "description" not in options:
        raise StationError(f"{url}: unknown instrument scheme '{scheme}://'; known: {', '.join(SCHEMES)}, sim://"
                           "chamber|table|supply (or any scheme with ?description=FILE.yaml)")
    if not target:
        raise StationError(f"{url}: give the instrument's address or port after {scheme}://")
    description = load_description(options.get("description") or shipped_descriptions()[scheme].stem)
    link = description.link
    baud = _number(url, options, "baud", 50, 12_000_000)
    unit = _number(url, options, "unit", 0, 247)
    timeout = _number(url, options, "timeout", 0.01, 60)
    link = dataclasses.replace(link, baud=int(baud) if baud is not None else link.baud,
                               unit=int(unit) if unit is not None else link.unit,
                               timeout_s=timeout if timeout is not None else link.timeout_s)
    axes = _number(url, options, "axes", 1, 3)
    description = dataclasses.replace(description, link=link,
                                      axes=int(axes) if axes is not None else description.axes)
    if kind is not None and description.kind != kind:
        raise StationError(f"{url}: is a {description.kind} ({description.name}), not a {kind}")
    channel = _number(url, options, "channel", 1, 99)
    return connect(url, target, description, transcript, int(channel) if channel is not None else None)
