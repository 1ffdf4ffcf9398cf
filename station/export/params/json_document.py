"""The parameter file as a JSON or YAML document for tools without our reader.

The document is the parameter file itself (schema ``imu-station/params/1``, every section with
its derived keys: correction, scale, misalignment) plus an ``export`` block saying who wrote it
and when. Numbers are plain floats; a term the data did not show stays ``null``.
"""

from __future__ import annotations

import json
from typing import Any

import yaml

from station import __version__
from station.export.params.file import ParamsFile


def export_document(params: ParamsFile, station_id: str, exported: str) -> dict[str, Any]:
    """The parameter file as a document, with an ``export`` block naming the tool, station and time."""
    doc = params.to_dict()
    doc["export"] = {"tool": f"imu-station {__version__}", "station_id": station_id, "exported": exported}
    return doc


def render_json(params: ParamsFile, station_id: str, exported: str) -> str:
    """The export document as JSON text."""
    return json.dumps(export_document(params, station_id, exported), indent=2, allow_nan=False) + "\n"


def render_yaml(params: ParamsFile, station_id: str, exported: str) -> str:
    """The export document as YAML text."""
    return yaml.safe_dump(export_document(params, station_id, exported), sort_keys=False,
                          default_flow_style=None, width=120)
