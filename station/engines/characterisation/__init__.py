"""The unit's datasheet figures, measured: turn-on bias repeatability, gyroscope
scale-factor nonlinearity and asymmetry.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from station.common.lazy import lazy_exports

if TYPE_CHECKING:
    from station.engines.characterisation.scale import ScaleAxis as ScaleAxis
    from station.engines.characterisation.scale import rate_steps as rate_steps
    from station.engines.characterisation.scale import scale_linearity as scale_linearity
    from station.engines.characterisation.turn_on import Repeatability as Repeatability
    from station.engines.characterisation.turn_on import allan_points as allan_points
    from station.engines.characterisation.turn_on import mean_noise as mean_noise
    from station.engines.characterisation.turn_on import reduce_record as reduce_record
    from station.engines.characterisation.turn_on import repeatability as repeatability
    from station.engines.characterisation.turn_on import turn_on_repeatability as turn_on_repeatability

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "scale": ("rate_steps", "scale_linearity", "ScaleAxis"),
    "turn_on": ("allan_points", "mean_noise", "reduce_record", "Repeatability", "repeatability",
                "turn_on_repeatability"),
})
