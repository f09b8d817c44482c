"""``ros2msg`` schema text for MCAP channels, built from the installed ``.msg`` definitions.

The layout follows ROS 2's own recorder, which Foxglove's strict parser expects
(docs/ros-graph.md): the root definition first, then each nested type once, behind a line of
80 ``=`` and a ``MSG:`` header that spells the type exactly as the fields do
(``std_msgs/Header``, never ``std_msgs/msg/Header``).
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Callable
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any

PRIMITIVES = frozenset(
    [
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    ]
)
SEPARATOR = "=" * 80
_ARRAY_OR_BOUND = re.compile(r"(\[[^\]]*\]|<=\d+)")


def _split(type_name: str) -> tuple[str, str]:
    """'sdhn_msgs/msg/RobotAction' or 'sdhn_msgs/RobotAction' -> ('sdhn_msgs', 'RobotAction')."""
    parts = type_name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f"not a ROS message type name: {type_name!r} (want pkg/msg/Type)")


def _sdhn_msgs() -> ModuleType:
    import sdhn_msgs.msg

    return sdhn_msgs.msg


def _std_msgs() -> ModuleType:
    import std_msgs.msg

    return std_msgs.msg


def _builtin_interfaces() -> ModuleType:
    import builtin_interfaces.msg

    return builtin_interfaces.msg


# The message packages a recording may hold, by name: a type name read from a file or from the
# graph only ever selects one of these; it never names a module to import.
MESSAGE_PACKAGES: dict[str, Callable[[], ModuleType]] = {
    "sdhn_msgs": _sdhn_msgs,
    "std_msgs": _std_msgs,
    "builtin_interfaces": _builtin_interfaces,
}


class UnknownMessageType(LookupError):
    """A type name outside :data:`MESSAGE_PACKAGES`, or not a class in its package."""


def message_class(type_name: str) -> Any:
    """'pkg/msg/Type' (or 'pkg/Type') -> the installed Python message class.

    Raises ValueError for a malformed name, UnknownMessageType for a package outside the
    allowlist or a type the package does not have."""
    package, name = _split(type_name)
    load = MESSAGE_PACKAGES.get(package)
    if load is None:
        raise UnknownMessageType(f"{type_name}: package {package!r} is not one this project "
                                 f"records; allowed: {', '.join(MESSAGE_PACKAGES)}")
    cls = getattr(load(), name, None)
    if not isinstance(cls, type):
        raise UnknownMessageType(f"{type_name}: {package} has no message {name!r}")
    return cls


@cache
def message_definition(type_name: str) -> str:
    """The text of one installed ``.msg`` file."""
    package, name = _split(type_name)
    # The pip-installed venv sets no AMENT_PREFIX_PATH; its own prefix holds share/<pkg>/msg.
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    for prefix in [*prefixes, sys.prefix]:
        path = Path(prefix) / "share" / package / "msg" / f"{name}.msg"
        if path.is_file():
            return path.read_text()
    raise FileNotFoundError(f"no definition of {type_name} under {[*prefixes, sys.prefix]}")


def nested_types(definition: str, package: str) -> list[str]:
    """Types of the non-primitive fields, spelled as 'pkg/Type', in order of first use."""
    found: list[str] = []
    for raw in definition.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line or "=" in line.split()[1 if len(line.split()) > 1 else 0]:
            continue  # blank, comment or constant ("uint8 STAY=0")
        field_type = _ARRAY_OR_BOUND.sub("", line.split()[0])
        if field_type in PRIMITIVES:
            continue
        full = field_type if "/" in field_type else f"{package}/{field_type}"
        if full not in found:
            found.append(full)
    return found


@cache
def ros2msg_schema(type_name: str) -> str:
    """The full ``ros2msg`` schema of a message type: root definition, then every nested one."""
    package, _ = _split(type_name)
    root = message_definition(type_name)
    parts = [root.rstrip("\n")]
    seen: set[str] = set()
    queue = nested_types(root, package)
    while queue:
        nested = queue.pop(0)
        if nested in seen:
            continue
        seen.add(nested)
        text = message_definition(nested)
        parts.append(f"{SEPARATOR}\nMSG: {nested}\n{text.rstrip(chr(10))}")
        queue.extend(nested_types(text, _split(nested)[0]))
    return "\n".join(parts) + "\n"
