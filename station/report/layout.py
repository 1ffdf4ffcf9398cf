"""How the certificate lays out what it lists: per-axis rows gathered into one line of x, y, z cells,
and the sequence a labelled capture ran, in words.

A cell holds one short figure (value \u00b1 1-sigma) and never a sentence: notes go under their table,
so a printed cell stays on one line.
"""

from __future__ import annotations

from typing import Any

from station.engines.calibration.common import pose_vector
from station.report.html import number, with_sigma
from station.report.parameters import AXES, Row


def grouped(rows: list[Row]) -> dict[str, Any]:
    """Per-axis rows as table lines: one line per quantity (per matrix row for ``xy``-style axes)
    with its x, y, z cells, or a single value spanning them; each quantity's note once, below.

    Parameters
    ----------
    rows : list of Row

    Returns
    -------
    dict
        ``rows``: list of ``{"quantity", "unit", "cells"}`` (``cells`` three texts, or one for a
        value that is not per axis); ``notes``: each different note once, as ``"quantity: note"``
        unless it names its subject itself (``"N = white noise"``).
    """
    lines: list[dict[str, Any]] = []
    by_key: dict[str, dict[str, Any]] = {}
    notes: dict[str, str] = {}
    for row in rows:
        if len(row.axis) == 2:
            key, column = f"{row.quantity}, row {row.axis[0]}", AXES.index(row.axis[1])
        elif row.axis in AXES and row.axis:
            key, column = row.quantity, AXES.index(row.axis)
        else:
            key, column = row.quantity, -1
        line = by_key.get(key)
        if line is None:
            line = {"quantity": key, "unit": row.unit, "cells": [] if column < 0 else [number(None)] * 3}
            by_key[key] = line
            lines.append(line)
        text = with_sigma(row.value, row.sigma)
        if column < 0:
            line["cells"] = [text]
        else:
            line["cells"][column] = text
        if row.note and row.note not in notes:
            notes[row.note] = row.note if " = " in row.note else f"{row.quantity}: {row.note}"
    return {"rows": lines, "notes": list(notes.values())}


def sequence_of(samples: Any) -> str:
    """The sequence a labelled capture ran, from its step labels: its static poses and its rotations.

    Parameters
    ----------
    samples : Samples
        A capture with ``segments()`` (label, slice).

    Returns
    -------
    str
        E.g. ``12 static poses (+x, -x, ...), 6 rotations (rot+x, ...)``; empty without labels.
    """
    poses: list[str] = []
    turns: list[str] = []
    for label, _ in samples.segments():
        if not label:
            continue
        target = poses if pose_vector(label) is not None else turns
        if label not in target:
            target.append(label)
    parts = []
    if poses:
        parts.append(f"{len(poses)} static poses ({', '.join(poses)})")
    if turns:
        parts.append(f"{len(turns)} rotations ({', '.join(turns)})")
    return ", ".join(parts) + (", from the labelled capture" if parts else "")
