"""The ``characterisation`` section of the parameter file (``shared/specs/params-file.md``), built from
the characterisation engines' results.

Besides the spec's keys it records each figure's uncertainty: ``*_interval`` (per axis [low, high], the
chi-square confidence interval at ``repeatability_level``) for the turn-on repeatabilities and
``*_sd_ppm`` (1-sigma) for the scale-factor figures, the in-run noise of the turn-on means that was
removed (``*_bias_in_run``), the rates the scale figures rest on and the scale-factor error
``(K - 1) 1e6`` of the all-rates line. A run that measures one group keeps the other group's keys of a
section already in the file.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from station.engines.characterisation.scale import ScaleAxis
from station.engines.characterisation.turn_on import Repeatability
from station.export.params.file import to_plain


def repeatability_keys(accel: Repeatability, gyro: Repeatability, sources: Sequence[str]) -> dict[str, Any]:
    """The turn-on repeatability keys of the section.

    Parameters
    ----------
    accel, gyro : Repeatability
        The engine's results (m/s^2, rad/s).
    sources : sequence of str
        The records, one per turn-on.

    Returns
    -------
    dict
    """
    return to_plain({
        "turn_ons": accel.turn_ons,
        "accel_bias_repeatability": accel.sigma,
        "gyro_bias_repeatability": gyro.sigma,
        "accel_bias_repeatability_interval": accel.interval,
        "gyro_bias_repeatability_interval": gyro.interval,
        "repeatability_level": accel.level,
        "accel_bias_in_run": accel.in_run,
        "gyro_bias_in_run": gyro.in_run,
        "turn_on_records": list(sources),
    })


def scale_keys(axes: Sequence[ScaleAxis | None], sources: Sequence[str]) -> dict[str, Any]:
    """The scale-factor keys of the section, per axis, null where an axis was not measured.

    Parameters
    ----------
    axes : sequence of ScaleAxis or None
        x, y, z.
    sources : sequence of str
        The rate captures.

    Returns
    -------
    dict
    """
    def per_axis(name: str) -> list[Any]:
        return [None if a is None else getattr(a, name) for a in axes]

    return to_plain({
        "gyro_scale_nonlinearity_ppm": per_axis("nonlinearity_ppm"),
        "gyro_scale_asymmetry_ppm": per_axis("asymmetry_ppm"),
        "gyro_scale_nonlinearity_sd_ppm": per_axis("nonlinearity_sd_ppm"),
        "gyro_scale_asymmetry_sd_ppm": per_axis("asymmetry_sd_ppm"),
        "gyro_scale_error_ppm": per_axis("scale_error_ppm"),
        "gyro_scale_error_sd_ppm": per_axis("scale_error_sd_ppm"),
        "gyro_scale_rates_dps": per_axis("rates_dps"),
        "rate_records": list(sources),
    })


def merged(existing: Any, keys: dict[str, Any]) -> dict[str, Any]:
    """The section with ``keys`` written over an existing one (kept where ``keys`` does not speak).

    Parameters
    ----------
    existing : dict or None
        The section already in the file.
    keys : dict

    Returns
    -------
    dict
    """
    out = dict(existing) if isinstance(existing, dict) else {}
    out.update(keys)
    return out
