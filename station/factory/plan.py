"""The factory plan: what an unattended run does to each unit, as a YAML file.

A plan names the sequence, the device rate, the engine settings, the pass/fail limits with their
units, the run's time limits and the export formats::

    schema: imu-station/plan/1
    name: imu-line-a
    sequence:                       # or just: sequence: six-position
      name: six-position            # built-in (six-position, twelve-position, rotations) ...
      # file: my-sequence.yaml      # ... or a sequence file, relative to the plan
      rotations: true
      hold_s: 2
      rotation_rate_dps: 90
      settle_s: 1
    device: {rate_hz: 200}          # protocol: frame:board.yaml (a board's own frames; relative to the plan)
    engine: {method: turntable, gravity: 9.80665}   # or latitude: 45.07 (and height: 240)
    run: {timeout_s: 300, step_timeout_s: 20, max_attempts: 2}
    limits:
      accel.bias:         {max_abs: 0.5, unit: m/s^2}
      accel.scale_error:  {max_abs: 3, unit: "%"}
      gyro.bias:          {max_abs: 2, unit: deg/s}
      link.lost_fraction: {max: 0.001}
    export: [c, json]
    instruments:                    # the lab's instruments (shared/specs/instruments.md), with limits
      chamber: {url: "votsch://10.0.0.5", min_c: -40, max_c: 85, max_gradient: 3,
                soak_c: 25, settle_rate_c_per_min: 0.05, settle_s: 300, settle_timeout_s: 3600}
      table: {url: "acutrol://10.0.0.7:5000?axes=3", max_rate_dps: 400, max_accel_dps2: 200, mount: +z}
      supply: {url: "scpi://10.0.0.9", max_v: 12, max_a: 1, volts: 5, amps: 0.5}
      on_abort: {chamber: hold, table: stop, supply: keep}   # or chamber: stop | setpoint:23, supply: off

Every limit applies to each component of its quantity (the three axes of a bias, the six
off-diagonal terms of a misalignment) and is written in the unit it names. Every mistake is
refused with the file, the line and what to write instead.

The unit speaks the native protocol (the run asks it its serial and sets its rate), or streams a
board's own frames (``protocol: frame:FILE.yaml``, ``shared/specs/frame-description.md``): the run
then sends it nothing, the serial is given to the run, and the rate is the description's
``rate_hz`` when it states one, else ``device.rate_hz``. The description is read and checked with
the plan, before any port is opened.

Why this module is long: the plan is one schema read by one walker over the composed YAML nodes
(``PlanReader``), so that every refusal names its line; each section's reader is a short function of
that walker, and splitting them into modules would pass the walker's private state across them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from protocols.units import STANDARD_GRAVITY
from station.acquisition import sequences
from station.acquisition.sequences import Sequence
from station.common.yaml_file import read_yaml
from station.errors import InputFileError, StationError
from station.factory.campaign_plan import CampaignPlan, read_campaign
from station.factory.plan_reader import PlanReader, shown
from station.instruments.bench import InstrumentPlan, OnAbort, check_on_abort
from station.instruments.limits import Limits

SCHEMA = "imu-station/plan/1"
G0 = STANDARD_GRAVITY
DEG = math.pi / 180.0

# unit name -> (dimension, factor to SI)
UNITS: dict[str, tuple[str, float]] = {
    "m/s^2": ("acceleration", 1.0), "mg": ("acceleration", G0 * 1e-3), "g": ("acceleration", G0),
    "rad/s": ("rate", 1.0), "deg/s": ("rate", DEG), "dps": ("rate", DEG), "deg/h": ("rate", DEG / 3600.0),
    "rad": ("angle", 1.0), "mrad": ("angle", 1e-3), "deg": ("angle", DEG),
    "": ("ratio", 1.0), "%": ("ratio", 1e-2), "ppm": ("ratio", 1e-6),
}

# quantity -> (dimension, what it is)
QUANTITIES: dict[str, tuple[str, str]] = {
    "accel.bias": ("acceleration", "accelerometer bias b, per axis"),
    "accel.scale_error": ("ratio", "accelerometer scale K - 1, per axis"),
    "accel.misalignment": ("angle", "accelerometer misalignment S, six off-diagonal terms"),
    "accel.residual_rms": ("acceleration", "accelerometer fit residual RMS"),
    "gyro.bias": ("rate", "gyroscope bias b, per axis"),
    "gyro.scale_error": ("ratio", "gyroscope scale K - 1, per axis"),
    "gyro.misalignment": ("angle", "gyroscope misalignment S, six off-diagonal terms"),
    "gyro.residual_rms": ("rate", "gyroscope fit residual RMS"),
    "link.lost_fraction": ("ratio", "samples lost on the link over samples expected"),
}
SI_UNIT = {"acceleration": "m/s^2", "rate": "rad/s", "angle": "rad", "ratio": ""}
EXPORT_FORMATS = ("c", "bin", "json", "yaml", "px4", "ardupilot")
METHODS = ("turntable",)

_TOP = {"schema", "name", "sequence", "device", "engine", "run", "limits", "export", "instruments",
        "campaign"}
_SEQUENCE = {"name", "file", "rotations", "hold_s", "rotation_rate_dps", "settle_s"}
_DEVICE = {"rate_hz", "protocol"}
_ENGINE = {"method", "gravity", "latitude", "height"}
_RUN = {"timeout_s", "step_timeout_s", "max_attempts"}
_LIMIT = {"min", "max", "max_abs", "unit"}
_INSTRUMENTS = {"chamber", "table", "supply", "on_abort"}
# Each instrument's URL and the limits of its kind (station.instruments.limits.Limits).
_INSTRUMENT_KEYS = {"chamber": {"url", "min_c", "max_c", "max_gradient", "soak_c", "settle_rate_c_per_min",
                                "settle_s", "settle_timeout_s"},
                    "table": {"url", "max_rate_dps", "max_accel_dps2", "mount"},
                    "supply": {"url", "max_v", "max_a", "volts", "amps"}}
# Keys of the run (not limits), by where InstrumentPlan keeps them.
_RUN_KEYS = {"soak_c": "soak_c", "settle_rate_c_per_min": "settle_rate_c_per_min", "settle_s": "settle_s",
             "settle_timeout_s": "settle_timeout_s", "volts": "supply_v", "amps": "supply_a"}
_MOUNTS = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass(frozen=True)
class LimitSpec:
    """Limits of one quantity, in ``unit``; ``low``/``high`` None is unbounded on that side."""

    quantity: str
    low: float | None
    high: float | None
    unit: str
    line: int

    @property
    def si_factor(self) -> float:
        """Factor from this limit's unit to SI (``UNITS``)."""
        return UNITS[self.unit][1]

    def check(self, value: float) -> bool:
        """True when ``value`` (in this limit's unit) is within it; NaN never is."""
        if not math.isfinite(value):
            return False
        return (self.low is None or value >= self.low) and (self.high is None or value <= self.high)


@dataclass(frozen=True)
class Plan:
    """A station plan as read from its YAML file: sequence, link, engine, timeouts, limits and exports."""

    path: Path
    name: str
    sha256: str
    sequence: Sequence
    rate_hz: int = 200
    protocol: str = "native"
    method: str = "turntable"
    gravity: float | None = None
    latitude: float | None = None
    height: float = 0.0
    timeout_s: float = 600.0
    step_timeout_s: float = 30.0
    max_attempts: int = 2
    limits: tuple[LimitSpec, ...] = ()
    export: tuple[str, ...] = ()
    instruments: InstrumentPlan | None = None
    campaign: CampaignPlan | None = None

    @property
    def asks_serial(self) -> bool:
        """Whether the unit is asked its serial (native protocol); a frame-described board is not."""
        return self.protocol == "native"

    def limit(self, quantity: str) -> LimitSpec | None:
        """The limit of ``quantity``, or None when the plan sets none."""
        for spec in self.limits:
            if spec.quantity == quantity:
                return spec
        return None


def load_plan(path: str | Path) -> Plan:
    """Read and check a plan file (schema ``imu-station/plan/1``)."""
    path = Path(path)
    document = read_yaml(path, "does not exist; give the plan YAML (see examples/plan.yaml)")
    raw, root = document.raw, document.root
    r = PlanReader(path)
    if root is None:
        raise InputFileError(path, "is empty; a plan needs at least 'schema', 'name' and 'sequence'")
    top = r.mapping(root, _TOP, "the plan")
    if "schema" not in top:
        raise r.fail(root, f"has no 'schema'; the first line should be 'schema: {SCHEMA}'", column="schema")
    if r.scalar(top["schema"], "'schema'") != SCHEMA:
        raise r.fail(top["schema"], f"schema is {top['schema'].value!r}, this station reads {SCHEMA!r}",
                     column="schema")
    for key in ("name", "sequence"):
        if key not in top:
            raise r.fail(root, f"has no '{key}'", column=key)
    fields: dict[str, Any] = {"name": r.scalar(top["name"], "'name'")}
    fields["sequence"] = _sequence(r, top["sequence"])
    if "device" in top:
        dev = r.mapping(top["device"], _DEVICE, "'device'")
        if "rate_hz" in dev:
            fields["rate_hz"] = r.integer(dev["rate_hz"], "rate_hz")
            if fields["rate_hz"] > 4000:
                raise r.fail(dev["rate_hz"], "'rate_hz' above 4000 Hz is beyond the native protocol's range",
                             column="rate_hz")
        if "protocol" in dev:
            try:
                fields["protocol"], rate = run_protocol(r.scalar(dev["protocol"], "'protocol'"), path.parent)
            except StationError as exc:
                raise r.fail(dev["protocol"], str(exc), column="protocol") from None
            if rate is not None and "rate_hz" in dev and fields["rate_hz"] != rate:
                raise r.fail(dev["rate_hz"], f"'rate_hz' is {fields['rate_hz']} but the frame description "
                             f"gives rate_hz {rate}; leave it out or make them agree", column="rate_hz")
            if rate is not None:
                fields["rate_hz"] = rate
    if "engine" in top:
        fields.update(_engine(r, top["engine"]))
    if "run" in top:
        run = r.mapping(top["run"], _RUN, "'run'")
        for key in ("timeout_s", "step_timeout_s"):
            if key in run:
                fields[key] = r.number(run[key], key)
        if "max_attempts" in run:
            fields["max_attempts"] = r.integer(run["max_attempts"], "max_attempts")
    if "limits" in top:
        fields["limits"] = _limits(r, top["limits"])
    if "export" in top:
        fields["export"] = _export(r, top["export"])
    if "instruments" in top:
        fields["instruments"] = _instruments(r, top["instruments"])
    if "campaign" in top:
        fields["campaign"] = read_campaign(r, top["campaign"], fields.get("instruments"))
    return Plan(path=path, sha256=hashlib.sha256(raw).hexdigest(), **fields)


def run_protocol(protocol: str, relative_to: Path | None = None) -> tuple[str, int | None]:
    """The protocol an unattended run reads a unit with, checked, and the rate it fixes.

    Parameters
    ----------
    protocol : str
        ``native`` or ``frame:FILE.yaml`` (a board's own frames; a shipped description by name).
    relative_to : Path, optional
        Where a relative description file is looked for first (the plan's folder).

    Returns
    -------
    tuple
        The protocol with the description's file made absolute, and the description's
        ``rate_hz`` rounded to whole Hz (None for the native protocol or a description without one).

    Raises
    ------
    StationError
        Another protocol, or a description file that is missing or breaks the schema (an
        ``InputFileError`` naming its file, line and key).
    """
    if protocol == "native":
        return protocol, None
    name, _, option = protocol.partition(":")
    if name != "frame" or not option:
        raise StationError(f"protocol {protocol!r}: an unattended run reads the native protocol (it asks the "
                           "unit its serial and sets its rate) or a board's own frames described in YAML, "
                           "frame:FILE.yaml")
    from station.frames.reader import load_description, resolve

    file = Path(option)
    if relative_to is not None and not file.is_absolute() and (relative_to / file).is_file():
        file = relative_to / file
    else:
        file = resolve(option)
    desc = load_description(file)
    return f"frame:{file.resolve()}", None if desc.rate_hz is None else max(1, round(desc.rate_hz))


def with_instruments(plan: Plan, urls: dict[str, str | None]) -> Plan:
    """``plan`` with the instruments ``urls`` names (``--chamber``, ``--table``, ``--supply``) in place of
    its own; an instrument the plan does not name gets only its own limits."""
    given = {kind: url for kind, url in urls.items() if url is not None}
    if not given:
        return plan
    for kind, url in given.items():
        if "://" not in url:
            raise StationError(f"--{kind} {url!r} is not an instrument URL; write e.g. {_EXAMPLE_URL[kind]}")
    base = plan.instruments if plan.instruments is not None else InstrumentPlan(
        limits=Limits(source="no plan limits (the instruments' own)"))
    return dataclasses.replace(plan, instruments=base.with_urls(given))


def with_protocol(plan: Plan, protocol: str) -> Plan:
    """``plan`` read with another protocol (``run --protocol``): the description's rate, when it gives one.

    Parameters
    ----------
    plan : Plan
        The plan as loaded.
    protocol : str
        ``native`` or ``frame:FILE.yaml`` (relative to the working folder, or a shipped name).

    Returns
    -------
    Plan
        A copy with the protocol (its file absolute) and the rate.

    Raises
    ------
    StationError
        As :func:`run_protocol`.
    """
    chosen, rate = run_protocol(protocol)
    return dataclasses.replace(plan, protocol=chosen, rate_hz=rate or plan.rate_hz)


def _sequence(r: PlanReader, node: yaml.Node) -> Sequence:
    if isinstance(node, yaml.ScalarNode):
        spec: dict[str, yaml.Node] = {"name": node}
    else:
        spec = r.mapping(node, _SEQUENCE, "'sequence'")
    if ("name" in spec) == ("file" in spec):
        raise r.fail(node, "'sequence' needs either 'name' (a built-in: "
                     f"{', '.join(sequences.BUILTIN)}) or 'file' (a sequence YAML), not both or neither")
    hold = r.number(spec["hold_s"], "hold_s") if "hold_s" in spec else 5.0
    rate = r.number(spec["rotation_rate_dps"], "rotation_rate_dps") if "rotation_rate_dps" in spec else 90.0
    settle = r.number(spec["settle_s"], "settle_s") if "settle_s" in spec else 1.0
    if "file" in spec:
        extra = [k for k in ("rotations", "hold_s", "rotation_rate_dps", "settle_s") if k in spec]
        if extra:
            raise r.fail(spec[extra[0]], f"'{extra[0]}' applies to built-in sequences; a sequence file "
                         "sets its own timing", column=extra[0])
        target = Path(r.scalar(spec["file"], "'file'"))
        if not target.is_absolute():
            target = r.path.parent / target
        return sequences.load_yaml(target)
    name = r.scalar(spec["name"], "'name'")
    if name not in sequences.BUILTIN:
        raise r.fail(spec["name"], f"unknown sequence {name!r}; built-in ones are "
                     f"{', '.join(sequences.BUILTIN)}, or give 'file: my-sequence.yaml'", column="name")
    rotations = r.boolean(spec["rotations"], "rotations") if "rotations" in spec else True
    return sequences.builtin(name, rotations, hold, rate, settle)


def _engine(r: PlanReader, node: yaml.Node) -> dict[str, Any]:
    eng = r.mapping(node, _ENGINE, "'engine'")
    out: dict[str, Any] = {}
    if "method" in eng:
        method = r.scalar(eng["method"], "'method'")
        if method not in METHODS:
            raise r.fail(eng["method"], f"method {method!r}: a factory run captures a labelled sequence, "
                         f"so the method is one of {', '.join(METHODS)}", column="method")
        out["method"] = method
    if "gravity" in eng and "latitude" in eng:
        raise r.fail(eng["latitude"], "give either 'gravity' or 'latitude' (and 'height'), not both",
                     column="latitude")
    if "gravity" in eng:
        g = r.number(eng["gravity"], "gravity")
        if not 9.7 <= g <= 9.9:
            raise r.fail(eng["gravity"], f"gravity {g}: local gravity on Earth is 9.78..9.84 m/s^2",
                         column="gravity")
        out["gravity"] = g
    if "latitude" in eng:
        lat = r.number(eng["latitude"], "latitude", positive=False)
        if not -90 <= lat <= 90:
            raise r.fail(eng["latitude"], f"latitude {lat}: must be within -90..90 degrees",
                         column="latitude")
        out["latitude"] = lat
    if "height" in eng:
        if "latitude" not in eng:
            raise r.fail(eng["height"], "'height' needs 'latitude' (normal gravity at the station)",
                         column="height")
        out["height"] = r.number(eng["height"], "height", positive=False)
    return out


def _limits(r: PlanReader, node: yaml.Node) -> tuple[LimitSpec, ...]:
    entries = r.mapping(node, set(), "'limits'")
    out = []
    for quantity, value_node in entries.items():
        key_node = next(k for k, v in node.value if v is value_node)
        if quantity not in QUANTITIES:
            raise r.fail(key_node, f"unknown quantity {shown(quantity)}; limits can be set on "
                         f"{', '.join(QUANTITIES)}", column=quantity)
        dimension = QUANTITIES[quantity][0]
        spec = r.mapping(value_node, _LIMIT, f"the limit of {quantity}")
        unit = r.scalar(spec["unit"], "'unit'") if "unit" in spec else SI_UNIT[dimension]
        allowed = [u for u, (d, _) in UNITS.items() if d == dimension]
        if unit not in UNITS or UNITS[unit][0] != dimension:
            raise r.fail(spec.get("unit", value_node), f"unit {shown(unit)} is not a unit of {quantity} "
                         f"({dimension}); use one of {', '.join(repr(u) for u in allowed)}", column="unit")
        if "max_abs" in spec and ("min" in spec or "max" in spec):
            raise r.fail(spec["max_abs"], "give either 'max_abs' or 'min'/'max', not both", column="max_abs")
        low: float | None
        high: float | None
        if "max_abs" in spec:
            bound = r.number(spec["max_abs"], "max_abs")
            low, high = -bound, bound
        else:
            low = r.number(spec["min"], "min", positive=False) if "min" in spec else None
            high = r.number(spec["max"], "max", positive=False) if "max" in spec else None
            if low is None and high is None:
                raise r.fail(value_node, f"the limit of {quantity} needs 'max_abs', 'min' or 'max'")
            if low is not None and high is not None and low > high:
                raise r.fail(spec["min"], f"'min' {low} is above 'max' {high}", column="min")
        out.append(LimitSpec(quantity, low, high, unit, key_node.start_mark.line + 1))
    return tuple(out)


def _export(r: PlanReader, node: yaml.Node) -> tuple[str, ...]:
    if not isinstance(node, yaml.SequenceNode):
        raise r.fail(node, f"'export' must be a list of formats, e.g. [c, json]; formats are "
                     f"{', '.join(EXPORT_FORMATS)}", column="export")
    out = []
    for item in node.value:
        fmt = r.scalar(item, "an export format")
        if fmt not in EXPORT_FORMATS:
            raise r.fail(item, f"unknown export format {fmt!r}; formats are {', '.join(EXPORT_FORMATS)}",
                         column="export")
        if fmt in out:
            raise r.fail(item, f"export format {fmt!r} is listed twice", column="export")
        out.append(fmt)
    return tuple(out)


def _instruments(r: PlanReader, node: yaml.Node) -> InstrumentPlan:
    """``instruments:``: each kind's URL and limits, and ``on_abort``."""
    section = r.mapping(node, _INSTRUMENTS, "'instruments'")
    urls: dict[str, str] = {}
    limits: dict[str, float] = {}
    run: dict[str, Any] = {}
    for kind, keys in _INSTRUMENT_KEYS.items():
        if kind not in section:
            continue
        entry = r.mapping(section[kind], keys, f"'instruments.{kind}'")
        if "url" not in entry:
            raise r.fail(section[kind], f"'instruments.{kind}' has no 'url' (e.g. {_EXAMPLE_URL[kind]})",
                         column="url")
        url = r.scalar(entry["url"], "'url'")
        if "://" not in url:
            raise r.fail(entry["url"], f"'url' {url!r} is not an instrument URL; write e.g. "
                         f"{_EXAMPLE_URL[kind]}", column="url")
        urls[kind] = url
        for key in sorted(keys - {"url", "mount"}):
            if key in entry:
                value = r.number(entry[key], key, positive=key not in ("min_c", "max_c", "soak_c"))
                if key in _RUN_KEYS:
                    run[_RUN_KEYS[key]] = value
                else:
                    limits[key] = value
        if "mount" in entry:
            mount = r.scalar(entry["mount"], "'mount'")
            if mount not in _MOUNTS:
                raise r.fail(entry["mount"], f"'mount' must be the unit axis along the table's inner axis, "
                             f"one of {', '.join(_MOUNTS)}, not {mount!r}", column="mount")
            run["mount"] = mount
    if "min_c" in limits and "max_c" in limits and limits["min_c"] >= limits["max_c"]:
        raise r.fail(section["chamber"], f"'min_c' {limits['min_c']:g} must be below 'max_c' "
                     f"{limits['max_c']:g}", column="min_c")
    on_abort = OnAbort()
    if "on_abort" in section:
        actions = r.mapping(section["on_abort"], {"chamber", "table", "supply"}, "'instruments.on_abort'")
        chosen = {}
        for kind, action_node in actions.items():
            action = r.scalar(action_node, f"'on_abort.{kind}'")
            problem = check_on_abort(kind, action)
            if problem is not None:
                raise r.fail(action_node, problem, column=kind)
            chosen[kind] = action
        on_abort = OnAbort(**chosen)
    checks = (("soak_c", "min_c", "max_c", "chamber"), ("supply_v", None, "max_v", "supply"),
              ("supply_a", None, "max_a", "supply"))
    for key, low, high, kind in checks:
        if key not in run:
            continue
        given = float(run[key])
        for bound, beyond in ((low, given < limits.get(low or "", -math.inf)),
                              (high, given > limits.get(high or "", math.inf))):
            if bound is not None and beyond:
                name = {"supply_v": "volts", "supply_a": "amps"}.get(key, key)
                raise r.fail(section[kind], f"'{name}' {given:g} is beyond '{bound}' {limits[bound]:g}",
                             column=name)
    return InstrumentPlan(chamber=urls.get("chamber"), table=urls.get("table"), supply=urls.get("supply"),
                          limits=Limits(**limits, source=f"the plan {r.path.name}"), on_abort=on_abort, **run)


_EXAMPLE_URL = {"chamber": "votsch://10.0.0.5", "table": "acutrol://10.0.0.7:5000", "supply": "scpi://10.0.0.9"}
