"""Calibration sequences as data: the built-in ones of ``shared/specs/capture-csv.md`` and YAML ones.

A sequence is a list of steps. A :class:`PoseStep` holds the unit still with the named sensor axes
up (label ``+z``, ``-x``, ``+x+y``); a :class:`RotationStep` turns it about one of its axes held
vertical (label ``rot+z``, ``rot-x``, ``rot+x:180``). The labels are the step labels of the capture.

A user-defined sequence file (YAML)::

    schema: imu-station/sequence/1     # optional; any other value is refused
    name: bench-check
    hold_s: 5                          # default hold of pose steps
    rotation_rate_dps: 90              # default rate of rotation steps
    settle_s: 1                        # still time before and after each rotation
    steps:
      - +z
      - {pose: -z, hold_s: 10}
      - rot+z
      - {rotation: rot+x:180, rate_dps: 45}

Every mistake is refused with the file, the line and what to write instead.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from station.common.yaml_file import read_yaml
from station.errors import InputFileError, StationError

SCHEMA = "imu-station/sequence/1"
SIX_POSITION = ("+x", "-x", "+y", "-y", "+z", "-z")
TWELVE_EXTRA = ("+x+y", "-x-y", "+y+z", "-y-z", "+z+x", "-z-x")
ROTATIONS = ("rot+x", "rot-x", "rot+y", "rot-y", "rot+z", "rot-z")
BUILTIN = ("six-position", "twelve-position", "rotations")
AXES = "xyz"

_POSE_RE = re.compile(r"^(?:[+-][xyz]){1,3}$")
_ROT_RE = re.compile(r"^rot([+-])([xyz])(?::([0-9]+(?:\.[0-9]*)?))?$")


class SequenceError(StationError):
    """A label or step that does not follow the spec; the loader turns it into an InputFileError."""


def pose_vector(label: str) -> np.ndarray:
    """The unit vector, in sensor axes, that points up in pose ``label`` (``+x+y`` -> (1,1,0)/sqrt 2).

    Parameters
    ----------
    label : str

    Returns
    -------
    ndarray, (3,)

    Raises
    ------
    SequenceError
        A label that is not signed axes, or names an axis twice.
    """
    if not _POSE_RE.match(label):
        raise SequenceError(f"pose {label!r} is not signed axes like '+z', '-x' or '+x+y'")
    v = np.zeros(3)
    for sign, axis in re.findall(r"([+-])([xyz])", label):
        i = AXES.index(axis)
        if v[i] != 0:
            raise SequenceError(f"pose {label!r} names axis {axis} twice")
        v[i] = 1.0 if sign == "+" else -1.0
    return v / np.linalg.norm(v)


def pose_label(up: np.ndarray) -> str:
    """The label of the pose whose up vector is ``up`` (inverse of :func:`pose_vector`).

    Parameters
    ----------
    up : ndarray, (3,)

    Returns
    -------
    str
    """
    up = np.asarray(up, float)
    parts = [("+" if up[i] > 0 else "-") + AXES[i] for i in range(3) if abs(up[i]) > 1e-9]
    return "".join(parts)


@dataclass(frozen=True)
class PoseStep:
    """Hold the unit still with ``label``'s axes up for ``hold_s`` seconds."""

    label: str
    hold_s: float = 5.0

    kind = "pose"

    def __post_init__(self) -> None:
        pose_vector(self.label)
        if not (math.isfinite(self.hold_s) and self.hold_s > 0):
            raise SequenceError(f"hold_s of {self.label!r} must be a positive number of seconds, "
                                f"not {self.hold_s}")

    @property
    def up(self) -> np.ndarray:
        """Unit vector (sensor frame) that points up in this pose."""
        return pose_vector(self.label)


@dataclass(frozen=True)
class RotationStep:
    """Turn ``angle_deg`` about sensor axis ``axis`` (0, 1, 2) held vertical; negative is clockwise.

    ``settle_s`` of stillness is captured before and after the turn (both under the step's
    label), so an engine can take the gyro bias from them and integrate the turn between.
    """

    label: str
    rate_dps: float = 90.0
    settle_s: float = 1.0

    kind = "rotation"

    def __post_init__(self) -> None:
        parse_rotation(self.label)
        if not (math.isfinite(self.rate_dps) and self.rate_dps > 0):
            raise SequenceError(f"rate_dps of {self.label!r} must be a positive number, not {self.rate_dps}")
        if not (math.isfinite(self.settle_s) and self.settle_s > 0):
            raise SequenceError(f"settle_s of {self.label!r} must be a positive number, not {self.settle_s}")

    @property
    def axis(self) -> int:
        """Index (0, 1, 2) of the sensor axis turned about."""
        return parse_rotation(self.label)[0]

    @property
    def angle_deg(self) -> float:
        """Signed angle of the turn, deg (negative for rot-)."""
        return parse_rotation(self.label)[1]

    @property
    def axis_vector(self) -> np.ndarray:
        """Unit vector of the turn's axis, sensor frame."""
        v = np.zeros(3)
        v[self.axis] = 1.0
        return v

    @property
    def start_pose(self) -> str:
        """The pose the turn starts from: its axis up."""
        return "+" + AXES[self.axis]

    @property
    def duration_s(self) -> float:
        """Nominal time of the turn itself at ``rate_dps`` (the settles not included)."""
        return abs(self.angle_deg) / self.rate_dps


Step = PoseStep | RotationStep


def parse_rotation(label: str) -> tuple[int, float]:
    """(axis index, signed angle in degrees) of a rotation label: ``rot-z`` -> (2, -360.0).

    Parameters
    ----------
    label : str

    Returns
    -------
    tuple
        (axis index, signed angle in degrees).

    Raises
    ------
    SequenceError
        Not a rotation label, or an angle outside (0, 3600] degrees.
    """
    m = _ROT_RE.match(label)
    if not m:
        raise SequenceError(f"rotation {label!r} is not like 'rot+z', 'rot-x' or 'rot+x:180'")
    sign, axis, degrees = m.groups()
    angle = float(degrees) if degrees else 360.0
    if not 0 < angle <= 3600:
        raise SequenceError(f"rotation {label!r}: the angle must be above 0 and at most 3600 degrees")
    return AXES.index(axis), angle if sign == "+" else -angle


def make_step(label: str, hold_s: float = 5.0, rate_dps: float = 90.0, settle_s: float = 1.0) -> Step:
    """A step from its label alone: ``rot...`` is a rotation, anything else a pose.

    Parameters
    ----------
    label : str
    hold_s : float
        Seconds held still.
    rate_dps : float
        Rotation rate, deg/s.
    settle_s : float
        Seconds still after a rotation.

    Returns
    -------
    PoseStep or RotationStep
    """
    if label.startswith("rot"):
        return RotationStep(label, rate_dps=rate_dps, settle_s=settle_s)
    return PoseStep(label, hold_s=hold_s)


@dataclass(frozen=True)
class Sequence:
    """A named, ordered list of steps; labels are unique within a sequence."""

    name: str
    steps: tuple[Step, ...]

    def __post_init__(self) -> None:
        if not self.steps:
            raise SequenceError(f"sequence {self.name!r} has no steps")
        seen: set[str] = set()
        for step in self.steps:
            if step.label in seen:
                raise SequenceError(f"sequence {self.name!r} has step {step.label!r} twice; "
                                    "labels must be unique")
            seen.add(step.label)

    def __len__(self) -> int:
        return len(self.steps)

    @property
    def labels(self) -> list[str]:
        """The step labels, in order."""
        return [s.label for s in self.steps]

    @property
    def nominal_duration_s(self) -> float:
        """Capture time of all steps if the operator were instant."""
        return sum(s.hold_s if isinstance(s, PoseStep) else s.duration_s + 2 * s.settle_s for s in self.steps)

    def with_timing(self, hold_s: float | None = None, rate_dps: float | None = None,
                    settle_s: float | None = None) -> Sequence:
        """The same steps with every hold, rate or settle replaced (short runs in tests and demos).

        Parameters
        ----------
        hold_s, rate_dps, settle_s : float, optional
            New values; None keeps each step's own.

        Returns
        -------
        Sequence
        """
        steps: list[Step] = []
        for s in self.steps:
            if isinstance(s, PoseStep):
                steps.append(replace(s, hold_s=hold_s) if hold_s is not None else s)
            else:
                steps.append(replace(s, rate_dps=s.rate_dps if rate_dps is None else rate_dps,
                                     settle_s=s.settle_s if settle_s is None else settle_s))
        return Sequence(self.name, tuple(steps))


def builtin(name: str, rotations: bool = True, hold_s: float = 5.0, rotation_rate_dps: float = 90.0,
            settle_s: float = 1.0) -> Sequence:
    """A built-in sequence of the capture-csv spec, optionally followed by the six rotations.

    ``rotations`` alone (name ``"rotations"``) is the six rotations without static poses.

    Parameters
    ----------
    name : str
        A key of ``BUILTIN``, or ``"rotations"``.
    rotations : bool
        Append the six rotations.
    hold_s, rotation_rate_dps, settle_s : float
        Timing of every step.

    Returns
    -------
    Sequence

    Raises
    ------
    SequenceError
        An unknown name.
    """
    poses: tuple[str, ...]
    if name == "six-position":
        poses = SIX_POSITION
    elif name == "twelve-position":
        poses = SIX_POSITION + TWELVE_EXTRA
    elif name == "rotations":
        poses, rotations = (), True
    else:
        raise SequenceError(f"unknown sequence {name!r}; built-in ones are {', '.join(BUILTIN)}, "
                            "or give a YAML sequence file")
    steps: list[Step] = [PoseStep(p, hold_s=hold_s) for p in poses]
    if rotations:
        steps += [RotationStep(r, rate_dps=rotation_rate_dps, settle_s=settle_s) for r in ROTATIONS]
    suffix = "" if name == "rotations" or not rotations else "+rotations"
    return Sequence(name + suffix, tuple(steps))


def resolve(name_or_path: str, rotations: bool = True, hold_s: float = 5.0,
            rotation_rate_dps: float = 90.0) -> Sequence:
    """A built-in sequence by name, or the sequence of a YAML file (``rotations`` applies to built-ins).

    Parameters
    ----------
    name_or_path : str
    rotations : bool
    hold_s, rotation_rate_dps : float
        Timing of the built-in sequences.

    Returns
    -------
    Sequence

    Raises
    ------
    InputFileError
        Neither a built-in name nor a readable sequence file.
    """
    if name_or_path in BUILTIN:
        try:
            return builtin(name_or_path, rotations, hold_s, rotation_rate_dps)
        except SequenceError as exc:
            raise InputFileError("--sequence", str(exc)) from None
    path = Path(name_or_path)
    if path.suffix.lower() not in (".yaml", ".yml") and not path.exists():
        raise InputFileError(name_or_path, f"is neither a built-in sequence ({', '.join(BUILTIN)}) "
                             "nor a YAML sequence file")
    return load_yaml(path)


# ---- YAML sequences --------------------------------------------------------------------------------

_TOP_KEYS = {"schema", "name", "hold_s", "rotation_rate_dps", "settle_s", "steps"}
_POSE_KEYS = {"pose", "hold_s"}
_ROT_KEYS = {"rotation", "rate_dps", "settle_s"}


def _line(node: yaml.Node) -> int:
    return node.start_mark.line + 1


def _number(node: yaml.Node, path: Path, key: str) -> float:
    # Only a plain scalar can be a number: "5" in quotes is a string and is refused.
    value = yaml.safe_load(node.value) if isinstance(node, yaml.ScalarNode) and node.style is None else None
    if not (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value) and value > 0):
        raise InputFileError(path, f"'{key}' must be a positive number, not {getattr(node, 'value', '?')!r}",
                             line=_line(node), column=key)
    return float(value)


def _scalar(node: yaml.Node, path: Path, what: str) -> str:
    if not isinstance(node, yaml.ScalarNode):
        raise InputFileError(path, f"{what} must be a plain value", line=_line(node))
    return str(node.value)


def load_yaml(path: str | Path) -> Sequence:
    """Read a sequence file; refuse unknown keys, bad labels and bad numbers naming the line.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    Sequence

    Raises
    ------
    InputFileError
        Naming the file, line and key.
    """
    path = Path(path)
    root = read_yaml(path, "does not exist; give a built-in sequence name or a YAML sequence file").root
    if not isinstance(root, yaml.MappingNode):
        raise InputFileError(path, "must be a YAML mapping with 'name' and 'steps'", line=1)
    top = {}
    for key_node, value_node in root.value:
        key = _scalar(key_node, path, "a key")
        if key not in _TOP_KEYS:
            raise InputFileError(path, f"unknown key {key!r}; known keys are {', '.join(sorted(_TOP_KEYS))}",
                                 line=_line(key_node), column=key)
        top[key] = value_node
    if "schema" in top and _scalar(top["schema"], path, "'schema'") != SCHEMA:
        raise InputFileError(path, f"schema is {top['schema'].value!r}, this station reads {SCHEMA!r}",
                             line=_line(top["schema"]), column="schema")
    name = _scalar(top["name"], path, "'name'") if "name" in top else path.stem
    defaults = {
        "hold_s": _number(top["hold_s"], path, "hold_s") if "hold_s" in top else 5.0,
        "rate_dps": _number(top["rotation_rate_dps"], path, "rotation_rate_dps")
        if "rotation_rate_dps" in top else 90.0,
        "settle_s": _number(top["settle_s"], path, "settle_s") if "settle_s" in top else 1.0,
    }
    if "steps" not in top:
        raise InputFileError(path, "has no 'steps'; list poses and rotations, e.g. steps: [+z, -z, rot+z]",
                             line=_line(root), column="steps")
    steps_node = top["steps"]
    if not isinstance(steps_node, yaml.SequenceNode) or not steps_node.value:
        raise InputFileError(path, "'steps' must be a non-empty list of poses and rotations",
                             line=_line(steps_node), column="steps")
    steps: list[Step] = []
    seen: dict[str, int] = {}
    for node in steps_node.value:
        step = _step(node, path, defaults)
        if step.label in seen:
            raise InputFileError(path, f"step {step.label!r} is already at line {seen[step.label]}; "
                                 "labels must be unique", line=_line(node))
        seen[step.label] = _line(node)
        steps.append(step)
    return Sequence(name, tuple(steps))


def _step(node: yaml.Node, path: Path, defaults: dict[str, float]) -> Step:
    line = _line(node)
    try:
        if isinstance(node, yaml.ScalarNode):
            return make_step(str(node.value), defaults["hold_s"], defaults["rate_dps"], defaults["settle_s"])
        if not isinstance(node, yaml.MappingNode):
            raise SequenceError("a step is a label ('+z', 'rot+x') or a mapping like {pose: +z, hold_s: 5}")
        fields: dict[str, Any] = {}
        for key_node, value_node in node.value:
            fields[_scalar(key_node, path, "a key")] = value_node
        if "pose" in fields:
            _refuse_unknown(fields, _POSE_KEYS, path)
            hold = _number(fields["hold_s"], path, "hold_s") if "hold_s" in fields else defaults["hold_s"]
            return PoseStep(_scalar(fields["pose"], path, "'pose'"), hold_s=hold)
        if "rotation" in fields:
            _refuse_unknown(fields, _ROT_KEYS, path)
            rate = _number(fields["rate_dps"], path, "rate_dps") if "rate_dps" in fields \
                else defaults["rate_dps"]
            settle = _number(fields["settle_s"], path, "settle_s") if "settle_s" in fields \
                else defaults["settle_s"]
            label = _scalar(fields["rotation"], path, "'rotation'")
            if not label.startswith("rot"):
                raise SequenceError(f"rotation {label!r} must start with 'rot', like 'rot+z'")
            return RotationStep(label, rate_dps=rate, settle_s=settle)
        raise SequenceError("a step mapping needs 'pose' (pose: +z) or 'rotation' (rotation: rot+x)")
    except SequenceError as exc:
        raise InputFileError(path, str(exc), line=line) from None


def _refuse_unknown(fields: dict[str, Any], known: set[str], path: Path) -> None:
    for key, value_node in fields.items():
        if key not in known:
            raise InputFileError(path, f"unknown step key {key!r}; it takes {', '.join(sorted(known))}",
                                 line=_line(value_node), column=key)
