"""The one YAML reader for every file the project reads (suites, training configs, launch files,
``--set`` values): PyYAML's safe loader plus the checks it lacks.

    data = load_yaml(Path("configs/suites/paper.yaml"), what="suite")   # a file
    value = load_yaml("[1, 2]", what="--set seeds")                     # text

Refused, each as one :class:`YamlError` line naming ``what`` (and the line where it applies):

- a key given twice in one mapping (PyYAML keeps the last one silently: a suite defining
  ``sdhn:`` twice trained one method under the other's label);
- a document whose alias expansion would exceed ``MAX_NODES`` nodes (a "billion laughs" file of
  a few hundred bytes otherwise builds gigabytes of lists), and a recursive alias;
- a file over ``MAX_BYTES`` (read no further than that), a binary file, malformed YAML, nesting
  deeper than the parser's recursion allows, a path that is not a regular file (a FIFO would
  block the reader).

Merge keys (``<<: *base``) stay allowed: a key that the mapping itself sets overrides the merged
one, as YAML specifies; only a key written twice in the same mapping is a duplicate.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, SequenceNode

__all__ = ["MAX_BYTES", "MAX_NODES", "YamlError", "load_yaml"]

MAX_BYTES = 1 << 20  # the largest file read; our suites and configs are a few KiB
MAX_NODES = 200_000  # nodes after alias expansion; paper.yaml has ~300

_MERGE_TAG = "tag:yaml.org,2002:merge"


class YamlError(ValueError):
    """A YAML source that cannot be read safely; the message is one line naming it."""


def _line(node: Node) -> int:
    return int(node.start_mark.line) + 1


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key written twice in one mapping."""

    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, MappingNode):  # checked before the merge keys are flattened in
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_TAG:
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: SafeLoader refuses it itself
                    continue
                if first is not None:
                    raise _Duplicate(f"duplicate key {key!r} at line {_line(key_node)} "
                                     f"(first at line {first})")
                seen[key] = _line(key_node)
        return super().construct_mapping(node, deep=deep)


class _Duplicate(Exception):
    """Raised inside the constructor; turned into a YamlError naming the source."""


def _expanded_size(root: Node, limit: int) -> int:
    """Nodes the document has once every alias is expanded (an alias counts its whole target
    each time), computed without expanding; > ``limit`` stops early. ValueError on a cycle."""
    size: dict[int, int] = {}
    active: set[int] = set()
    stack: list[tuple[Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if key in size:
            continue
        kids: list[Node] = []
        if isinstance(node, SequenceNode):
            kids = list(node.value)
        elif isinstance(node, MappingNode):
            kids = [n for pair in node.value for n in pair]
        if children_done:
            active.discard(key)
            size[key] = min(limit + 1, 1 + sum(size[id(k)] for k in kids))
            continue
        if key in active:
            raise ValueError("a recursive alias (a node that contains itself)")
        active.add(key)
        stack.append((node, True))
        for kid in kids:
            if id(kid) in active:
                raise ValueError("a recursive alias (a node that contains itself)")
            if id(kid) not in size:
                stack.append((kid, False))
    return size[id(root)]


def _read(path: Path, what: str, max_bytes: int) -> str:
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):  # a FIFO would block open() for good
            raise YamlError(f"{what}: not a regular file (a FIFO, socket, device or directory)")
        with open(path, "rb") as f:
            raw = f.read(max_bytes + 1)
    except OSError as e:
        raise YamlError(f"{what}: cannot read: {e.strerror or e}") from None
    if len(raw) > max_bytes:
        raise YamlError(f"{what}: larger than {max_bytes} bytes (a YAML file here is a few "
                        "KiB)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise YamlError(f"{what}: not a text file (UTF-8 YAML expected)") from None


def load_yaml(source: str | Path, *, what: str, max_bytes: int = MAX_BYTES,
              max_nodes: int = MAX_NODES) -> Any:
    """The single YAML document in ``source`` (a ``Path``: that file; a ``str``: the text
    itself), as plain Python data (None for an empty document). ``what`` names the source in
    every error, e.g. ``"suite"`` or ``"config"``. Raises :class:`YamlError` (a ValueError,
    one line) for everything listed in the module docstring."""
    if isinstance(source, Path):
        what = f"{what} {source}" if what else str(source)
        text = _read(source, what, max_bytes)
    else:
        text = source
        if len(text.encode("utf-8", "surrogatepass")) > max_bytes:
            raise YamlError(f"{what}: larger than {max_bytes} bytes")
    try:
        loader = _StrictLoader(text)
    except yaml.YAMLError as e:  # the reader refuses control characters up front
        raise YamlError(f"{what}: malformed YAML: {str(e).splitlines()[0]}") from None
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        try:
            nodes = _expanded_size(node, max_nodes)
        except ValueError as e:
            raise YamlError(f"{what}: {e} at line {_line(node)}") from None
        if nodes > max_nodes:
            raise YamlError(f"{what}: aliases expand to more than {max_nodes} nodes (an alias "
                            "bomb?); write the data out instead of nesting aliases")
        return loader.construct_document(node)
    except _Duplicate as e:
        raise YamlError(f"{what}: {e}") from None
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        at = f" at line {mark.line + 1}" if mark is not None else ""
        raise YamlError(f"{what}: malformed YAML{at}: {e.problem or e.context or 'unreadable'}"
                        ) from None
    except yaml.YAMLError as e:
        raise YamlError(f"{what}: malformed YAML: {str(e).splitlines()[0] if str(e) else e}"
                        ) from None
    except RecursionError:
        raise YamlError(f"{what}: nested too deeply") from None
    finally:
        loader.dispose()
