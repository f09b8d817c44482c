"""Messages as ``ros2 topic echo`` prints them: YAML of the fields in declaration order.

What rosidl_runtime_py's ``message_to_yaml`` does (no wheel of it exists for Jazzy): arrays and
strings longer than ``truncate_length`` are cut and end with ``'...'``; ``no_arr`` prints
``'<array type: float[57]>'`` instead of an array's values, ``no_str`` ``'<string length: <N>>'``
instead of a string. Works on any generated message class (``get_fields_and_field_types``), so any
type the install has.
"""

from __future__ import annotations

import array
import sys
from typing import Any

import numpy as np
import yaml

DEFAULT_TRUNCATE = 128  # ros2 topic echo's --truncate-length default


def _is_message(value: Any) -> bool:
    return hasattr(value, "get_fields_and_field_types")


def _sequence(value: Any, field_type: str, truncate: int | None, no_arr: bool) -> Any:
    items = list(value.tolist() if isinstance(value, np.ndarray | array.array) else value)
    if no_arr:
        base = field_type.split("<", 1)[-1].rstrip(">").split(",")[0]
        return f"<array type: {base}[{len(items)}]>"
    cut = truncate is not None and len(items) > truncate
    out = [convert(v, "", truncate, no_arr, False) for v in items[: truncate if cut else None]]
    return [*out, "..."] if cut else out


def convert(value: Any, field_type: str = "", truncate: int | None = DEFAULT_TRUNCATE,
            no_arr: bool = False, no_str: bool = False) -> Any:
    """One field's value as plain YAML-able Python (nested messages as dicts)."""
    if _is_message(value):
        return to_dict(value, truncate, no_arr, no_str)
    if isinstance(value, bytes | bytearray):
        value = list(value)
    if isinstance(value, list | tuple | np.ndarray | array.array):
        return _sequence(value, field_type, truncate, no_arr)
    if isinstance(value, str):
        if no_str:
            return f"<string length: <{len(value)}>>"
        if truncate is not None and len(value) > truncate:
            return value[:truncate] + "..."
        return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def to_dict(msg: Any, truncate: int | None = DEFAULT_TRUNCATE, no_arr: bool = False,
            no_str: bool = False) -> dict[str, Any]:
    """A message's fields in declaration order, converted recursively."""
    return {name: convert(getattr(msg, name), field_type, truncate, no_arr, no_str)
            for name, field_type in msg.get_fields_and_field_types().items()}


def to_yaml(msg: Any, truncate: int | None = DEFAULT_TRUNCATE, no_arr: bool = False,
            no_str: bool = False) -> str:
    """The YAML document ``ros2 topic echo`` prints for one message (without the ``---``)."""
    return yaml.dump(to_dict(msg, truncate, no_arr, no_str), allow_unicode=True,
                     width=sys.maxsize, sort_keys=False, default_flow_style=False)


def field_value(msg: Any, path: str) -> Any:
    """``--field a.b``: the value of one (nested) field; ValueError naming a missing part."""
    value = msg
    for part in path.split("."):
        if not _is_message(value) or part not in value.get_fields_and_field_types():
            raise ValueError(f"--field {path}: no field {part!r}")
        value = getattr(value, part)
    return value
