"""One sign for every residual the station reports: measured minus model, in both calibration
methods' per-pose tables (and so in calibrate's output, its JSON and the TUI's results)."""

from __future__ import annotations

import numpy as np
import pytest

from mocks.rig import handheld_session, sequence_segments, simulate
from mocks.truth import UnitTruth
from station.engines.calibration.free import FreeCapture, FreeSettings, calibrate_free
from station.engines.calibration.turntable import TurntableCapture, TurntableSettings, calibrate_turntable

G = 9.80665


def _calibrated_norm(report, capture, pose) -> float:
    inside = (capture.t >= pose["t0"]) & (capture.t <= pose["t1"])
    return float(np.linalg.norm(report.accel.correct(capture.acc[inside]).mean(axis=0)))


@pytest.fixture(scope="module")
def truth():
    return UnitTruth.random(12)


def test_free_method_reports_measured_minus_model(truth) -> None:
    capture = simulate(truth, handheld_session(n_poses=16, seed=4), rate_hz=100.0, seed=4).to_capture()
    report = calibrate_free(FreeCapture(capture.t, capture.acc, capture.gyro), FreeSettings(gravity=G))
    assert report.accel.extra["residual"] == "|a| - g (m/s^2)"
    residual = np.array([p["residual"] for p in report.poses])
    measured = np.array([_calibrated_norm(report, capture, p) - G for p in report.poses])
    # the interval means trim a few samples at the ends: the same numbers within a tenth of their spread
    np.testing.assert_allclose(residual, measured, atol=0.1 * np.abs(measured).max())
    assert np.corrcoef(residual, measured)[0, 1] > 0.9


def test_turntable_method_reports_measured_minus_model(truth) -> None:
    rec = simulate(truth, sequence_segments("twelve-position", True, hold_s=6.0), rate_hz=100.0, seed=5)
    capture = rec.to_capture()
    report = calibrate_turntable(TurntableCapture(capture.t, capture.acc, capture.gyro, capture.step, 100.0),
                                 TurntableSettings(gravity=G))
    statics = [p for p in report.poses if p.get("kind") == "static"]
    norm_error = np.array([p["norm_error"] for p in statics])
    measured = np.array([_calibrated_norm(report, capture, p) - G for p in statics])
    np.testing.assert_allclose(norm_error, measured, atol=1e-6 + 0.05 * np.abs(measured).max())
