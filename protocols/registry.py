"""Decoders by protocol name, for ``--protocol`` options. Each protocol module registers here."""

from __future__ import annotations

from collections.abc import Callable

from protocols.base import StreamDecoderBase
from protocols.native import NativeDecoder

DECODERS: dict[str, Callable[[], StreamDecoderBase]] = {
    "native": NativeDecoder,
}


def make_decoder(name: str) -> StreamDecoderBase:
    try:
        return DECODERS[name]()
    except KeyError:
        raise ValueError(f"unknown protocol {name!r}; known: {', '.join(sorted(DECODERS))}") from None
