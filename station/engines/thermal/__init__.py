"""Temperature compensation of the bias: a model in T and dT, piecewise, chosen by
cross-validation, and its evaluation as firmware computes it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.engines.thermal.blocks import block_ids as block_ids
    from station.engines.thermal.blocks import still_poses as still_poses
    from station.engines.thermal.fit import MIN_BLOCKS as MIN_BLOCKS
    from station.engines.thermal.fit import MIN_SEGMENT_SPAN_DEGC as MIN_SEGMENT_SPAN_DEGC
    from station.engines.thermal.fit import MIN_SPAN_DEGC as MIN_SPAN_DEGC
    from station.engines.thermal.fit import RATE_FOLLOWS_TEMP_R2 as RATE_FOLLOWS_TEMP_R2
    from station.engines.thermal.fit import TAU_CANDIDATES_S as TAU_CANDIDATES_S
    from station.engines.thermal.fit import TAU_WITHOUT_RATE_S as TAU_WITHOUT_RATE_S
    from station.engines.thermal.fit import TRIADS as TRIADS
    from station.engines.thermal.fit import PreparedSweep as PreparedSweep
    from station.engines.thermal.fit import RateTerms as RateTerms
    from station.engines.thermal.fit import ThermalFit as ThermalFit
    from station.engines.thermal.fit import ThermalSettings as ThermalSettings
    from station.engines.thermal.fit import ThermalSweep as ThermalSweep
    from station.engines.thermal.fit import check_rate_terms as check_rate_terms
    from station.engines.thermal.fit import choose_tau as choose_tau
    from station.engines.thermal.fit import dtemp_clamp as dtemp_clamp
    from station.engines.thermal.fit import fit_thermal as fit_thermal
    from station.engines.thermal.fit import hold_last_reading as hold_last_reading
    from station.engines.thermal.fit import prepare_blocks as prepare_blocks
    from station.engines.thermal.fit import segment_options as segment_options
    from station.engines.thermal.model import TERMS as TERMS
    from station.engines.thermal.model import DtempFilter as DtempFilter
    from station.engines.thermal.model import ThermalBias as ThermalBias
    from station.engines.thermal.model import ThermalModel as ThermalModel
    from station.engines.thermal.model import ThermalSegment as ThermalSegment
    from station.engines.thermal.model import estimate_dtemp as estimate_dtemp

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "blocks": ("block_ids", "still_poses"),
    "fit": ("check_rate_terms", "choose_tau", "dtemp_clamp", "fit_thermal", "hold_last_reading",
            "MIN_BLOCKS", "MIN_SEGMENT_SPAN_DEGC", "MIN_SPAN_DEGC", "prepare_blocks", "PreparedSweep",
            "RATE_FOLLOWS_TEMP_R2", "RateTerms", "segment_options", "TAU_CANDIDATES_S",
            "TAU_WITHOUT_RATE_S", "ThermalFit", "ThermalSettings", "ThermalSweep", "TRIADS"),
    "model": ("DtempFilter", "estimate_dtemp", "TERMS", "ThermalBias", "ThermalModel", "ThermalSegment"),
})
