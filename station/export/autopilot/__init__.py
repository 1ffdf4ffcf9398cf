"""The calibration as PX4 and ArduPilot parameters, with what each autopilot's model
cannot hold measured.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.export.autopilot.ardupilot import build_ardupilot as build_ardupilot
    from station.export.autopilot.ardupilot import render_ardupilot as render_ardupilot
    from station.export.autopilot.px4 import build_px4 as build_px4
    from station.export.autopilot.px4 import render_px4 as render_px4
    from station.export.autopilot.shared import DTEMP_POINTS as DTEMP_POINTS
    from station.export.autopilot.shared import FIT_POINTS as FIT_POINTS
    from station.export.autopilot.shared import GRID_POINTS as GRID_POINTS
    from station.export.autopilot.shared import GYRO_POSE_RATE as GYRO_POSE_RATE
    from station.export.autopilot.shared import MAG_UNIT as MAG_UNIT
    from station.export.autopilot.shared import NEGLIGIBLE as NEGLIGIBLE
    from station.export.autopilot.shared import NOMINAL_TEMP as NOMINAL_TEMP
    from station.export.autopilot.shared import POSE_NAMES as POSE_NAMES
    from station.export.autopilot.shared import AutopilotExport as AutopilotExport
    from station.export.autopilot.shared import CubicFit as CubicFit
    from station.export.autopilot.shared import InstanceCorrection as InstanceCorrection
    from station.export.autopilot.shared import InstanceOffsets as InstanceOffsets
    from station.export.autopilot.shared import Limitation as Limitation
    from station.export.autopilot.shared import MagCorrection as MagCorrection
    from station.export.autopilot.shared import Param as Param
    from station.export.autopilot.shared import TargetCorrection as TargetCorrection
    from station.export.autopilot.shared import assess as assess
    from station.export.autopilot.shared import assess_mag as assess_mag
    from station.export.autopilot.shared import finish_export as finish_export
    from station.export.autopilot.shared import fit_cubic as fit_cubic
    from station.export.autopilot.shared import limitations as limitations
    from station.export.autopilot.shared import misalignment_size as misalignment_size
    from station.export.autopilot.shared import polar as polar
    from station.export.autopilot.shared import reference_temp as reference_temp
    from station.export.autopilot.shared import rotation_angle as rotation_angle
    from station.export.autopilot.shared import sanitize_comment as sanitize_comment
    from station.export.autopilot.shared import six_poses as six_poses
    from station.export.autopilot.shared import symmetric_from as symmetric_from
    from station.export.autopilot.shared import symmetric_params as symmetric_params
    from station.export.autopilot.shared import thermal_intrinsics_loss as thermal_intrinsics_loss
    from station.export.autopilot.shared import thermal_range as thermal_range
    from station.export.autopilot.shared import vector_params as vector_params

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "ardupilot": ("build_ardupilot", "render_ardupilot"),
    "px4": ("build_px4", "render_px4"),
    "shared": ("assess", "assess_mag", "AutopilotExport", "CubicFit", "DTEMP_POINTS", "finish_export",
               "fit_cubic", "FIT_POINTS", "GRID_POINTS", "GYRO_POSE_RATE", "InstanceCorrection",
               "InstanceOffsets", "Limitation", "limitations", "MAG_UNIT", "MagCorrection",
               "misalignment_size", "NEGLIGIBLE", "NOMINAL_TEMP", "Param", "polar", "POSE_NAMES",
               "reference_temp", "rotation_angle", "sanitize_comment", "six_poses", "symmetric_from",
               "symmetric_params", "TargetCorrection", "thermal_intrinsics_loss", "thermal_range",
               "vector_params"),
})
