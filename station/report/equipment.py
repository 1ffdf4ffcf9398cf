"""What a certificate says about the bench: the reference equipment (the instruments of the run, with
their identity, and the reference values the fit was scaled to) and the ambient conditions, each where
known. Nothing is invented: what is not recorded is said to be so.

Sources, in order: a factory record's ``instrument.KIND`` measurements (identity and URL, written when
the run opened its bench) or, failing those, its ``instruments.json`` attachment (read only from inside
the record's folder); the plan's instrument URLs (``--plan``: named, not identified); the ``mag``
section's field source (the geomagnetic model and place); the record's chamber measurements; the unit's
own temperature over each capture given.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from station.factory.records import RunRecord
from station.report.html import number

INSTRUMENTS_ATTACHMENT = "instruments"
MAX_INSTRUMENTS_BYTES = 4 << 20  # the identities come first; a long transcript is not read for them
KIND_NAMES = {"chamber": "climatic chamber", "table": "rate table", "supply": "power supply"}


class Captured(Protocol):
    """What this module reads of a capture given to the certificate."""

    path: str
    samples: Any


@dataclass(frozen=True)
class Equipment:
    """One line of the reference equipment: what it is, its identity (as it answered), where it was."""

    what: str
    identity: str
    where: str


def equipment(record: RunRecord | None, plan: dict[str, Any], mag: dict[str, Any] | None) -> list[Equipment]:
    """The instruments of the run and the reference values the calibration rests on.

    Parameters
    ----------
    record : RunRecord or None
        A factory run's record (its instruments as identified).
    plan : dict
        The plan as the certificate knows it; ``instruments`` maps a kind to its URL.
    mag : dict or None
        The ``mag`` section (its ``field_source`` names the reference field).

    Returns
    -------
    list of Equipment
    """
    found: dict[str, Equipment] = {}
    if record is not None:
        for m in record.measurements().values():
            if m.name.startswith("instrument."):
                kind = m.name.split(".", 1)[1]
                found[kind] = Equipment(KIND_NAMES.get(kind, kind), str(m.value), m.doc)
        if not found:
            for kind, seen in _instruments_file(record).items():
                identity = str(seen.get("identity") or "not identified")
                found[kind] = Equipment(KIND_NAMES.get(kind, kind), identity, str(seen.get("url") or ""))
    for kind, url in (plan.get("instruments") or {}).items():
        if kind not in found and url:
            found[kind] = Equipment(KIND_NAMES.get(kind, kind), "named by the plan, not identified", str(url))
    out = list(found.values())
    if isinstance(mag, dict) and mag.get("field_source"):
        field = mag.get("field_norm")
        shown = f"{float(field):.1f} uT" if isinstance(field, int | float) else "field"
        out.append(Equipment("reference magnetic field", f"{shown} from {mag['field_source']}", ""))
    return out


def _instruments_file(record: RunRecord) -> dict[str, dict[str, Any]]:
    """The identities in the record's ``instruments.json``; empty when absent, outside the record's
    folder, too large or not what the runner writes."""
    attached = next((a for a in record.attachments() if a.name == INSTRUMENTS_ATTACHMENT), None)
    path = record.attachment_file(attached) if attached is not None else None
    if path is None or not path.is_file() or path.stat().st_size > MAX_INSTRUMENTS_BYTES:
        return {}
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    found = doc.get("instruments") if isinstance(doc, dict) else None
    if not isinstance(found, dict):
        return {}
    return {str(k): v for k, v in found.items() if isinstance(v, dict)}


def ambient(record: RunRecord | None, captures: Sequence[Captured],
            roles: dict[str, str]) -> list[dict[str, str]]:
    """The conditions known: the record's chamber measurements and the unit's own temperature over each
    capture (its internal sensor: the unit's temperature, near the air's only after a soak).

    Parameters
    ----------
    record : RunRecord or None
    captures : list
        The captures given (``path``, ``samples`` with ``temp``).
    roles : dict
        A capture's path to what the calibration used it for (``accel``, ``thermal`` ...).

    Returns
    -------
    list of dict
        ``what``, ``value`` and ``source`` per line.
    """
    out = []
    if record is not None:
        for m in record.measurements().values():
            if m.name.startswith(("chamber.", "ambient.")) and isinstance(m.value, int | float):
                out.append({"what": m.name, "value": f"{number(m.value)} {m.unit}".strip(),
                            "source": "factory record"})
    for capture in captures:
        temp = getattr(capture.samples, "temp", None)
        if temp is None:
            continue
        temp = np.asarray(temp, float)
        temp = temp[np.isfinite(temp)]
        if temp.size == 0:
            continue
        role = roles.get(capture.path, "capture")
        out.append({"what": f"unit temperature during the {role} capture",
                    "value": f"{temp.min():.1f} to {temp.max():.1f} degC (mean {temp.mean():.1f})",
                    "source": Path(capture.path).name})  # the whole path is in the data table
    return out
