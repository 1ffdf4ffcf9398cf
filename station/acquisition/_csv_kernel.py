"""The compiled parse of a capture CSV's sample rows (``capture_csv.iter_csv_chunks``).

``np.loadtxt`` parses about 6 M numbers a second and holds the GIL: 1.2 s of the 86 MB, one-million-row
ADIS16405 record, most of an ``imu-station allan`` run (issue 30). This loop reads the bytes of whole
lines straight into the chunk's array in about 0.2 s, and without the GIL (the Allan command's read-ahead
thread parses while the main thread sums the chunk before).

It reads only what it is sure to read as ``np.loadtxt`` would: fields ``[+-]digits[.digits][e[+-]digits]``
or ``nan``, ``,`` between them, every line of the header's field count and ending in ``\\n`` or
``\\r\\n``; the fields of columns the reader ignores may hold any printable ASCII but ``#``. Anything else
(a blank, ``inf``, a comment, a line of another width, more digits than below) stops it at that line,
and the caller reads from the start of the chunk the way it always has, with every message it gives.

Exactness: the digits from the first nonzero one to the last (at most 18) make an integer mantissa in
int64; when it is below 2**53 and the power of ten left is 1e22 or less, both are exact doubles and one
IEEE multiplication or division gives the correctly rounded value, the very double ``float()`` and
``np.loadtxt`` give (Clinger's fast path). That holds for every number the station writes (``%.9g``,
``%.6f``); others (17 significant digits of a shortest ``repr``, ``%.18e``) stop the loop as above.
"""

from __future__ import annotations

import numba
import numpy as np

POW10 = np.array([float(10**k) for k in range(23)])  # exact: every power of ten up to 1e22 is a double
MAX_MANTISSA = 1 << 53
MAX_DIGITS = 18  # significant digits kept in int64 before 2**53 is checked
POW10_INT = np.array([10**k for k in range(MAX_DIGITS + 1)], dtype=np.int64)

OK, FULL, ROOM, MORE, STOP = 0, 1, 2, 3, 4
"""Why :func:`parse_rows` returned: the buffer's whole lines are read (``OK``); the chunk holds its rows
or characters (``FULL``); ``out`` is full before the chunk is (``ROOM``: give a larger one); a line runs
past the buffer's end (``MORE``: read on); a line it does not read (``STOP``)."""


@numba.njit(nogil=True, cache=True, boundscheck=False)
def _number(buf: np.ndarray, p: int, end: int) -> tuple[float, int]:  # pragma: no cover - compiled
    """The number at ``p`` and the position after it, which the caller checks is a ``,`` or the line's
    end; position -1 for a field this loop does not read (the chunk goes to ``np.loadtxt``)."""
    negative = False
    c = buf[p] if p < end else 0
    if c == 43 or c == 45:  # '+', '-'
        negative = c == 45
        p += 1
    if p + 3 <= end and buf[p] == 110 and buf[p + 1] == 97 and buf[p + 2] == 110:  # 'nan'
        if negative or c == 43:
            return 0.0, -1  # '+nan', '-nan': left to np.loadtxt
        return np.nan, p + 3
    # value = mantissa * 10**(zeros - after_dot + exponent part): the digits without their leading and
    # trailing zeros, so that 25.000000 or 1000 cost their nonzero digits alone
    mantissa = 0
    digits = 0  # of the mantissa, from its first nonzero digit to its last
    zeros = 0  # zeros since the last nonzero digit, not (yet) in the mantissa
    seen = 0
    after_dot = 0
    dot = False
    while p < end:
        c = buf[p]
        if c == 46 and not dot:  # '.'
            dot = True
            p += 1
            continue
        if c < 48 or c > 57:
            break
        seen += 1
        after_dot += dot
        if c == 48:
            zeros += digits > 0
        else:
            digits += zeros + 1
            if digits > MAX_DIGITS:
                return 0.0, -1
            mantissa = mantissa * POW10_INT[zeros + 1] + (c - 48)
            zeros = 0
        p += 1
    if seen == 0:
        return 0.0, -1
    exponent = zeros - after_dot
    if p < end and (buf[p] == 101 or buf[p] == 69):  # 'e', 'E'
        p += 1
        sign = 1
        if p < end and (buf[p] == 43 or buf[p] == 45):
            sign = -1 if buf[p] == 45 else 1
            p += 1
        written = 0
        value = 0
        while p < end and 48 <= buf[p] <= 57:
            if value < 100000:
                value = value * 10 + (buf[p] - 48)
            written += 1
            p += 1
        if written == 0:
            return 0.0, -1
        exponent += sign * value
    if mantissa == 0:
        x = 0.0
    elif mantissa > MAX_MANTISSA or exponent < -22 or exponent > 22:
        return 0.0, -1
    elif exponent < 0:
        x = float(mantissa) / POW10[-exponent]
    else:
        x = float(mantissa) * POW10[exponent]
    return (-x if negative else x), p


@numba.njit(nogil=True, cache=True, boundscheck=False)
def parse_rows(buf: np.ndarray, pos: int, slots: np.ndarray, out: np.ndarray, row: int, chars: int,
               max_rows: int, max_chars: int, batch: int,
               max_line: int) -> tuple[int, int, int, int]:  # pragma: no cover - compiled
    """Parse whole lines of ``buf`` from ``pos`` into ``out`` from ``row`` on.

    Parameters
    ----------
    buf : ndarray of uint8
        The file's bytes from a line's start; its last line may be cut (``MORE``).
    pos : int
        Where the next line starts in ``buf``.
    slots : ndarray of int64
        For each field of a line, its column in ``out`` (-1: a field the reader ignores).
    out : ndarray, (rows, columns) float64
        The chunk's values so far, with room for more.
    row : int
        Rows of the chunk already read.
    chars : int
        Characters of the chunk's lines already read.
    max_rows : int
        The chunk is full at this many rows.
    max_chars, batch : int
        The chunk ends at the first multiple of ``batch`` rows whose lines hold ``max_chars`` characters
        (where the text reader checks them).
    max_line : int
        The longest line read, its end included.

    Returns
    -------
    tuple of int
        Rows of the chunk read, the position of the next line in ``buf``, characters of the chunk read,
        and the reason (``OK``, ``FULL``, ``ROOM``, ``MORE``, ``STOP``).
    """
    end = len(buf)
    fields = len(slots)
    while True:
        if row == max_rows or (row % batch == 0 and chars >= max_chars):
            return row, pos, chars, FULL
        if row == len(out):
            return row, pos, chars, ROOM
        if pos == end:
            return row, pos, chars, OK
        p = pos
        for j in range(fields):
            slot = slots[j]
            if slot >= 0:
                x, q = _number(buf, p, end)
                if q < 0:
                    break
                out[row, slot] = x
                p = q
            else:
                while p < end and 32 <= buf[p] < 127 and buf[p] != 44 and buf[p] != 35:  # ',' '#'
                    p += 1
            if p >= end:
                break
            c = buf[p]
            if j < fields - 1:
                if c != 44:
                    break
                p += 1
            elif c == 13 and p + 1 < end and buf[p + 1] == 10:  # '\r\n'
                p += 2
            elif c == 10:
                p += 1
            else:
                break
        else:
            if p - pos > max_line:
                return row, pos, chars, STOP
            chars += p - pos
            pos = p
            row += 1
            continue
        # the line was not read whole: cut by the buffer's end, or a line this loop leaves to np.loadtxt
        nl = pos
        while nl < end and buf[nl] != 10:
            nl += 1
        if nl == end and end - pos <= max_line:
            return row, pos, chars, MORE
        return row, pos, chars, STOP


def compile_now() -> None:
    """Compile :func:`parse_rows` now, for the argument types a capture read passes (numba caches it on
    disk): ``./scripts/setup`` calls it, so that the first long capture read after an install does not
    wait a second for the compiler."""
    buf = np.array(bytearray(b"1,2\n"), dtype=np.uint8)  # writable, as a read's buffer (another type else)
    parse_rows(buf, 0, np.arange(2, dtype=np.int64), np.empty((1, 2)), 0, 0, 1, 1 << 20, 1, 1 << 16)
