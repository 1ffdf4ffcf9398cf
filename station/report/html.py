"""The reports' Jinja2 environment: templates shipped in ``station/report/templates``, escaping on,
and the number filters the pages share."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import jinja2


def number(value: Any, digits: int = 4) -> str:
    """``value`` to ``digits`` significant figures; an en dash for a value not known (None, NaN)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "\u2013"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    return f"{value:.{digits}g}"


def limits_text(low: float | None, high: float | None) -> str:
    """``[-2 .. 2]``, ``<= 0.02``, ``>= 1`` or an en dash: a measurement's limits as a cell shows them."""
    if low is not None and high is not None:
        return f"[{number(low)} .. {number(high)}]"
    if high is not None:
        return f"\u2264 {number(high)}"
    if low is not None:
        return f"\u2265 {number(low)}"
    return "\u2013"


@cache
def environment() -> jinja2.Environment:
    """The one environment (templates compiled once per process)."""
    env = jinja2.Environment(loader=jinja2.PackageLoader("station.report", "templates"),
                             autoescape=jinja2.select_autoescape(default=True, default_for_string=True),
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters["num"] = number
    env.filters["limits"] = limits_text
    return env


def render(template: str, **context: Any) -> str:
    """Render ``template`` (a file in the templates folder) with ``context``.

    Parameters
    ----------
    template : str
        E.g. ``certificate.html.j2``.
    **context
        The template's variables; SVG plots are passed as strings the template marks safe.

    Returns
    -------
    str
        The page.
    """
    return environment().get_template(template).render(**context)
