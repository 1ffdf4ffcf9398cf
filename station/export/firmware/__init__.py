"""The calibration for firmware: C99 source and header, and the CRC-checked parameter blob
(``shared/specs/firmware-api.md``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.export.firmware.blob import CARRIED as CARRIED
    from station.export.firmware.blob import FLAG_MAG as FLAG_MAG
    from station.export.firmware.blob import SERIAL_SIZE as SERIAL_SIZE
    from station.export.firmware.blob import STATION_ID_SIZE as STATION_ID_SIZE
    from station.export.firmware.blob import BlobError as BlobError
    from station.export.firmware.blob import build_blob as build_blob
    from station.export.firmware.blob import fixed_utf8 as fixed_utf8
    from station.export.firmware.blob import parse_blob as parse_blob
    from station.export.firmware.c_source import BLOB_NAME as BLOB_NAME
    from station.export.firmware.c_source import DEFAULT_MAX_SEGMENTS as DEFAULT_MAX_SEGMENTS
    from station.export.firmware.c_source import c_comment_text as c_comment_text
    from station.export.firmware.c_source import c_string_literal as c_string_literal
    from station.export.firmware.c_source import write_c_export as write_c_export

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "blob": ("BlobError", "build_blob", "CARRIED", "fixed_utf8", "FLAG_MAG", "parse_blob", "SERIAL_SIZE",
             "STATION_ID_SIZE"),
    "c_source": ("BLOB_NAME", "c_comment_text", "c_string_literal", "DEFAULT_MAX_SEGMENTS",
                 "write_c_export"),
})
