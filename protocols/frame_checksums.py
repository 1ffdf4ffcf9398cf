"""The checksums a frame description may name (``specs/frame-description.md``), over many frames at once.

Every checksum is computed for all rows of a 2-D ``uint8`` array (one frame's covered bytes a row)
in numpy, so checking a buffer of frames costs a few passes over it and no Python loop per frame:

- sums and XOR are numpy reductions along the rows;
- CRCs are affine in the message bits, so for rows of a fixed width ``n`` a CRC is
  ``crc(0^n) ^ XOR_i T_i[byte_i]`` with one table of 256 entries per column (the native
  decoder's trick, ``protocols/native.py``); the tables are built once per width from the
  column-by-column definition, which is also used for widths too wide to tabulate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np


@dataclass(frozen=True)
class CrcModel:
    """A CRC in the Rocksoft model: width, polynomial, initial value and whether bits are reflected."""

    width: int
    poly: int
    init: int
    reflected: bool


CRC_MODELS: dict[str, CrcModel] = {
    "crc8": CrcModel(8, 0x07, 0x00, False),
    "crc16-ccitt-false": CrcModel(16, 0x1021, 0xFFFF, False),
    "crc16-xmodem": CrcModel(16, 0x1021, 0x0000, False),
    "crc16-modbus": CrcModel(16, 0x8005, 0xFFFF, True),
    "crc32": CrcModel(32, 0x04C11DB7, 0xFFFFFFFF, True),  # IEEE 802.3, as zlib: xorout 0xFFFFFFFF
}
CRC32_XOROUT = 0xFFFFFFFF

# Bytes of the checksum field of each type.
CHECKSUM_SIZES: dict[str, int] = {
    "none": 0, "sum8": 1, "xor8": 1, "sum16": 2, "crc8": 1, "crc16-ccitt-false": 2, "crc16-xmodem": 2,
    "crc16-modbus": 2, "crc32": 4,
}
CHECKSUM_TYPES = tuple(CHECKSUM_SIZES)

# Widest rows tabulated (a table is width * 256 entries); wider rows go column by column.
_MAX_TABLE_WIDTH = 128


def _reflect(value: int, bits: int) -> int:
    return int(f"{value:0{bits}b}"[::-1], 2)


@cache
def _byte_table(name: str) -> np.ndarray:
    """The classic 256-entry table of a CRC: the register after one byte shifted through it."""
    model = CRC_MODELS[name]
    dtype = np.uint32 if model.width > 16 else (np.uint16 if model.width > 8 else np.uint8)
    mask = (1 << model.width) - 1
    table = np.zeros(256, dtype=dtype)
    if model.reflected:
        poly = _reflect(model.poly, model.width)
        for byte in range(256):
            crc = byte
            for _ in range(8):
                crc = (crc >> 1) ^ poly if crc & 1 else crc >> 1
            table[byte] = crc
    else:
        top = 1 << (model.width - 1)
        for byte in range(256):
            crc = byte << (model.width - 8)
            for _ in range(8):
                crc = ((crc << 1) ^ model.poly) & mask if crc & top else (crc << 1) & mask
            table[byte] = crc
    return table


def _crc_columns(name: str, rows: np.ndarray) -> np.ndarray:
    """A CRC of every row, one column at a time (the loop runs over the frame's width, not its count)."""
    model = CRC_MODELS[name]
    table = _byte_table(name)
    dtype = table.dtype.type
    crc = np.full(rows.shape[0], model.init, dtype=table.dtype)
    shift = dtype(model.width - 8)
    eight = dtype(8)
    for col in range(rows.shape[1]):
        byte = rows[:, col].astype(table.dtype)
        if model.reflected:
            crc = (crc >> eight) ^ table[(crc ^ byte) & dtype(0xFF)]
        elif model.width == 8:
            crc = table[crc ^ byte]
        else:
            crc = (crc << eight) ^ table[((crc >> shift) ^ byte) & dtype(0xFF)]
    if name == "crc32":
        crc ^= dtype(CRC32_XOROUT)
    return crc


@cache
def _affine_tables(name: str, width: int) -> tuple[int, np.ndarray, np.ndarray]:
    """``(crc of width zero bytes, flat per-column tables, each column's offset into them)``."""
    zero = np.zeros((1, width), dtype=np.uint8)
    base = _crc_columns(name, zero)[0]
    unit = np.zeros((width, 256, width), dtype=np.uint8)
    for col in range(width):
        unit[col, :, col] = np.arange(256)
    tables = _crc_columns(name, unit.reshape(-1, width)) ^ base
    offsets = np.arange(width, dtype=np.uint16 if width <= 256 else np.uint32) * 256
    return int(base), tables, offsets


def crc_rows(name: str, rows: np.ndarray) -> np.ndarray:
    """The CRC ``name`` (a key of :data:`CRC_MODELS`) of every row of a 2-D ``uint8`` array.

    Parameters
    ----------
    name : str
        ``crc8``, ``crc16-ccitt-false``, ``crc16-xmodem``, ``crc16-modbus`` or ``crc32``.
    rows : numpy.ndarray
        ``(frames, bytes)`` of ``uint8``.

    Returns
    -------
    numpy.ndarray
        One unsigned CRC per row.
    """
    width = rows.shape[1]
    if width == 0 or width > _MAX_TABLE_WIDTH:
        return _crc_columns(name, rows)
    base, tables, offsets = _affine_tables(name, width)
    looked_up = tables.take(rows + offsets)  # uint8 + uint16 offsets: uint16 indices, no cast
    return np.bitwise_xor.reduce(looked_up, axis=1) ^ tables.dtype.type(base)


def _sum8(rows: np.ndarray) -> np.ndarray:
    return rows.sum(axis=1, dtype=np.uint8)


def _sum16(rows: np.ndarray) -> np.ndarray:
    return rows.sum(axis=1, dtype=np.uint16)


def _xor8(rows: np.ndarray) -> np.ndarray:
    return np.bitwise_xor.reduce(rows, axis=1) if rows.shape[1] else np.zeros(len(rows), np.uint8)


_FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {"sum8": _sum8, "sum16": _sum16, "xor8": _xor8}


def checksum_rows(name: str, rows: np.ndarray) -> np.ndarray:
    """The checksum ``name`` (any of :data:`CHECKSUM_TYPES` but ``none``) of every row.

    Parameters
    ----------
    name : str
        The checksum type as a frame description names it.
    rows : numpy.ndarray
        ``(frames, bytes)`` of ``uint8``: the covered bytes of each frame.

    Returns
    -------
    numpy.ndarray
        One unsigned value per row, of the checksum's width.
    """
    if name in _FUNCTIONS:
        return _FUNCTIONS[name](rows)
    return crc_rows(name, rows)


class RowChecksum:
    """:func:`checksum_rows` of one checksum over rows of one width, its work arrays kept between calls.

    A decoder fed by a serial port checks a hundred or so frames a call, where allocating the index and
    lookup arrays costs as much as the arithmetic: a decoder keeps one of these (they are not shared
    between threads). Values are those of :func:`checksum_rows`.

    Parameters
    ----------
    name : str
        The checksum type (any of :data:`CHECKSUM_TYPES` but ``none``).
    width : int
        The number of bytes each row covers.
    """

    def __init__(self, name: str, width: int):
        self.name = name
        self.tabled = name not in _FUNCTIONS and 0 < width <= _MAX_TABLE_WIDTH
        if self.tabled:
            base, self.tables, self.offsets = _affine_tables(name, width)
            self.base = self.tables.dtype.type(base)
            self._index = np.empty((0, width), dtype=self.offsets.dtype)
            self._looked_up = np.empty((0, width), dtype=self.tables.dtype)

    def __call__(self, rows: np.ndarray) -> np.ndarray:
        """The checksum of every row of ``rows`` (``(frames, width)`` of ``uint8``).

        Parameters
        ----------
        rows : numpy.ndarray
            The covered bytes of each frame.

        Returns
        -------
        numpy.ndarray
            One unsigned value per row, of the checksum's width (a new array).
        """
        if not self.tabled:
            return checksum_rows(self.name, rows)
        n = len(rows)
        if len(self._index) < n:
            self._index = np.empty((n, rows.shape[1]), dtype=self._index.dtype)
            self._looked_up = np.empty((n, rows.shape[1]), dtype=self._looked_up.dtype)
        index = np.add(rows, self.offsets, out=self._index[:n])
        # The indices are in range by construction (a byte plus its column's offset): no bounds check.
        looked_up = self.tables.take(index, out=self._looked_up[:n], mode="clip")
        out = np.bitwise_xor.reduce(looked_up, axis=1)
        out ^= self.base
        return out


def checksum(name: str, data: bytes) -> int:
    """The checksum ``name`` of one run of bytes (for encoders and tests).

    Parameters
    ----------
    name : str
        The checksum type.
    data : bytes
        The covered bytes.

    Returns
    -------
    int
        Its value.
    """
    rows = np.frombuffer(data, dtype=np.uint8).reshape(1, len(data))
    return int(checksum_rows(name, rows)[0])
