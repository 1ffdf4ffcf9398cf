"""The reports' Jinja2 environment: templates shipped in ``station/report/templates``, escaping on,
and the number filters the pages share."""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import jinja2

SCIENTIFIC_BELOW = 1e-3
SCIENTIFIC_FROM = 1e7


def number(value: Any, digits: int = 4) -> str:
    """``value`` as every page writes a number: ``digits`` significant figures in positional notation
    (the integer digits are never rounded off, trailing zeros dropped), scientific only below 0.001 or
    from 10^7 on; an en dash for a value not known (None, NaN).

    One rule for every table and page, so that the same figure reads the same everywhere (``%g``
    switched to exponents at five integer digits: 21070 on one page read 2.107e+04 on another).
    """
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "\u2013"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    if isinstance(value, int) or value == 0:
        return str(int(value)) if float(value).is_integer() else f"{value:.{digits}g}"
    size = abs(value)
    if size < SCIENTIFIC_BELOW or size >= SCIENTIFIC_FROM:
        mantissa, exponent = f"{value:.{digits - 1}e}".split("e")
        return f"{mantissa.rstrip('0').rstrip('.')}e{exponent}"
    decimals = max(0, digits - 1 - math.floor(math.log10(size)))
    text = f"{value:.{decimals}f}"
    if "." in text:  # as %g: no trailing zeros (a limit of 80 reads 80, not 80.00)
        text = text.rstrip("0").rstrip(".")
    return "0" if float(text) == 0 else text


def measured(value: Any, sigma: Any) -> tuple[str, str]:
    """A value and its 1-sigma as a certificate writes them: the 1-sigma to two significant figures
    and the value to the same last decimal (GUM 7.2.6); either alone by :func:`number`.

    Returns
    -------
    tuple of str
        The value's text and the 1-sigma's (an en dash where not known).
    """
    if isinstance(sigma, bool) or not isinstance(sigma, int | float) or not (0 < sigma < math.inf):
        return number(value), number(None)
    if (not isinstance(value, int | float) or not math.isfinite(value)
            or not SCIENTIFIC_BELOW <= sigma < SCIENTIFIC_FROM or abs(value) >= SCIENTIFIC_FROM):
        return number(value), number(sigma, 2)
    decimals = max(0, 1 - math.floor(math.log10(sigma)))
    shown = f"{value:.{decimals}f}"
    return ("0" if float(shown) == 0 else shown), f"{sigma:.{decimals}f}"


def with_sigma(value: Any, sigma: Any) -> str:
    """``value \u00b1 sigma`` by :func:`measured`; the value alone when the 1-sigma is not known."""
    shown, sd = measured(value, sigma)
    return shown if sd == number(None) else f"{shown} \u00b1 {sd}"


def css_string(text: Any) -> str:
    """``text`` as a quoted CSS string (``@page`` margin boxes): every character but letters, digits,
    space and a few safe marks is written as a hex escape (six digits and the space that ends it, which
    CSS consumes: a space after it in the text stays), so a hostile serial cannot close the string,
    the rule or the ``<style>`` element. The template marks it ``safe``: HTML escaping would corrupt
    it inside ``<style>``, where entities are not decoded."""
    safe = set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 .,:-_+/()")
    return '"' + "".join(c if c in safe else f"\\{ord(c):06x} " for c in str(text)) + '"'


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
    env.filters["sigma"] = with_sigma
    env.filters["css_string"] = css_string
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
