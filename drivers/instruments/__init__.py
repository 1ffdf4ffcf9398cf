"""Lab instruments beside the unit: climatic chambers, rate tables, bench supplies
(``shared/specs/instruments.md``).

Each is chosen by URL and spoken from a description (``description``): a line protocol
(``ascii``) or Modbus (``modbus``, through pymodbus). :func:`connect` opens one from its checked
description and the target its URL names; the station (``station.instruments``) reads the
description files, maps URL schemes to the shipped ones and wraps each instrument in the plan's
limits.
"""

from __future__ import annotations

from urllib.parse import parse_qsl, unquote

from drivers.instruments.ascii import AsciiSpeaker
from drivers.instruments.description import InstrumentDescription
from drivers.instruments.errors import InstrumentError
from drivers.instruments.kinds import KINDS, Chamber, Instrument, Supply, Table
from drivers.instruments.link import Link, SerialLink, SocketLink, is_network_target, split_host
from drivers.instruments.speaker import Speaker
from drivers.instruments.transcript import Transcript

__all__ = ["Chamber", "Instrument", "InstrumentError", "Supply", "Table", "Transcript", "connect",
           "parse_url"]


def parse_url(url: str) -> tuple[str, str, dict[str, str]]:
    """``scheme://TARGET?key=value`` as (scheme, target, options); TARGET is ``HOST[:PORT]``, a device path
    (``espec:///dev/ttyUSB0``) or a pyserial URL, percent-decoded."""
    if "://" not in url:
        raise InstrumentError(f"{url}: not an instrument URL; write SCHEME://TARGET, e.g. votsch://10.0.0.5 "
                              "or espec:///dev/ttyUSB0 (imu-station instrument --help lists the schemes)",
                              url)
    scheme, rest = url.split("://", 1)
    target, _, query = rest.partition("?")
    return scheme.lower(), unquote(target), dict(parse_qsl(query, keep_blank_values=True))


def open_link(target: str, description: InstrumentDescription, url: str) -> Link:
    """The byte link for an ASCII description: TCP for ``HOST[:PORT]``, else a serial port."""
    transport = description.link.transport
    network = is_network_target(target) if transport == "auto" else transport == "tcp"
    if network:
        host, port = split_host(target, description.link.tcp_port, url)
        return SocketLink(host, port, url)
    return SerialLink(target, description.link.baud, url)


def connect(url: str, target: str, description: InstrumentDescription, transcript: Transcript | None = None,
            channel: int | None = None) -> Instrument:
    """Open the instrument ``description`` describes at ``target``.

    Parameters
    ----------
    url : str
        The URL it was named by (carried in every message).
    target : str
        ``HOST[:PORT]``, a device path or a pyserial URL.
    description : InstrumentDescription
        Its checked description.
    transcript : Transcript, optional
        Where every exchange is written (a new one by default).
    channel : int, optional
        A supply's channel (selected before each command when given).

    Returns
    -------
    Instrument
        A :class:`Chamber`, :class:`Table` or :class:`Supply`.
    """
    speaker: Speaker
    if description.protocol == "modbus":
        from drivers.instruments.modbus import ModbusSpeaker, open_client  # pymodbus only for Modbus

        speaker = ModbusSpeaker(url, description, open_client(target, description, url), transcript)
    else:
        speaker = AsciiSpeaker(url, description, open_link(target, description, url), transcript)
    kind = KINDS[description.kind]
    return Supply(url, speaker, channel) if kind is Supply else kind(url, speaker)
