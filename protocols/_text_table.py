"""Text lines of numbers read in arrays: which lines have a dialect's form, and their numbers as a table.

The text decoder (``protocols/ascii_lines.py``) reads the well-formed lines of a chunk together. Two
steps cost the most when done a line (or a number) at a time, and are done here on the whole text:

- :func:`simple_table`: lines whose every field is a simple number (``[+-]`` digits with at most one
  dot, at most 15 characters): the integers of the text without its dots, read by numpy's C
  ``fromstring`` (integers parse an order of magnitude faster than doubles), each divided by ten to
  its count of decimals: the fast path below, for a read of a few dozen lines, where the others'
  fixed costs dominate;

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


_SIMPLE_BYTES = b"0123456789.+-"
_SIMPLE_CHARS = 15  # a field of at most 15 characters has at most 15 digits: exact, as _DIGITS
_ALL = np.logical_and.reduce  # ndarray.all without its Python wrapper
_ANY = np.logical_or.reduce
_MAX = np.maximum.reduce


def simple_table(text: bytes, n: int, delimiter: bytes, width: int,
                 integers: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """The numbers of the ``n`` lines of ``text`` (joined by ``\\n``, ``width`` fields each split by
    ``delimiter``, a byte of no number and no blank) as an (n, width) table in double, every line
    parsed, when every field is a simple number: ``[+-]`` then digits with at most one dot (none where
    ``integers``), at least one digit, at most 15 characters; else None (then :func:`number_table`, or
    the lines one by one, read them).

    Each number is the double ``float()`` (``int()`` where ``integers``) gives for its field: the field
    without its dot is an integer below 10**15, exact in double, and so is the power of ten it is
    divided by (Clinger's fast path; ``float("-0.0")`` is -0.0, restored where the integer is 0).
    numpy's ``fromstring`` reads the integers; what it would read where ``int()`` refuses (a lone sign,
    as 0) is refused before, what it refuses (an empty field, a sign inside one) it raises on.
    """
    if not n or delimiter in b" \t" or text.translate(None, _SIMPLE_BYTES + delimiter + b"\n"):
        return None
    plain = text.replace(b".", b"")
    if integers and len(plain) != len(text):
        return None
    try:
        ints = np.fromstring(plain.replace(b"\n", delimiter), dtype=np.int64, sep=delimiter.decode("ascii"))
    except ValueError:  # an empty field, a sign inside one
        return None
    raw = np.frombuffer(text, dtype=np.uint8)
    seps = ((raw == delimiter[0]) | (raw == 10)).nonzero()[0]
    if len(ints) != n * width or len(seps) != n * width - 1:
        return None
    ends = np.empty(len(seps) + 1, dtype=np.intp)  # each field's end
    ends[:-1] = seps
    ends[-1] = len(raw)
    if n > 1 and not _ALL(raw[ends[width - 1 : -1 : width]] == 10):
        return None  # a line of a field too many, another of one too few
    if ends[0] > _SIMPLE_CHARS or (n * width > 1 and _MAX(ends[1:] - ends[:-1]) > _SIMPLE_CHARS + 1):
        return None
    # A field ends with a digit, or a dot after one: else it is a lone sign ("-", "-."), read as 0.
    last = raw[ends - 1] - 48
    if not _ALL(last < 10):
        dotted = (last == 254).nonzero()[0]  # '.' - 48
        if len(dotted) != int(np.count_nonzero(last >= 10)) or not _ALL(raw[ends[dotted] - 2] - 48 < 10):
            return None
    dots = (raw == 46).nonzero()[0]  # '.'
    if len(dots):
        field = ends.searchsorted(dots)
        if len(dots) > 1 and not _ALL(field[1:] != field[:-1]):
            return None  # two dots in a field
        decimals = np.zeros(len(ends), dtype=np.intp)
        decimals[field] = ends[field] - dots - 1
        table = ints / _POW10[decimals]
    else:
        table = ints.astype(np.float64)
    zero = ints == 0
    if not integers and _ANY(zero):
        at = zero.nonzero()[0]
        starts = np.where(at > 0, ends[at - 1] + 1, 0)
        table[at[raw[starts] == 45]] = -0.0  # '-'
    return table.reshape(n, width), np.ones(n, dtype=bool)


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
