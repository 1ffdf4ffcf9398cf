"""Decoders by protocol name, for ``--protocol`` options. Each protocol module registers here."""

from __future__ import annotations

from collections.abc import Callable

from protocols.ascii_lines import AsciiDecoder
from protocols.base import StreamDecoderBase
from protocols.detect import AutoDecoder
from protocols.frame import decoder_from_option
from protocols.mavlink import MavlinkDecoder
from protocols.native import NativeDecoder
from protocols.xsens import XsensDecoder

DECODERS: dict[str, Callable[[], StreamDecoderBase]] = {
    "native": NativeDecoder,
    "xsens": XsensDecoder,
    "mavlink": MavlinkDecoder,  # needs pymavlink (extra "mavlink"); raises MavlinkUnavailable without
    "ascii": AsciiDecoder,
    "auto": AutoDecoder,  # recognises one of the above from the first bytes
}


# Decoders that take one option, given as ``name:option``: the CSV column spec and/or the rate of
# lines without a clock for ``ascii`` (``ascii:t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps``,
# ``ascii:@50``), the IMU message of ``mavlink`` (``mavlink:SCALED_IMU2``), the packets of ``xsens``
# that make the samples (``xsens:hr`` for AccelerationHR / RateOfTurnHR, ``xsens:normal``) and/or the
# local field that scales its normalised MagneticField to microtesla (``xsens:field=49.5``), the
# description file of a board's own frames for ``frame`` (``frame:board.yaml``, read by
# station.frames.reader).
DECODER_OPTIONS: dict[str, Callable[[str], StreamDecoderBase]] = {
    "ascii": AsciiDecoder.from_option,
    "xsens": XsensDecoder.from_option,
    "mavlink": lambda source: MavlinkDecoder(source=source),
    "frame": decoder_from_option,
}


def make_decoder(name: str) -> StreamDecoderBase:
    """The decoder of ``name`` (a key of ``DECODERS``), or of ``name:option`` (``DECODER_OPTIONS``)."""
    base, has_option, option = name.partition(":")
    if has_option:
        if base not in DECODER_OPTIONS:
            raise ValueError(f"protocol {base!r} takes no option (those that do: "
                             f"{', '.join(DECODER_OPTIONS)})")
        return DECODER_OPTIONS[base](option)
    try:
        return DECODERS[name]()
    except KeyError:
        raise ValueError(f"unknown protocol {name!r}; known: {', '.join(sorted(DECODERS))}") from None
