"""Checks of a node's ``--params-file`` files before rcl reads them, so a file rcl cannot parse is
one line naming the file and the fault, not rcl's 23-line traceback from ``rclpy.init``.

What rcl's YAML parser refuses or chokes on, refused here first (``ParamsFileError``, one line of
at most a few hundred characters):

- a path that is missing or not a regular file (a FIFO would block), a file over
  ``MAX_BYTES``, a binary file, malformed YAML, a key given twice (``sdhn_base.yaml_io``);
- anchors, aliases and tags (rcl does not expand them; ``!!binary``), non-scalar values,
  ``null``;
- a list mixing types (``[1, "a"]``), an integer outside int64;
- more than ``MAX_ENTRIES`` parameters in one file (300,000 stalled start-up for over a minute),
  a string longer than ``MAX_STRING`` characters;
- a layout other than ``node_name: {ros__parameters: {...}}``.

Names a node does not declare are warned about by the runner (``unknown_parameters``).
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from sdhn_base.yaml_io import YamlError, load_yaml

MAX_BYTES = 1 << 20
MAX_ENTRIES = 10_000
MAX_STRING = 64 * 1024
INT64 = (-(2**63), 2**63 - 1)
# A node key as rcl reads it: /-separated tokens, each a name or a wildcard (* or **)
_TOKEN = r"(\*\*|\*|[A-Za-z_][A-Za-z0-9_]*)"
NODE_KEY = re.compile(rf"/?{_TOKEN}(/{_TOKEN})*")


class ParamsFileError(ValueError):
    """A parameters file that rcl would refuse, or that no node of ours should read."""


def params_files(args: Sequence[str]) -> list[str]:
    """The paths given with ``--params-file`` in ``args`` (ROS arguments)."""
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == "--params-file"]


def _short(text: str, n: int = 80) -> str:
    return text if len(text) <= n else f"{text[:n]}... ({len(text)} characters)"


def _leaf(where: str, value: Any) -> type:
    """The type of a scalar parameter value, or ParamsFileError."""
    if isinstance(value, bool):
        return bool
    if isinstance(value, int):
        if not INT64[0] <= value <= INT64[1]:
            raise ParamsFileError(f"{where}: {_short(str(value))} is outside int64")
        return int
    if isinstance(value, float):
        return float
    if isinstance(value, str):
        if len(value) > MAX_STRING:
            raise ParamsFileError(f"{where}: a string of {len(value)} characters; allowed: at "
                                  f"most {MAX_STRING}")
        return str
    what = "null" if value is None else type(value).__name__
    raise ParamsFileError(f"{where}: {what}; allowed: a bool, integer, float, string or a list "
                          "of one of these")


def _walk(prefix: str, body: Mapping[Any, Any], count: list[int]) -> None:
    for key, value in body.items():
        where = f"{prefix}.{key}" if prefix else str(key)
        if not isinstance(key, str):
            raise ParamsFileError(f"{_short(where)}: parameter names are strings")
        if isinstance(value, Mapping):  # nested names: a.b.c
            _walk(where, value, count)
            continue
        count[0] += 1
        if count[0] > MAX_ENTRIES:
            raise ParamsFileError(f"more than {MAX_ENTRIES} parameters")
        if isinstance(value, list):
            kinds = {_leaf(f"{where}[{k}]", v) for k, v in enumerate(value)}
            if len(kinds) > 1:
                raise ParamsFileError(f"{_short(where)}: a list mixing "
                                      f"{', '.join(sorted(t.__name__ for t in kinds))}; allowed: "
                                      "one type per list")
        else:
            _leaf(_short(where), value)


def check_params_file(path: str) -> None:
    """ParamsFileError naming ``path`` and the first fault rcl would refuse (module docstring)."""
    p = Path(path)
    try:
        info = os.stat(p)
    except OSError as e:
        raise ParamsFileError(f"--params-file {path}: {e.strerror or e}") from None
    if not stat.S_ISREG(info.st_mode):
        raise ParamsFileError(f"--params-file {path}: not a regular file")
    if info.st_size > MAX_BYTES:
        raise ParamsFileError(f"--params-file {path}: {info.st_size} bytes; allowed: at most "
                              f"{MAX_BYTES}")
    try:
        data = load_yaml(p, what="--params-file", max_bytes=MAX_BYTES)
        text = p.read_text(encoding="utf-8")
        for token in yaml.scan(text):
            if isinstance(token, yaml.AnchorToken | yaml.AliasToken | yaml.TagToken):
                raise ParamsFileError(f"--params-file {path}: anchors, aliases or tags (&, *, !) "
                                      f"at line {token.start_mark.line + 1}; rcl does not read "
                                      "them")
    except YamlError as e:
        raise ParamsFileError(_short(str(e), 300)) from None
    except (yaml.YAMLError, UnicodeDecodeError, OSError) as e:
        raise ParamsFileError(f"--params-file {path}: {_short(str(e), 200)}") from None
    if not isinstance(data, Mapping):
        raise ParamsFileError(f"--params-file {path}: allowed: a mapping of node names, each "
                              "with ros__parameters")
    count = [0]
    for node, body in data.items():
        if not (isinstance(node, str) and NODE_KEY.fullmatch(node)):
            raise ParamsFileError(f"--params-file {path}: node key {_short(repr(node))}; "
                                  "allowed: /-separated names (letters, digits, _) or * and **")
        if not (isinstance(body, Mapping) and isinstance(body.get("ros__parameters"), Mapping)):
            raise ParamsFileError(f"--params-file {path}: {_short(str(node))}: allowed: "
                                  "{ros__parameters: {name: value, ...}}")
        try:
            _walk("", body["ros__parameters"], count)
        except ParamsFileError as e:
            raise ParamsFileError(f"--params-file {path}: {_short(str(node))}: {e}") from None


def unknown_parameters(overrides: Sequence[str], declared: Sequence[str]) -> list[str]:
    """Names given to a node (files, ``-p``) that it does not declare (a misspelt name did
    nothing, silently)."""
    return sorted(set(overrides) - set(declared) - {"use_sim_time"})
