"""Noise values for estimators: Kalibr, VINS-Fusion, ORB-SLAM3 and OpenVINS (continuous densities), PX4 EKF2
and ArduPilot EKF3 (per prediction step), each with an explicit inflation factor, and Gauss-Markov
processes for EKF-style filters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.export.estimators.gauss_markov import discrete_gm as discrete_gm
    from station.export.estimators.gauss_markov import gm_yaml as gm_yaml
    from station.export.estimators.noise_export import EstimatorExport as EstimatorExport
    from station.export.estimators.noise_export import build_noise_export as build_noise_export

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "gauss_markov": ("discrete_gm", "gm_yaml"),
    "noise_export": ("EstimatorExport", "build_noise_export"),
})
