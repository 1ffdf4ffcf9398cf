"""Pure codecs: bytes to frames and back. No I/O, no threads; bad bytes never raise."""

from protocols.base import SAMPLE_DTYPE, Decoded, DecoderStats, Message, StreamDecoderBase

__all__ = ["SAMPLE_DTYPE", "Decoded", "DecoderStats", "Message", "StreamDecoderBase"]
