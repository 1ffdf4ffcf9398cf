"""Allan variance: the overlapping deviation of a still record, the IEEE 952 noise terms
(Q, N, B, K, R) fitted to it, the noise model chosen by the data, and the white noise and random
walk that are equivalent to a whole model.

Arrays in, result dataclasses out. The equations are cited in each module; how the engine is checked
is in docs/methods/allan.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.engines.allan.deviation import BLOCK as BLOCK
    from station.engines.allan.deviation import INTEGRATE_ROWS as INTEGRATE_ROWS
    from station.engines.allan.deviation import MIN_SAMPLES as MIN_SAMPLES
    from station.engines.allan.deviation import ONE_SIGMA as ONE_SIGMA
    from station.engines.allan.deviation import AllanCurve as AllanCurve
    from station.engines.allan.deviation import ProgressCallback as ProgressCallback
    from station.engines.allan.deviation import allan_curve as allan_curve
    from station.engines.allan.deviation import alpha_from_slope as alpha_from_slope
    from station.engines.allan.deviation import cluster_sizes as cluster_sizes
    from station.engines.allan.deviation import confidence_interval as confidence_interval
    from station.engines.allan.deviation import edf_table as edf_table
    from station.engines.allan.deviation import greenhall_edf as greenhall_edf
    from station.engines.allan.deviation import integrate_rates as integrate_rates
    from station.engines.allan.deviation import nonoverlapping_adev as nonoverlapping_adev
    from station.engines.allan.deviation import overlapping_adev as overlapping_adev
    from station.engines.allan.deviation import overlapping_adev_phase as overlapping_adev_phase
    from station.engines.allan.deviation import strided_phase as strided_phase
    from station.engines.allan.equivalent import white_walk_equivalent as white_walk_equivalent
    from station.engines.allan.fit import B_FACTOR as B_FACTOR
    from station.engines.allan.fit import K_CROSSING_FRACTION as K_CROSSING_FRACTION
    from station.engines.allan.fit import ML_METHOD as ML_METHOD
    from station.engines.allan.fit import AxisNoise as AxisNoise
    from station.engines.allan.fit import basis as basis
    from station.engines.allan.fit import dominant_alpha as dominant_alpha
    from station.engines.allan.fit import fit_axis as fit_axis
    from station.engines.allan.fit import gauss_markov_avar as gauss_markov_avar
    from station.engines.allan.fit import identify_noise as identify_noise
    from station.engines.allan.fit import missing_terms as missing_terms
    from station.engines.allan.fit import model_avar as model_avar
    from station.engines.allan.likelihood import autocovariance as autocovariance
    from station.engines.allan.likelihood import block_length as block_length
    from station.engines.allan.likelihood import negative_log_likelihood as negative_log_likelihood
    from station.engines.allan.likelihood import white_walk_ml as white_walk_ml
    from station.engines.allan.model import Estimate as Estimate
    from station.engines.allan.model import GaussMarkov as GaussMarkov
    from station.engines.allan.model import NoiseModel as NoiseModel
    from station.engines.allan.model import filtered_white_avar as filtered_white_avar
    from station.engines.allan.model import ieee_model as ieee_model
    from station.engines.allan.model import log_chi2_moments as log_chi2_moments
    from station.engines.allan.model import preferred as preferred
    from station.engines.allan.model import select_model as select_model
    from station.engines.allan.model import sinusoid_avar as sinusoid_avar
    from station.engines.allan.terms import NAMES as NAMES
    from station.engines.allan.terms import SENSOR_AXES as SENSOR_AXES
    from station.engines.allan.terms import TERMS as TERMS
    from station.engines.allan.terms import UNITS as UNITS

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "deviation": ("allan_curve", "AllanCurve", "alpha_from_slope", "BLOCK", "cluster_sizes",
                  "confidence_interval", "edf_table", "greenhall_edf", "integrate_rates", "INTEGRATE_ROWS",
                  "MIN_SAMPLES", "nonoverlapping_adev", "ONE_SIGMA", "overlapping_adev",
                  "overlapping_adev_phase", "ProgressCallback", "strided_phase"),
    "equivalent": ("white_walk_equivalent",),
    "fit": ("AxisNoise", "B_FACTOR", "basis", "dominant_alpha", "fit_axis", "gauss_markov_avar",
            "identify_noise", "K_CROSSING_FRACTION", "missing_terms", "ML_METHOD", "model_avar"),
    "likelihood": ("autocovariance", "block_length", "negative_log_likelihood", "white_walk_ml"),
    "model": ("Estimate", "filtered_white_avar", "GaussMarkov", "ieee_model", "log_chi2_moments",
              "NoiseModel", "preferred", "select_model", "sinusoid_avar"),
    "terms": ("NAMES", "SENSOR_AXES", "TERMS", "UNITS"),
})
