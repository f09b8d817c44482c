"""What every sdhn node reports on ``/diagnostics``, without ROS: rolling percentiles, counters
per window, thresholds -> level, key/values (docs/lifecycle-and-diagnostics.md).

A node builds one :class:`Report` per second from its own numbers; the thin publisher in
:mod:`sdhn_base.ros.diagnostics` turns it into a ``diagnostic_msgs/DiagnosticStatus``. The levels
have the values of ``DiagnosticStatus.OK/WARN/ERROR``; every threshold is defined here, once
(:data:`THRESHOLDS`), and the docs page's table lists the same numbers (a test compares them).

    latency = RollingPercentiles(1000)
    latency.add(0.8)                                   # ms, on the hot path: one array store
    window = WindowCounts()
    values = {"decision_latency_p99_ms": latency.percentile(99)}
    values |= drop_values(drops, window.new(drops))    # drops: the node's dict[str, int]
    report = make_report(name, team_ns, values, ["decision_latency_p99_ms", "dropped_in_window"])

Drop counts are taken as a plain ``dict[str, int]`` of cumulative counts per cause, whatever the
node names its causes: :class:`WindowCounts` turns them into "new in this window", which is what a
level is judged on (a drop an hour ago must not keep a node WARN forever).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

OK, WARN, ERROR = 0, 1, 2  # the byte values of diagnostic_msgs/DiagnosticStatus levels
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}
PERIOD_S = 1.0  # every node publishes one DiagnosticArray per PERIOD_S


@dataclass(frozen=True)
class Threshold:
    """A value at or above ``warn`` is WARN, at or above ``error`` ERROR (NaN: no data, OK)."""

    key: str
    warn: float
    error: float
    meaning: str  # one line for the docs table and the status message

    def level(self, value: float) -> int:
        if math.isnan(value):
            return OK
        if value >= self.error:
            return ERROR
        return WARN if value >= self.warn else OK


def _t(key: str, warn: float, error: float, meaning: str) -> tuple[str, Threshold]:
    return key, Threshold(key, warn, error, meaning)


# Why these numbers: the simulator's default step deadline is 1 s and a loaded 2-core machine
# answers in ~1 ms (docs/ros-performance.md), so 100 ms p99 is far outside normal and 500 ms is
# half the deadline (misses are near). One missed action in a window is already worth a WARN
# (a robot stood still for a step); half the robot-steps missed means the team is not acting.
THRESHOLDS: dict[str, Threshold] = dict((
    _t("decision_latency_p99_ms", 100.0, 500.0,
       "actor: p99 of observation received -> action sent, last 1000 decisions"),
    _t("dropped_in_window", 1, math.inf,
       "any node: messages dropped (any cause) in the last window"),
    _t("missed_actions_in_window", 1, math.inf,
       "simulator: robot-steps that took 'stay' because the action missed the deadline"),
    _t("missed_fraction_in_window", 0.5, 0.5,
       "simulator: missed robot-steps / all robot-steps in the last window"),
    _t("queue_depth", 2, 4,
       "trainer: rollouts waiting for the learner process (dropped beyond 4)"),
    _t("write_queue_depth", 20_000, 200_000,
       "recorder: messages received, not yet written to the MCAP file"),
    _t("not_written", 1, 1,
       "recorder: messages lost because writing the file failed"),
))


def judge(values: Mapping[str, float], keys: Iterable[str]) -> tuple[int, str]:
    """The worst level of ``values[k]`` over ``keys`` (each judged by its THRESHOLDS entry), and
    one line naming every key that is not OK ('' when all are)."""
    level, why = OK, []
    for key in keys:
        value = float(values.get(key, math.nan))
        lv = THRESHOLDS[key].level(value)
        if lv != OK:
            limit = THRESHOLDS[key].error if lv == ERROR else THRESHOLDS[key].warn
            why.append(f"{key}={_fmt(value)} (>= {_fmt(limit)})")
            level = max(level, lv)
    return level, "; ".join(why)


class RollingPercentiles:
    """The last ``size`` samples in a ring; percentiles computed on demand (once a second), so
    :meth:`add` costs one array store on the hot path."""

    def __init__(self, size: int = 1000) -> None:
        self._ring = np.empty(size, dtype=np.float64)
        self._next = 0
        self.count = 0  # samples ever added

    def add(self, value: float) -> None:
        self._ring[self._next] = value
        self._next = (self._next + 1) % self._ring.size
        self.count += 1

    def clear(self) -> None:
        self._next = self.count = 0

    def percentile(self, q: float) -> float:
        """The q-th percentile of the samples in the ring (NaN before the first)."""
        n = min(self.count, self._ring.size)
        return float(np.percentile(self._ring[:n], q)) if n else math.nan


@dataclass
class WindowCounts:
    """Cumulative counters per cause -> what is new since the previous call."""

    last: dict[str, int] = field(default_factory=dict)

    def new(self, counts: Mapping[str, int]) -> dict[str, int]:
        out = {k: int(v) - self.last.get(k, 0) for k, v in counts.items()}
        self.last = {k: int(v) for k, v in counts.items()}
        return {k: v for k, v in out.items() if v > 0}


def drop_values(total: Mapping[str, int], new: Mapping[str, int]) -> dict[str, float]:
    """Key/values of a node's drops: ``dropped/<cause>`` (since start) per cause, and
    ``dropped_in_window`` (the sum of the new ones), which is what the level is judged on."""
    out: dict[str, float] = {f"dropped/{k}": float(v) for k, v in sorted(total.items())}
    out["dropped_in_window"] = float(sum(new.values()))
    return out


@dataclass(frozen=True)
class Report:
    """One node's status for one period (a ``diagnostic_msgs/DiagnosticStatus``)."""

    name: str  # the node's fully qualified name, e.g. /sdhn/robot_3/actor
    hardware_id: str  # the team namespace
    level: int
    message: str
    values: Mapping[str, float | int | str]

    def key_values(self) -> list[tuple[str, str]]:
        return [(k, _fmt(v)) for k, v in self.values.items()]


def make_report(name: str, hardware_id: str, values: Mapping[str, float | int | str],
                judged: Iterable[str], note: str = "", *, floor: int = OK) -> Report:
    """A report judged on ``judged`` keys; ``note`` leads the message, ``floor`` is the least
    level (e.g. WARN for a node that cannot act yet, whatever its numbers)."""
    numeric = {k: float(v) for k, v in values.items() if isinstance(v, int | float)}
    level, why = judge(numeric, judged)
    level = max(level, floor)
    message = "; ".join(part for part in (note, why) if part) or "ok"
    return Report(name, hardware_id, level, message, dict(values))


def _fmt(value: float | int | str) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, int) or (isinstance(value, float) and value.is_integer()):
        return str(int(value))
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return f"{value:.3f}"
