"""Noise values for estimators: Kalibr, VINS-Fusion and ORB-SLAM3 (``imu.yaml``) and
Gauss-Markov processes for EKF-style filters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.export.estimators.gauss_markov import discrete_gm as discrete_gm
    from station.export.estimators.gauss_markov import gm_yaml as gm_yaml

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "gauss_markov": ("discrete_gm", "gm_yaml"),
})
