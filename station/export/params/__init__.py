"""The parameter file (schema ``imu-station/params/1``): reading, checking and writing it,
the sections each engine command writes, and the file as a plain JSON or YAML document.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.export.params.characterisation import merged as merged
    from station.export.params.characterisation import repeatability_keys as repeatability_keys
    from station.export.params.characterisation import scale_keys as scale_keys
    from station.export.params.file import SCHEMA as SCHEMA
    from station.export.params.file import SECTIONS as SECTIONS
    from station.export.params.file import ParamsFile as ParamsFile
    from station.export.params.file import UnitMismatchError as UnitMismatchError
    from station.export.params.file import gauss_markov_of as gauss_markov_of
    from station.export.params.file import merge_sections as merge_sections
    from station.export.params.file import open_for_unit as open_for_unit
    from station.export.params.file import sensor_to_dict as sensor_to_dict
    from station.export.params.file import to_plain as to_plain
    from station.export.params.file import unit_conflict as unit_conflict
    from station.export.params.magnetometer import mag_section as mag_section
    from station.export.params.noise import noise_section as noise_section
    from station.export.params.sections import MAG as MAG
    from station.export.params.sections import field_norm as field_norm
    from station.export.params.sections import g_sensitivity as g_sensitivity
    from station.export.params.sections import left_out as left_out
    from station.export.params.sections import mag_calibration as mag_calibration
    from station.export.params.sections import present as present

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "characterisation": ("merged", "repeatability_keys", "scale_keys"),
    "file": ("gauss_markov_of", "merge_sections", "open_for_unit", "ParamsFile", "SCHEMA", "SECTIONS",
             "sensor_to_dict", "to_plain", "unit_conflict", "UnitMismatchError"),
    "magnetometer": ("mag_section",),
    "noise": ("noise_section",),
    "sections": ("field_norm", "g_sensitivity", "left_out", "MAG", "mag_calibration", "present"),
})
