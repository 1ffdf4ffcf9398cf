"""Checksums of the native protocol (CRC-16/CCITT-FALSE) and of parameter blobs (CRC-32)."""

from __future__ import annotations

import binascii
import zlib

import numpy as np

CRC16_POLY = 0x1021
CRC16_INIT = 0xFFFF


def _crc16_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint16)
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC16_POLY) if crc & 0x8000 else (crc << 1)
        table[byte] = crc & 0xFFFF
    return table


CRC16_TABLE = _crc16_table()
_TABLE_LIST = [int(v) for v in CRC16_TABLE]


def crc16_ccitt_false(data: bytes | bytearray | memoryview, crc: int = CRC16_INIT) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0 (with ``crc=0``: XMODEM).

    The standard library's ``binascii.crc_hqx`` is this very CRC from a given start value, in C: a
    decoder checks a candidate frame per false start in sync-rich garbage, so the cost per byte counts
    (a byte-at-a-time loop in Python ran at a few MB/s; ``crc16_bytewise`` keeps it as the reference).
    """
    return binascii.crc_hqx(data, crc)


def crc16_bytewise(data: bytes, crc: int = CRC16_INIT) -> int:
    """:func:`crc16_ccitt_false` a byte at a time from the table: the reference the tests compare with."""
    table = _TABLE_LIST
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


def crc16_rows(rows: np.ndarray) -> np.ndarray:
    """CRC-16/CCITT-FALSE of every row of a 2-D uint8 array, vectorised over rows.

    One table look-up per column, done for all rows at once: the loop runs over the
    (short) frame length, never over the (long) number of frames.
    """
    crc = np.full(rows.shape[0], CRC16_INIT, dtype=np.uint16)
    for col in range(rows.shape[1]):
        idx = (crc >> 8) ^ rows[:, col]
        crc = (crc << 8) ^ CRC16_TABLE[idx]
    return crc


def crc32(data: bytes) -> int:
    """CRC-32 (IEEE 802.3), as zlib computes it."""
    return zlib.crc32(data) & 0xFFFFFFFF
