"""The plan's ``campaign:`` section: a chamber campaign, soak by soak, run unattended.

::

    campaign:
      soaks_c: [-20, 0, 20, 40, 60]   # in this order; the chamber ramps from one to the next
      ramp_c_per_min: 3               # the chamber's gradient, within instruments.chamber.max_gradient
      end_c: 25                       # optional: a last recorded ramp back (the down sweep for hysteresis)
      settle: {rate_c_per_min: 0.1, hold_s: 120, timeout_s: 3600}   # on the unit's own temperature
      soak:                           # at every soak, in this order
        sequence: true                # the plan's sequence on the table (the soak's calibration)
        power_cycles: 3               # through the supply, a still record after each (turn-on bias)
        turn_on_s: 10                 # each of those records
        off_s: 2                      # the supply's output held off
        still_s: 30                   # a still record (0: none)
      ramp: {record: true, rate_hz: 10}   # record still while the chamber ramps (T/dT bias, hysteresis)
      simulate: {speed: 10, wait_speed: 200}   # --simulate only: the unit's clock against the wall's

Every time is in device seconds (the unit's own clock), so a simulated campaign whose clock runs
fast keeps the plan's meaning. ``simulate.speed`` is the clock's pace during sequences and records,
``wait_speed`` while the station only waits for the chamber (ramps, settles, a supply held off):
the station asks the simulated rig to change pace, a real unit is not concerned.

A campaign needs the plan's chamber (and its supply for power cycles, a table for the sequence);
every soak must lie within the chamber's ``min_c``/``max_c`` and the gradient within its
``max_gradient``. Each mistake is refused with the file, its line and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import yaml

from station.factory.plan_reader import PlanReader

if TYPE_CHECKING:
    from station.instruments.bench import InstrumentPlan

_CAMPAIGN = {"soaks_c", "ramp_c_per_min", "end_c", "settle", "soak", "ramp", "simulate"}
_SETTLE = {"rate_c_per_min", "hold_s", "timeout_s"}
_SOAK = {"sequence", "power_cycles", "turn_on_s", "off_s", "still_s"}
_RAMP = {"record", "rate_hz"}
_SIMULATE = {"speed", "wait_speed"}
MAX_SPEED = 50.0  # the unit's clock during captures: past this a 200 Hz unit floods the station's decoder
MAX_WAIT_SPEED = 2000.0  # while waiting the unit streams at ramp.rate_hz: samples stay few


@dataclass(frozen=True)
class CampaignPlan:
    """A chamber campaign (see the module docstring); times in device seconds."""

    soaks_c: tuple[float, ...]
    ramp_c_per_min: float
    end_c: float | None = None
    settle_rate_c_per_min: float = 0.1
    settle_hold_s: float = 120.0
    settle_timeout_s: float = 3600.0
    sequence: bool = True
    power_cycles: int = 0
    turn_on_s: float = 10.0
    off_s: float = 2.0
    still_s: float = 0.0
    ramp_record: bool = True
    ramp_rate_hz: int = 10
    speed: float = 10.0
    wait_speed: float = 200.0

    def ramps(self) -> list[tuple[str, float]]:
        """Every ramp's step id and target, in order: one before each soak, and the end ramp."""
        out = [(f"ramp-{i + 1}", temp) for i, temp in enumerate(self.soaks_c)]
        if self.end_c is not None:
            out.append(("ramp-end", self.end_c))
        return out


def read_campaign(r: PlanReader, node: yaml.Node, instruments: InstrumentPlan | None) -> CampaignPlan:
    """Read and check ``campaign:`` against the plan's instruments (a chamber is needed).

    Parameters
    ----------
    r : PlanReader
        The plan's walker (names the file and line of a refusal).
    node : yaml.Node
        The section.
    instruments : InstrumentPlan or None
        The plan's ``instruments:`` as read.

    Returns
    -------
    CampaignPlan

    Raises
    ------
    InputFileError
        A missing or bad key, a soak beyond the chamber's limits, a gradient beyond its
        ``max_gradient``, power cycles without a supply.
    """
    section = r.mapping(node, _CAMPAIGN, "'campaign'")
    if instruments is None or instruments.chamber is None:
        raise r.fail(node, "a campaign needs the chamber: add 'instruments: {chamber: {url: ..., min_c: ..., "
                     "max_c: ..., max_gradient: ...}}'", column="campaign")
    for key in ("soaks_c", "ramp_c_per_min"):
        if key not in section:
            raise r.fail(node, f"'campaign' has no '{key}'", column=key)
    soaks = _soaks(r, section["soaks_c"], instruments)
    fields: dict[str, object] = {"soaks_c": soaks}
    ramp = r.number(section["ramp_c_per_min"], "ramp_c_per_min")
    max_gradient = instruments.limits.max_gradient
    if max_gradient is not None and ramp > max_gradient:
        raise r.fail(section["ramp_c_per_min"], f"'ramp_c_per_min' {ramp:g} is beyond the chamber's "
                     f"'max_gradient' {max_gradient:g} degC/min", column="ramp_c_per_min")
    fields["ramp_c_per_min"] = ramp
    if "end_c" in section:
        fields["end_c"] = _within(r, section["end_c"], "end_c", instruments)
    if "settle" in section:
        settle = r.mapping(section["settle"], _SETTLE, "'campaign.settle'")
        for key in sorted(settle):
            fields[f"settle_{key}" if key != "rate_c_per_min" else "settle_rate_c_per_min"] = \
                r.number(settle[key], key)
    if "soak" in section:
        fields.update(_soak(r, section["soak"], instruments))
    if "ramp" in section:
        ramp_node = r.mapping(section["ramp"], _RAMP, "'campaign.ramp'")
        if "record" in ramp_node:
            fields["ramp_record"] = r.boolean(ramp_node["record"], "record")
        if "rate_hz" in ramp_node:
            rate = r.integer(ramp_node["rate_hz"], "rate_hz")
            if rate > 4000:
                raise r.fail(ramp_node["rate_hz"], "'rate_hz' above 4000 Hz is beyond the native protocol's "
                             "range", column="rate_hz")
            fields["ramp_rate_hz"] = rate
    if "simulate" in section:
        sim = r.mapping(section["simulate"], _SIMULATE, "'campaign.simulate'")
        for key, top in (("speed", MAX_SPEED), ("wait_speed", MAX_WAIT_SPEED)):
            if key in sim:
                value = r.number(sim[key], key)
                if value > top:
                    raise r.fail(sim[key], f"'{key}' {value:g} is above {top:g} times real time", column=key)
                fields[key] = value
    return CampaignPlan(**fields)  # type: ignore[arg-type]  # each key read with its type above


def _within(r: PlanReader, node: yaml.Node, key: str, instruments: InstrumentPlan) -> float:
    value = r.number(node, key, positive=False)
    low, high = instruments.limits.min_c, instruments.limits.max_c
    if (low is not None and value < low) or (high is not None and value > high):
        raise r.fail(node, f"'{key}' {value:g} degC is beyond the chamber's limits "
                     f"{'-inf' if low is None else f'{low:g}'}..{'inf' if high is None else f'{high:g}'} "
                     "degC (instruments.chamber min_c, max_c)", column=key)
    return value


def _soaks(r: PlanReader, node: yaml.Node, instruments: InstrumentPlan) -> tuple[float, ...]:
    if not isinstance(node, yaml.SequenceNode) or not node.value:
        raise r.fail(node, "'soaks_c' must be a list of temperatures in degC, e.g. [-20, 0, 20, 40, 60]",
                     column="soaks_c")
    out = tuple(_within(r, item, "soaks_c", instruments) for item in node.value)
    for item, (a, b) in zip(node.value[1:], zip(out, out[1:], strict=False), strict=True):
        if math.isclose(a, b):
            raise r.fail(item, f"'soaks_c' lists {b:g} degC twice in a row; each soak is a new temperature",
                         column="soaks_c")
    return out


def _soak(r: PlanReader, node: yaml.Node, instruments: InstrumentPlan) -> dict[str, object]:
    soak = r.mapping(node, _SOAK, "'campaign.soak'")
    out: dict[str, object] = {}
    if "sequence" in soak:
        out["sequence"] = r.boolean(soak["sequence"], "sequence")
    if "power_cycles" in soak:
        cycles = r.value(soak["power_cycles"])
        if not isinstance(cycles, int) or isinstance(cycles, bool) or cycles < 0:
            raise r.fail(soak["power_cycles"], f"'power_cycles' must be a whole number (0: none), not "
                         f"{soak['power_cycles'].value!r}", column="power_cycles")
        if cycles and instruments.supply is None:
            raise r.fail(soak["power_cycles"], "'power_cycles' needs the unit's supply: add "
                         "'instruments: {supply: {url: ...}}'", column="power_cycles")
        if cycles in (1, 2):
            raise r.fail(soak["power_cycles"], "'power_cycles' must be 0 or at least 3: the turn-on "
                         "repeatability needs three power-ups", column="power_cycles")
        out["power_cycles"] = cycles
    for key in ("turn_on_s", "off_s"):
        if key in soak:
            out[key] = r.number(soak[key], key)
    if "still_s" in soak:
        out["still_s"] = r.number(soak["still_s"], "still_s", positive=False)
        if out["still_s"] < 0:  # type: ignore[operator]  # a float, read above
            raise r.fail(soak["still_s"], "'still_s' must be 0 (none) or a positive number of seconds",
                         column="still_s")
    return out
