"""From the wizard's labelled capture to the calibration report the results screen shows."""

from __future__ import annotations

from protocols.units import STANDARD_GRAVITY
from station.acquisition.capture import Capture
from station.engines.calibration.common import CalibrationReport
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable
from station.errors import EngineInputError


def calibrate_run(capture: Capture, gravity: float = STANDARD_GRAVITY) -> CalibrationReport:
    """The known-pose method (poses for the accelerometer, rotations for the gyroscope)."""
    if capture.step is None or not capture.segments():
        raise EngineInputError("no step was captured: run the sequence (w) before computing a calibration")
    rate = capture.device.get("rate_hz")
    data = TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step,
                            rate_hz=float(rate) if rate else None)
    return calibrate_turntable(data, TurntableSettings(gravity=gravity))
