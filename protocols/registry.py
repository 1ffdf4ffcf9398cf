"""Decoders by protocol name, for ``--protocol`` options. Each protocol module registers here."""

from __future__ import annotations

from collections.abc import Callable

from protocols.ascii_lines import AsciiDecoder
from protocols.base import StreamDecoderBase
from protocols.detect import AutoDecoder
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


def make_decoder(name: str) -> StreamDecoderBase:
    try:
        return DECODERS[name]()
    except KeyError:
        raise ValueError(f"unknown protocol {name!r}; known: {', '.join(sorted(DECODERS))}") from None
