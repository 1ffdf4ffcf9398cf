"""Plain-text tables for a command's printed report: a title, a header, a rule and aligned columns.

A command that prints a few small tables once pays nothing for them here; rich's tables cost the
calibrate command 20 ms to import and 17 ms to lay out on a quiet machine (docs/methods/speed.md).
"""

from __future__ import annotations

from collections.abc import Sequence


def format_table(title: str, header: Sequence[str], rows: Sequence[Sequence[str]],
                 right: Sequence[bool] | None = None, rule: bool = True) -> str:
    """The table as lines of text: the title, the header, a rule of dashes under each column, the rows.

    Parameters
    ----------
    title : str
        The line above the table (left out when empty).
    header : sequence of str
        One name per column.
    rows : sequence of sequences of str
        The cells, one row per sequence, as many cells as ``header`` has names.
    right : sequence of bool, optional
        Per column, True to align the column to the right (numbers); default all to the left.
    rule : bool
        The rule of dashes under the header (False: none).

    Returns
    -------
    str
        The table without a trailing newline; columns two spaces apart, trailing blanks removed.

    Raises
    ------
    ValueError
        A row with more or fewer cells than the header.
    """
    table = [list(header), *(list(row) for row in rows)]
    for row in table[1:]:
        if len(row) != len(header):
            raise ValueError(f"a row of {len(row)} cells in a table of {len(header)} columns: {row}")
    widths = [max(len(row[i]) for row in table) for i in range(len(header))]
    flags = list(right) if right is not None else [False] * len(header)

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.rjust(w) if r else c.ljust(w) for c, w, r in zip(cells, widths, flags, strict=True)
                         ).rstrip()

    lines = [title] if title else []
    lines += [line(table[0]), *([line(["-" * w for w in widths])] if rule else []),
              *(line(row) for row in table[1:])]
    return "\n".join(lines)
