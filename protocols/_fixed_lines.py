"""Lines of one width read as a two-dimensional byte array: every number of a chunk in one matrix product.

Devices that print numbers in a fixed format (VectorNav's ``%+08.3f``, a sign always written, zeros in
front) send lines of one width, each number in the same columns. A chunk of such lines is then an
(n, width) byte array, and the text decoder (``protocols/ascii_lines.py``) reads it in a fixed few
numpy calls whatever n is, where splitting the lines and parsing the numbers field by field costs a
few microseconds a line (issue 30: 300,000 lines/s on 4 KiB reads of about 35 lines).

A :class:`FixedForm` is the layout of one well-formed line (its template): which columns hold digits, a
sign, a dot, and which bytes stand as they are (the head, delimiters, the line end). A line of the
chunk is read by the template when its bytes are of the same class column by column (a digit where the
template has a digit, ``+`` or ``-`` where it has a sign, the same byte elsewhere); any other line (a
damaged one) is left to the caller. Each number ``[+-]digits[.digits]`` of at most 15 digits is an
integer mantissa below 2**53 over a power of ten up to 1e15, both exact in double, so one IEEE division
gives the correctly rounded value, the very double ``float()`` gives (Clinger's fast path); the mantissa
is a sum of digits times powers of ten, integers below 2**53 whose sum is exact in any order, so a
matrix product computes it exactly.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

_DIGITS = 15  # at most this many digits a number: mantissa < 10**15 < 2**53, exact in double
_POW10 = 10.0 ** np.arange(_DIGITS + 1)
_SIMPLE = re.compile(rb"[+-]?[0-9]*\.?[0-9]*")
# The class of a byte: digits as '0', signs as '+', any other byte itself.
_CLASS = np.arange(256, dtype=np.uint8)
_CLASS[ord("0") : ord("9") + 1] = ord("0")
_CLASS[ord("-")] = ord("+")
# A hexadecimal digit's value; 255 for any other byte.
_HEX = np.full(256, 255, dtype=np.int32)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _HEX[_c] = _i
    _HEX[bytes([_c]).lower()[0]] = _i


@dataclass(frozen=True)
class FixedForm:
    """The layout of a line of fixed width: what :func:`read_fixed` checks and parses, column by column.

    ``stride`` is the line's bytes with its end, ``key`` the class of each byte up to the checksum (or
    the whole line and its end), ``weights`` the (width, fields) matrix of each digit's power of ten
    within its number, ``scale`` the power of ten each number is divided by (its digits after the dot),
    ``signs`` the columns of the signs and ``signed`` the numbers they belong to; ``star`` the column of
    the ``*`` before a two-digit checksum (the XOR of the bytes from column 1 to it), or 0; ``crlf``
    whether lines end in CR LF (else LF).
    """

    stride: int
    crlf: bool
    key: np.ndarray
    weights: np.ndarray
    offset: np.ndarray
    scale: np.ndarray
    signs: np.ndarray
    signed: np.ndarray
    star: int


def fixed_form(line: bytes, ending: bytes, head: int, checksum: bool, delimiter: bytes) -> FixedForm | None:
    """The template of ``line`` (without its ``ending``): a head of ``head`` bytes, numbers split by
    ``delimiter``, and (``checksum``) ``*`` and two hex digits; None when a field is not a simple number
    (``[+-]digits[.digits]``, 1 to 15 digits: an exponent, blanks or more digits go the slow way)."""
    tail = 3 if checksum else 0
    if ending not in (b"\n", b"\r\n") or len(line) < head + tail or len(delimiter) != 1:
        return None
    if checksum and line[-3:-2] != b"*":
        return None
    body = line[head : len(line) - tail]
    width = len(line)
    fields = body.split(delimiter)
    weights = np.zeros((width, len(fields)))
    scale = np.ones(len(fields))
    signs, signed = [], []
    col = head
    for j, field in enumerate(fields):
        digits = sum(c in b"0123456789" for c in field)
        if not _SIMPLE.fullmatch(field) or not 0 < digits <= _DIGITS:
            return None
        if field[:1] in (b"+", b"-"):
            signs.append(col)
            signed.append(j)
        power = digits
        for i, c in enumerate(field):
            if 48 <= c <= 57:
                power -= 1
                weights[col + i, j] = _POW10[power]
        dot = field.find(b".")
        scale[j] = _POW10[len(field) - dot - 1 if dot >= 0 else 0]
        col += len(field) + 1
    full = np.frombuffer(line + ending, dtype=np.uint8)
    key = _CLASS[full[: width - 2]] if checksum else _CLASS[full]
    return FixedForm(len(full), ending == b"\r\n", key.copy(), weights, 48.0 * weights.sum(axis=0), scale,
                     np.array(signs, dtype=np.intp), np.array(signed, dtype=np.intp),
                     width - 3 if checksum else 0)


def read_fixed(form: FixedForm, text: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """The numbers of the lines of ``text`` as an (n, fields) table, and which lines are of the form (the
    others hold garbage); None when ``text`` is not n lines of the form's width and line end."""
    n, rest = divmod(len(text), form.stride)
    if rest or not n:
        return None
    if text.count(b"\n") != n or text.count(b"\r") != (n if form.crlf else 0):
        return None  # a line break inside a line, or lines of another width
    rows = np.frombuffer(text, dtype=np.uint8).reshape(n, form.stride)
    # With n of each, every line's end in its place means no line holds a break of its own.
    if (rows[:, -1] != 10).any() or (form.crlf and (rows[:, -2] != 13).any()):
        return None
    if form.star:
        good = np.logical_and.reduce(_CLASS[rows[:, : len(form.key)]] == form.key, axis=1)
        sums = _HEX[rows[:, form.star + 1 : form.star + 3]]
        good &= np.bitwise_xor.reduce(rows[:, 1 : form.star], axis=1) == sums[:, 0] * 16 + sums[:, 1]
    else:
        good = np.logical_and.reduce(_CLASS[rows] == form.key, axis=1)
    width = len(form.weights)
    table = rows[:, :width].astype(np.float64) @ form.weights
    table -= form.offset
    table /= form.scale
    if len(form.signs):
        negative = rows[:, form.signs] == 45  # '-'
        part = table[:, form.signed]
        np.negative(part, out=part, where=negative)
        table[:, form.signed] = part
    return table, good
