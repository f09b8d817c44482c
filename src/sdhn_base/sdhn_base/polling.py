"""Waiting on another process by polling a condition: what a benchmark or a fault test does while
a launched graph starts, restarts or settles."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def wait_until(cond: Callable[[], Any], timeout: float, poll: float = 0.05) -> bool:
    """True as soon as ``cond()`` is truthy, polled every ``poll`` seconds; after ``timeout``
    seconds, whether it is at a last look."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(poll)
    return bool(cond())
