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
    from station.engines.allan.deviation import AllanCurve as AllanCurve
    from station.engines.allan.deviation import ProgressCallback as ProgressCallback
    from station.engines.allan.deviation import allan_curve as allan_curve
    from station.engines.allan.deviation import cluster_sizes as cluster_sizes
    from station.engines.allan.deviation import integrate_rates as integrate_rates
    from station.engines.allan.deviation import nonoverlapping_adev as nonoverlapping_adev
    from station.engines.allan.deviation import overlapping_adev as overlapping_adev
    from station.engines.allan.deviation import overlapping_adev_phase as overlapping_adev_phase
    from station.engines.allan.deviation import strided_phase as strided_phase
    from station.engines.allan.equivalent import white_walk_equivalent as white_walk_equivalent
    from station.engines.allan.estimates import AxisNoise as AxisNoise
    from station.engines.allan.estimates import Estimate as Estimate
    from station.engines.allan.estimates import GaussMarkov as GaussMarkov
    from station.engines.allan.estimates import NoiseModel as NoiseModel
    from station.engines.allan.fit import K_CROSSING_FRACTION as K_CROSSING_FRACTION
    from station.engines.allan.fit import ML_METHOD as ML_METHOD
    from station.engines.allan.fit import dominant_alpha as dominant_alpha
    from station.engines.allan.fit import fit_axis as fit_axis
    from station.engines.allan.fit import identify_noise as identify_noise
    from station.engines.allan.fit import missing_terms as missing_terms
    from station.engines.allan.likelihood import autocovariance as autocovariance
    from station.engines.allan.likelihood import block_length as block_length
    from station.engines.allan.likelihood import negative_log_likelihood as negative_log_likelihood
    from station.engines.allan.likelihood import white_walk_ml as white_walk_ml
    from station.engines.allan.model import ieee_model as ieee_model
    from station.engines.allan.model import preferred as preferred
    from station.engines.allan.model import select_model as select_model
    from station.engines.allan.shapes import B_FACTOR as B_FACTOR
    from station.engines.allan.shapes import basis as basis
    from station.engines.allan.shapes import filtered_white_avar as filtered_white_avar
    from station.engines.allan.shapes import gauss_markov_avar as gauss_markov_avar
    from station.engines.allan.shapes import model_avar as model_avar
    from station.engines.allan.shapes import sinusoid_avar as sinusoid_avar
    from station.engines.allan.solver import prepare_solver as prepare_solver
    from station.engines.allan.solver import solver_ready as solver_ready
    from station.engines.allan.terms import NAMES as NAMES
    from station.engines.allan.terms import SENSOR_AXES as SENSOR_AXES
    from station.engines.allan.terms import TERMS as TERMS
    from station.engines.allan.terms import UNITS as UNITS
    from station.engines.allan.uncertainty import ONE_SIGMA as ONE_SIGMA
    from station.engines.allan.uncertainty import alpha_from_slope as alpha_from_slope
    from station.engines.allan.uncertainty import confidence_interval as confidence_interval
    from station.engines.allan.uncertainty import edf_table as edf_table
    from station.engines.allan.uncertainty import greenhall_edf as greenhall_edf
    from station.engines.allan.uncertainty import log_chi2_moments as log_chi2_moments

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "deviation": ("allan_curve", "AllanCurve", "BLOCK", "cluster_sizes", "integrate_rates",
                  "INTEGRATE_ROWS", "MIN_SAMPLES", "nonoverlapping_adev", "overlapping_adev",
                  "overlapping_adev_phase", "ProgressCallback", "strided_phase"),
    "equivalent": ("white_walk_equivalent",),
    "estimates": ("AxisNoise", "Estimate", "GaussMarkov", "NoiseModel"),
    "fit": ("dominant_alpha", "fit_axis", "identify_noise", "K_CROSSING_FRACTION", "missing_terms",
            "ML_METHOD"),
    "likelihood": ("autocovariance", "block_length", "negative_log_likelihood", "white_walk_ml"),
    "model": ("ieee_model", "preferred", "select_model"),
    "shapes": ("B_FACTOR", "basis", "filtered_white_avar", "gauss_markov_avar", "model_avar",
               "sinusoid_avar"),
    "solver": ("prepare_solver", "solver_ready"),
    "terms": ("NAMES", "SENSOR_AXES", "TERMS", "UNITS"),
    "uncertainty": ("alpha_from_slope", "confidence_interval", "edf_table", "greenhall_edf",
                    "log_chi2_moments", "ONE_SIGMA"),
})
