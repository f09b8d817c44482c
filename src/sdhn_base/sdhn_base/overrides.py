"""The one ``--set``-style override engine: typed coercion and dotted assignment on dataclasses.

    set_field(cfg, "ppo.lr", "3e-4")          # cfg.ppo.lr = 3e-4 (float)
    set_field(cfg, "restart", {"policy": "on-failure"})   # a section from a mapping
    coerce("seed", int, "7")                   # 7

Used by the trainer's config (``sdhn_train.config``) and the launcher
(``sdhn_bringup.launch_load``), so both accept the same spellings. Stdlib only. Every refusal
is an :class:`OverrideError` (a ``ValueError``) whose one-line message
names the field and what is allowed:

- bool: a bool, or one of true/false, 1/0, yes/no, on/off (any case);
- int: an int or an integral value (``"4"``, ``4.0``, ``"1e3"``); never ``2.7``, inf or NaN;
- float: anything ``float()`` reads (a bool is refused);
- str: the value as text (``None`` -> ``""``);
- ``X | None``: ``None``/``"null"``/``"none"`` -> None, else X;
- ``list[X]``: a list, ``"[a, b]"`` or ``"a,b"``, each element as X.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

TRUE = ("true", "1", "yes", "on")
FALSE = ("false", "0", "no", "off")


class OverrideError(ValueError):
    """A value or field path that cannot be applied; the message names the field."""


def _type_name(tp: Any) -> str:
    return str(getattr(tp, "__name__", tp))


def _as_int(path: str, value: Any) -> int:
    if isinstance(value, bool):
        raise OverrideError(f"{path}: expected int, got {value!r}; allowed: an integer")
    if isinstance(value, int):
        return value
    number: float
    if isinstance(value, float):
        number = value
    elif isinstance(value, str):
        text = value.strip()
        try:
            return int(text)
        except ValueError:
            pass
        try:
            number = float(text)
        except ValueError:
            raise OverrideError(f"{path}: expected int, got {value!r}; allowed: an integer"
                                ) from None
    else:
        raise OverrideError(f"{path}: expected int, got {value!r}; allowed: an integer")
    if not math.isfinite(number) or not number.is_integer():
        raise OverrideError(f"{path}: expected int, got {value!r}; allowed: an integer "
                            "(no fraction, inf or nan)")
    return int(number)


def _as_list(path: str, value: Any) -> list[Any]:
    if isinstance(value, list | tuple):
        return list(value)
    if isinstance(value, str):
        text = value.strip()
        if text.startswith("[") and text.endswith("]"):
            text = text[1:-1]
        return [part.strip() for part in text.split(",") if part.strip()]
    raise OverrideError(f"{path}: expected a list, got {value!r}; allowed: [a, b, ...]")


def coerce(path: str, tp: Any, value: Any) -> Any:
    """``value`` (a YAML scalar or a command-line string) as the annotated type ``tp``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and (
                value is None or (isinstance(value, str) and value.strip().lower()
                                  in ("null", "none"))):
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) != 1:
            raise OverrideError(f"{path}: unsupported type {tp}")
        return coerce(path, inner[0], value)
    if origin is list:
        return [coerce(path, args[0] if args else str, v) for v in _as_list(path, value)]
    if tp is bool:
        if isinstance(value, bool):
            return value
        text = str(value).strip().lower() if isinstance(value, str | int) else None
        if text in TRUE or text in FALSE:
            return text in TRUE
        raise OverrideError(f"{path}: expected true or false, got {value!r}; allowed: "
                            f"{'/'.join(TRUE)} or {'/'.join(FALSE)}")
    if tp is int:
        return _as_int(path, value)
    if tp is float:
        if not isinstance(value, bool):
            try:
                return float(value)
            except (TypeError, ValueError):
                pass
        raise OverrideError(f"{path}: expected float, got {value!r}; allowed: a number")
    if tp is str:
        return "" if value is None else str(value)
    raise OverrideError(f"{path}: unsupported type {_type_name(tp)}")


def set_field(obj: Any, dotted: str, value: Any, prefix: str = "") -> None:
    """Set ``a.b.c`` on nested dataclasses with coercion; a mapping sets a whole section.

    ``prefix`` is prepended to field paths in messages (``obj`` is itself a section)."""
    if not dataclasses.is_dataclass(obj):
        raise OverrideError(f"{prefix.rstrip('.') or 'object'}: is not a section")
    head, _, rest = dotted.partition(".")
    hints = typing.get_type_hints(type(obj))
    names = [f.name for f in dataclasses.fields(obj)]
    full = f"{prefix}{head}"
    if head not in names:
        owner = prefix.rstrip(".") or "the configuration"
        raise OverrideError(f"{full}: unknown field; allowed: the fields {owner} has: "
                            f"{', '.join(names)}")
    sub = getattr(obj, head)
    if dataclasses.is_dataclass(sub):
        if rest:
            set_field(sub, rest, value, f"{full}.")
        elif isinstance(value, dict):
            for k, v in value.items():
                set_field(sub, str(k), v, f"{full}.")
        else:
            raise OverrideError(f"{full}: expected a mapping of fields, got {value!r}; allowed: "
                                f"{', '.join(f.name for f in dataclasses.fields(sub))}")
    elif rest:
        raise OverrideError(f"{full}: is not a section; allowed: {full}=VALUE")
    else:
        setattr(obj, head, coerce(full, hints[head], value))
