"""Pure codecs: bytes to frames and back. No I/O, no threads; bad bytes never raise."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from protocols.base import SAMPLE_DTYPE, Decoded, DecoderStats, Message, StreamDecoderBase

__all__ = ["SAMPLE_DTYPE", "Decoded", "DecoderStats", "Message", "StreamDecoderBase"]


def __getattr__(name: str) -> Any:
    # protocols.base needs numpy: loaded when one of its names is used, not whenever a light module
    # of the package (errors, units) is imported, so that `imu-station --help` starts fast
    if name in __all__:
        return getattr(importlib.import_module("protocols.base"), name)
    raise AttributeError(f"module 'protocols' has no attribute {name!r}")
