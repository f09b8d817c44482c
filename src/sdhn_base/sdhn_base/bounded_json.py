"""JSON from untrusted bytes (a message payload, a file someone handed us), parsed with bounds.

The standard parser accepts what a crafted input uses to take a process down: nesting deep
enough to exhaust the recursion limit (``RecursionError``, which no ``except ValueError`` catches),
``NaN`` / ``Infinity`` literals and overflowing numbers (``1e999`` is ``inf``; ``int(inf)`` raises
``OverflowError``), and integers of thousands of digits. :func:`loads` refuses all of them with
:class:`JsonInputError` (a ``ValueError``), so a caller handles every bad input in one place:

    try:
        header = bounded_json.loads(payload[8:8 + n])
    except bounded_json.JsonInputError as e:
        drop("bad_header", str(e))
"""

from __future__ import annotations

import json
import math
from typing import Any

MAX_DEPTH = 32
"""Deepest nesting of arrays/objects accepted (our headers and sidecars use 3)."""
MAX_INT_DIGITS = 19
"""Longest integer literal accepted by default (an int64 has 19 digits)."""
STATE_FILE_INT_DIGITS = 200
"""For our own state files (checkpoints hold 128-bit RNG states, 39 digits)."""


class JsonInputError(ValueError):
    """The bytes are not JSON within the bounds; the message says which bound."""


def _reject_constant(name: str) -> Any:
    raise JsonInputError(f"non-finite number {name} (only finite numbers are allowed)")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise JsonInputError(f"number {text[:40]} overflows a float (only finite numbers are "
                             "allowed)")
    return value


def _int_parser(max_digits: int) -> Any:
    def parse(text: str) -> int:
        if len(text.lstrip("-")) > max_digits:
            raise JsonInputError(f"integer of {len(text)} digits (at most {max_digits} allowed)")
        return int(text)

    return parse


def depth(value: Any) -> int:
    """Nesting depth of parsed JSON (a scalar is 0, ``[]`` is 1), without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        item, d = stack.pop()
        if isinstance(item, dict):
            item = list(item.values())
        if isinstance(item, list):
            deepest = max(deepest, d + 1)
            stack.extend((child, d + 1) for child in item)
    return deepest


def loads(data: bytes | str, max_depth: int = MAX_DEPTH, finite: bool = True,
          max_int_digits: int = MAX_INT_DIGITS) -> Any:
    """Parse ``data`` as JSON; :class:`JsonInputError` when it is not valid UTF-8 JSON, nests
    deeper than ``max_depth``, holds an integer longer than ``max_int_digits`` or
    (``finite``, the default) a non-finite number. Our own state files relax the last two
    (``finite=False``: a NaN metric; ``max_int_digits``: a 128-bit RNG state)."""
    strict: dict[str, Any] = {"parse_constant": _reject_constant, "parse_float": _finite_float}
    try:
        value = json.loads(data, parse_int=_int_parser(max_int_digits),
                           **(strict if finite else {}))
    except JsonInputError:
        raise
    except RecursionError:
        raise JsonInputError(f"nested deeper than {max_depth} levels") from None
    except (ValueError, UnicodeDecodeError, TypeError) as e:  # JSONDecodeError is a ValueError
        raise JsonInputError(f"not JSON: {e}") from None
    if depth(value) > max_depth:
        raise JsonInputError(f"nested deeper than {max_depth} levels")
    return value
