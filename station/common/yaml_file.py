"""Reading the YAML files a user gives (parameter, sequence and plan files), within bounds.

One reader for all of them, so a hostile or broken file fails the same quick way everywhere:

- a file above ``MAX_BYTES`` is refused before it is read (a parameter file is a few tens of kB);
- aliases are counted as what they expand to while the file is composed, and a document that
  would expand past ``MAX_NODES`` nodes is refused at that point (a few kB of nested aliases
  otherwise expand to billions of nodes), as is an alias to a node that contains it;
- nesting deeper than ``MAX_DEPTH`` is refused before it can exhaust the stack;
- only plain YAML is constructed: mappings, lists, text, numbers, booleans and null. A timestamp
  stays the text it was written as; binary data, sets and ordered pairs are refused;
- with ``unique_keys`` (frame descriptions), a key given twice in one mapping is refused at its
  second line: PyYAML keeps the last silently, so a typo'd copy would win over the line it meant to fix.

Every refusal is an :class:`~station.errors.InputFileError` of one line naming the file and,
where there is one, the line.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from station.common.text import printable
from station.errors import InputFileError

MAX_BYTES = 256 * 1024  # a parameter file with 64 thermal segments per triad is 80 kB
MAX_NODES = 20_000  # that file has 4,200 nodes
MAX_DEPTH = 40


class _Refused(Exception):
    """A bound the document breaks, at a place in it."""

    def __init__(self, problem: str, mark: Any):
        super().__init__(problem)
        self.problem = problem
        self.line = mark.line + 1 if mark is not None else None


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader, counting nodes (an alias as the nodes it stands for) and depth."""

    def __init__(self, text: str):
        super().__init__(text)
        self._count = 0
        self._depth = 0
        self._sizes: dict[int, int] = {}

    def _grow(self, nodes: int, mark: Any) -> None:
        self._count += nodes
        if self._count > MAX_NODES:
            raise _Refused(f"expands to more than {MAX_NODES} values (aliases count as what they repeat); "
                           "a parameter, sequence or plan file needs a few thousand", mark)

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            target = self.anchors.get(event.anchor)
            if target is not None:
                size = self._sizes.get(id(target))
                if size is None:
                    raise _Refused(f"alias *{event.anchor} refers to a node that contains it",
                                   event.start_mark)
                self._grow(size, event.start_mark)
            return super().compose_node(parent, index)
        self._depth += 1
        if self._depth > MAX_DEPTH:
            raise _Refused(f"nests deeper than {MAX_DEPTH} levels", event.start_mark)
        start = self._count
        self._grow(1, event.start_mark)
        node = super().compose_node(parent, index)
        self._depth -= 1
        if event.anchor is not None:
            self._sizes[id(node)] = self._count - start
        return node


def _refuse_tag(loader: yaml.SafeLoader, node: yaml.Node) -> Any:
    tag = node.tag.replace("tag:yaml.org,2002:", "!!")
    raise yaml.constructor.ConstructorError(
        None, None, f"tag {tag} is not read here; use plain mappings, lists, text and numbers",
        node.start_mark)


_BoundedLoader.add_constructor("tag:yaml.org,2002:timestamp", yaml.SafeLoader.construct_yaml_str)
for _tag in ("binary", "set", "omap", "pairs"):
    _BoundedLoader.add_constructor(f"tag:yaml.org,2002:{_tag}", _refuse_tag)


@dataclass
class YamlFile:
    """A composed YAML file: its bytes, its root node (None when empty) and the nodes' lines."""

    path: Path
    raw: bytes
    root: yaml.Node | None
    _loader: _BoundedLoader = field(repr=False)

    def construct(self) -> Any:
        """The document as plain Python values (dict, list, str, int, float, bool, None)."""
        if self.root is None:
            return None
        try:
            return self._loader.construct_document(self.root)
        except yaml.YAMLError as exc:
            raise InputFileError.invalid_yaml(self.path, exc) from None

    def line_of(self, keys: Sequence[str | int]) -> int | None:
        """The line of the value at ``keys`` (mapping keys and list indices), or of the deepest part
        of that path the file has; None for an empty file."""
        node = self.root
        line = node.start_mark.line + 1 if node is not None else None
        for key in keys:
            child = _child(node, key)
            if child is None:
                break
            node = child
            line = node.start_mark.line + 1
        return line


def _child(node: yaml.Node | None, key: str | int) -> yaml.Node | None:
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            if isinstance(key_node, yaml.ScalarNode) and key_node.value == str(key):
                return value_node
    elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and 0 <= key < len(node.value):
        return node.value[key]
    return None


def read_bytes(path: str | Path, missing: str, max_bytes: int = MAX_BYTES) -> bytes:
    """The bytes of a file the user gave, refused past ``max_bytes`` without reading them all.

    ``missing`` is what to say when the file does not exist ("does not exist; give ...").
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            data = fh.read(max_bytes + 1)
    except FileNotFoundError:
        raise InputFileError(path, missing) from None
    except OSError as exc:
        raise InputFileError(path, f"cannot be read: {exc.strerror or exc}") from None
    if len(data) > max_bytes:
        raise InputFileError(path, f"is larger than {max_bytes // 1024} KiB, the most this station reads "
                             "from a YAML file; give the file the station wrote")
    return data


def _duplicate_key(root: yaml.Node | None) -> tuple[yaml.Node, str, int] | None:
    """The first key node given twice in one mapping (document order), its text and its first line."""
    stack = [root] if root is not None else []
    seen_nodes: set[int] = set()  # an alias repeats a node: walk it once
    found: list[tuple[yaml.Node, str, int]] = []
    while stack:
        node = stack.pop()
        if id(node) in seen_nodes:
            continue
        seen_nodes.add(id(node))
        if isinstance(node, yaml.MappingNode):
            lines: dict[str, int] = {}
            for key_node, value_node in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    if key_node.value in lines:
                        found.append((key_node, key_node.value, lines[key_node.value]))
                        break
                    lines[key_node.value] = key_node.start_mark.line + 1
                stack.append(value_node)
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)
    return min(found, key=lambda f: f[0].start_mark.index, default=None)


def read_yaml(path: str | Path, missing: str, max_bytes: int = MAX_BYTES,
              unique_keys: bool = False) -> YamlFile:
    """Read and compose a YAML file within the module's bounds (see the module docstring); with
    ``unique_keys``, refuse a key given twice in one mapping."""
    path = Path(path)
    raw = read_bytes(path, missing, max_bytes)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputFileError(path, f"is not UTF-8 text (byte 0x{raw[exc.start]:02x})", line=line) from None
    try:
        loader = _BoundedLoader(text)
        root = loader.get_single_node()
    except _Refused as exc:
        raise InputFileError(path, exc.problem, line=exc.line) from None
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        raise InputFileError(path, f"is not valid YAML: character U+{exc.character:04X} is not allowed",
                             line=line) from None
    except yaml.YAMLError as exc:
        raise InputFileError.invalid_yaml(path, exc) from None
    if unique_keys:
        twice = _duplicate_key(root)
        if twice is not None:
            node, key, first = twice
            raise InputFileError(path, f"key given twice (first on line {first}); PyYAML would keep the last "
                                 "silently: keep one", line=node.start_mark.line + 1,
                                 column=printable(key, 60))
    return YamlFile(path, raw, root, loader)
