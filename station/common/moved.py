"""Modules that moved when the house was arranged by subject (issue 29), importable by their old
names for one release with a DeprecationWarning.

``import station.engines.allan_fit`` still works: a finder on ``sys.meta_path`` answers for every old
name below with the module that now holds its code (the same module object, so a monkeypatch through
the old name reaches the code that runs), after a warning naming the new path. Three old modules
became packages of the same name (``station.engines.allan``, ``station.engines.thermal``,
``station.export.autopilot``); those packages name the old modules' public names themselves. The
list is in the changelog; this module goes in the release after.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import sys
import warnings
from types import ModuleType
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from importlib.abc import Loader

MOVED = {
    "station.engines.allan_equivalent": "station.engines.allan.equivalent",
    "station.engines.allan_fit": "station.engines.allan.fit",
    "station.engines.allan_kernel": "station.engines.allan._kernel",
    "station.engines.allan_ml": "station.engines.allan.likelihood",
    "station.engines.allan_model": "station.engines.allan.model",
    "station.engines.allan_terms": "station.engines.allan.terms",
    "station.engines.calibration_common": "station.engines.calibration.common",
    "station.engines.calibration_free": "station.engines.calibration.free",
    "station.engines.calibration_free_accel": "station.engines.calibration.free_accel",
    "station.engines.calibration_free_gyro": "station.engines.calibration.free_gyro",
    "station.engines.calibration_rotation": "station.engines.calibration._rotation",
    "station.engines.calibration_static": "station.engines.calibration._static",
    "station.engines.calibration_turntable": "station.engines.calibration.turntable",
    "station.engines.calibration_turntable_checks": "station.engines.calibration.turntable_checks",
    "station.engines.calibration_turntable_gsens": "station.engines.calibration.turntable_gsens",
    "station.engines.calibration_mag": "station.engines.magnetometer.calibration",
    "station.engines.mag_accel": "station.engines.magnetometer.accel",
    "station.engines.mag_coverage": "station.engines.magnetometer.coverage",
    "station.engines.mag_fit": "station.engines.magnetometer.fit",
    "station.engines.mag_inputs": "station.engines.magnetometer.inputs",
    "station.geomagnetic": "station.engines.magnetometer.geomagnetic",
    "station.engines.characterisation_scale": "station.engines.characterisation.scale",
    "station.engines.characterisation_turnon": "station.engines.characterisation.turn_on",
    "station.engines.thermal_blocks": "station.engines.thermal.blocks",
    "station.engines.thermal_design": "station.engines.thermal.design",
    "station.engines.thermal_model": "station.engines.thermal.model",
    "station.engines.thermal_triad": "station.engines.thermal.triad",
    "station.engines.correction": "station.engines.shared.correction",
    "station.engines.earth": "station.engines.shared.earth",
    "station.engines.levenberg_marquardt": "station.engines.shared.levenberg_marquardt",
    "station.engines.quaternion": "station.engines.shared.quaternion",
    "station.engines.samples": "station.engines.shared.samples",
    "station.engines.sensor_model": "station.engines.shared.sensor_model",
    "station.engines.static_detect": "station.engines.shared.static_detect",
    "station.export.params_file": "station.export.params.file",
    "station.export.params_check": "station.export.params.checks",
    "station.export.params_characterisation": "station.export.params.characterisation",
    "station.export.params_mag": "station.export.params.magnetometer",
    "station.export.sections": "station.export.params.sections",
    "station.export.json_export": "station.export.params.json_document",
    "station.export.allan_report": "station.export.params.noise",
    "station.export.c_export": "station.export.firmware.c_source",
    "station.export.blob": "station.export.firmware.blob",
    "station.export.px4": "station.export.autopilot.px4",
    "station.export.ardupilot": "station.export.autopilot.ardupilot",
    "station.export.kalibr": "station.export.estimators.kalibr",
    "station.export.gm_yaml": "station.export.estimators.gauss_markov",
    "station.export.allan_plot": "station.plots.allan",
    "station.export.loss_plot": "station.plots.autopilot_loss",
    "station.export.datasheet": "station.report.datasheet",
    "station.export.thermal_report": "station.console.thermal_report",
    "station.plots.mag_plot": "station.plots.magnetometer",
    "station.plots.thermal_plot": "station.plots.thermal",
    "station.factory.trend_plot": "station.plots.trend",
    "station.report.svg": "station.plots.svg",
    "station.report.fleet_svg": "station.plots.fleet_chart",
    "station.report.cert_plots": "station.plots.certificate",
    "station.text": "station.common.text",
    "station.text_table": "station.common.table",
    "station.files": "station.common.files",
    "station.yaml_file": "station.common.yaml_file",
    "station.cli_options": "station.console.options",
    "station.status_line": "station.console.status_line",
    "station.phase_line": "station.console.phase_line",
    "station.multi_status": "station.console.multi_status",
    "station.mag_summary": "station.console.mag_summary",
    "station.ports": "drivers.ports",
    "station.frame_file": "station.frames.reader",
    "station.frame_check": "station.frames.check",
    "station.frame_guess": "station.frames.guess",
}
"""Old module path -> new module path."""


class _MovedLoader:
    # Duck-typed (create_module, exec_module): importlib.abc costs 25 ms of every start-up.
    def __init__(self, new: str) -> None:
        self.new = new
        self.spec: importlib.machinery.ModuleSpec | None = None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(f"{spec.name} moved to {self.new}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        module = importlib.import_module(self.new)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        # The module is the new one, already run; the import system gave it the old name's spec.
        module.__spec__ = self.spec


class MovedFinder:
    """Finds an old module name of :data:`MOVED` as the module that now holds its code."""

    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        """A spec for an old module name, whose loader gives the new module; None for any other."""
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, cast("Loader", _MovedLoader(new)))


def install() -> None:
    """Put the finder on ``sys.meta_path`` once."""
    if not any(isinstance(f, MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(MovedFinder())
