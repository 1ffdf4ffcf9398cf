"""Text lines of numbers read in arrays: which lines have a dialect's form, and their numbers as a table.

The text decoder (``protocols/ascii_lines.py``) reads the well-formed lines of a chunk together. Two
steps cost the most when done a line (or a number) at a time, and are done here on the whole text:

- :func:`form_mask`: which lines are a head, fields of number characters with the right count of
  delimiters, and a tail (as the decoder's regular expression of the dialect, line for line);
- :func:`number_table`: the decimal numbers of those lines. A field ``[+-]digits[.digits]`` of at
  most 15 digits is an integer mantissa below 2**53 and a power of ten up to 1e15, both exact in
  double, so one IEEE division gives the correctly rounded value, the very double ``float()`` gives
  (Clinger's fast path). Other fields (an exponent, blanks, more digits) go through ``float()`` or
  ``int()`` one by one, as the line-by-line reader reads them.
"""

from __future__ import annotations

import numpy as np

_DIGITS = 15  # at most this many digits: mantissa < 10**15 < 2**53, exact in double
_POW10 = 10.0 ** np.arange(_DIGITS + 1)
# Per-byte codes whose sums over a field (or a line) count four kinds of byte at once, 16 bits each:
# digits, dots, signs, others (bytes no simple number holds). A field is at most a line (max_line
# bytes, well below 2**16), so the lanes never carry into each other; the running sum may wrap
# (uint64) but differences of it are exact.
_DIGIT, _DOT, _SIGN, _OTHER = 1, 1 << 16, 1 << 32, 1 << 48
_LANE = 0xFFFF


def _field_codes(delimiter: int) -> np.ndarray:
    codes = np.full(256, _OTHER, dtype=np.uint64)
    codes[ord("0") : ord("9") + 1] = _DIGIT
    codes[ord(".")] = _DOT
    codes[ord("+")] = codes[ord("-")] = _SIGN
    codes[delimiter] = codes[10] = 0  # separators: counted apart
    return codes


_CODES: dict[int, np.ndarray] = {}


def number_table(lines: list[bytes], delimiter: bytes, width: int,
                 integers: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The numbers of ``lines`` (``width`` fields split by ``delimiter``) as an (n, width) table in
    double, and which lines parsed (a line that did not holds NaN); None when the lines do not all
    have ``width`` fields.

    Each number is the double ``float()`` (``int()`` where ``integers``: MotionCal's counts) gives
    for its field; a field neither accepts makes its line fail.
    """
    n = len(lines)
    sep = delimiter[0]
    codes = _CODES.get(sep)
    if codes is None:
        codes = _CODES[sep] = _field_codes(sep)
    text = b"\n".join(lines) + b"\n"
    raw = np.frombuffer(text, dtype=np.uint8)
    ends = np.flatnonzero((raw == sep) | (raw == 10))  # each field's end: its separator
    if len(ends) != n * width:
        return None
    newline = raw[ends[width - 1 :: width]] == 10
    if not newline.all() or (width > 1 and (raw[ends.reshape(n, width)[:, :-1]] == 10).any()):
        return None
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    running = np.zeros(len(raw) + 1, dtype=np.uint64)
    np.cumsum(codes[raw], out=running[1:])
    counts = running[ends] - running[starts]
    digits = (counts & _LANE).astype(np.intp)
    dots = (counts >> 16) & _LANE
    signs = (counts >> 32) & _LANE
    first = raw[np.minimum(starts, len(raw) - 1)]
    signed = (first == 43) | (first == 45)  # '+', '-'
    simple = ((counts >> 48) == 0) & (digits > 0) & (digits <= _DIGITS) & (dots <= 1) & (signs == signed)
    if integers:
        simple &= dots == 0
    # The mantissa: every digit times ten to the number of digits after it in its field.
    raw_digits = raw - 48
    is_digit = raw_digits < 10
    values = raw_digits[is_digit].astype(np.float64)
    field = np.repeat(np.arange(len(ends)), digits)
    last = np.cumsum(digits) - 1  # the digit index of each field's last digit
    after = last[field] - np.arange(len(values))
    np.minimum(after, _DIGITS, out=after)  # fields of more digits are not simple: any power will do
    mantissa = np.bincount(field, weights=values * _POW10[after], minlength=len(ends))
    # Digits after the dot: those between it and its field's end.
    frac = np.zeros(len(ends), dtype=np.intp)
    at_dot = np.flatnonzero(raw == 46)
    if len(at_dot):
        dot_field = np.searchsorted(ends, at_dot)
        running_digits = np.cumsum(is_digit, dtype=np.intp)
        frac[dot_field] = running_digits[ends[dot_field] - 1] - running_digits[at_dot]
    np.minimum(frac, _DIGITS, out=frac)
    table = mantissa / _POW10[frac]
    np.negative(table, out=table, where=first == 45)
    if integers:
        table += 0.0  # int("-0") is 0: no negative zero (-0.0 + 0.0 is 0.0)
    good = np.ones(n, dtype=bool)
    if not simple.all():
        parse = int if integers else float
        for i in np.flatnonzero(~simple).tolist():
            try:
                table[i] = parse(text[starts[i] : ends[i]])
            except (ValueError, OverflowError):  # OverflowError: an integer beyond double
                good[i // width] = False
    table = table.reshape(n, width)
    table[~good] = np.nan
    return table, good


_LINE_CODES: dict[tuple[bytes, bytes], np.ndarray] = {}
_HEX_PAIRS = frozenset(f"{a}{b}".encode() for a in "0123456789ABCDEFabcdef" for b in "0123456789ABCDEFabcdef")


def form_mask(lines: list[bytes], head: bytes, chars: bytes, delimiter: bytes, fields: int,
              checksum: bool) -> np.ndarray:
    """Which ``lines`` are ``head``, ``fields`` fields of ``chars`` (the characters of numbers) split by
    ``delimiter``, and (``checksum``) ``*`` and two hex digits: the dialect's form as the text decoder's
    regular expression has it, for all lines at once."""
    codes = _LINE_CODES.get((chars, delimiter))
    if codes is None:
        codes = np.ones(256, dtype=np.int64)  # other bytes: one each, delimiters 1 << 32
        codes[np.frombuffer(chars, dtype=np.uint8)] = 0
        codes[delimiter[0]] = 1 << 32
        _LINE_CODES[(chars, delimiter)] = codes
    text = b"\n".join(lines)
    raw = np.frombuffer(text, dtype=np.uint8)
    lengths = np.fromiter(map(len, lines), dtype=np.intp, count=len(lines))
    starts = np.cumsum(lengths + 1) - lengths - 1
    tail = 3 if checksum else 0
    lo = starts + np.minimum(len(head), lengths)  # a line shorter than its head: inside it all the same
    hi = np.maximum(starts + lengths - tail, lo)
    running = np.zeros(len(raw) + 1, dtype=np.int64)
    np.cumsum(codes[raw], out=running[1:])
    counts = running[hi] - running[lo]
    ok = (counts == (fields - 1) << 32) & (lengths >= len(head) + tail)
    if head:
        ok &= np.fromiter((line.startswith(head) for line in lines), dtype=bool, count=len(lines))
    if checksum:
        ok &= np.fromiter((line[-3:-2] == b"*" and line[-2:] in _HEX_PAIRS for line in lines), dtype=bool,
                          count=len(lines))
    return ok
