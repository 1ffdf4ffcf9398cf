"""The plan file's YAML nodes read with their lines: every refusal of ``station.factory.plan`` and its
``campaign:`` section (``station.factory.campaign_plan``) names the file, the line and the key."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from station.common.text import printable
from station.errors import InputFileError

KEY_CHARS = 60
"""The most of a key or value of the file an error message shows."""


def shown(text: str) -> str:
    """A key or value of the file in an error message: quoted, escaped and cut (a key may be anything)."""
    return f"'{printable(text, KEY_CHARS)}'"


class PlanReader:
    """Walks the composed YAML nodes so every refusal can name its line."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, node: yaml.Node | None, problem: str, column: str | None = None) -> InputFileError:
        """The error for ``node``: the file, the node's line, the key (``column``) and the problem."""
        line = node.start_mark.line + 1 if node is not None else None
        # a key is the file's text: escaped and cut here, as the repr() of a key in a problem is
        return InputFileError(self.path, problem, line=line,
                              column=None if column is None else printable(column, KEY_CHARS))

    def mapping(self, node: yaml.Node, known: set[str], what: str) -> dict[str, yaml.Node]:
        """The keys of a mapping node and their value nodes; an unknown key (``known`` given) or one twice
        is refused."""
        if not isinstance(node, yaml.MappingNode):
            raise self.fail(node, f"{what} must be a mapping (key: value lines)")
        out: dict[str, yaml.Node] = {}
        for key_node, value_node in node.value:
            key = self.scalar(key_node, "a key")
            if known and key not in known:
                raise self.fail(key_node, f"unknown key {shown(key)} in {what}; known keys are "
                                f"{', '.join(sorted(known))}", column=key)
            if key in out:
                raise self.fail(key_node, f"key {shown(key)} appears twice in {what}", column=key)
            out[key] = value_node
        return out

    def scalar(self, node: yaml.Node, what: str) -> str:
        """A plain value's text; a list or mapping is refused."""
        if not isinstance(node, yaml.ScalarNode):
            raise self.fail(node, f"{what} must be a plain value")
        return str(node.value)

    def value(self, node: yaml.Node) -> Any:
        """A plain value as YAML reads it (number, bool, text); a quoted one stays text."""
        if isinstance(node, yaml.ScalarNode) and node.style is None:
            return yaml.safe_load(node.value)
        return self.scalar(node, "a value")

    def number(self, node: yaml.Node, key: str, positive: bool = True) -> float:
        """A finite number (above 0 when ``positive``)."""
        value = self.value(node)
        good = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if not good or (positive and value <= 0):
            kind = "a positive number" if positive else "a number"
            raise self.fail(node, f"'{key}' must be {kind}, not {getattr(node, 'value', '?')!r}", column=key)
        return float(value)

    def integer(self, node: yaml.Node, key: str) -> int:
        """A whole number above 0."""
        value = self.value(node)
        if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
            raise self.fail(node, f"'{key}' must be a positive whole number, not {node.value!r}", column=key)
        return value

    def boolean(self, node: yaml.Node, key: str) -> bool:
        """true or false."""
        value = self.value(node)
        if not isinstance(value, bool):
            raise self.fail(node, f"'{key}' must be true or false, not {node.value!r}", column=key)
        return value
