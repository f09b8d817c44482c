"""The ROS-free diagnostics core: rolling percentiles, counters per window, thresholds -> level,
and the docs page's threshold table agreeing with the one definition in code."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sdhn_base.diagnostics import (
    ERROR,
    OK,
    THRESHOLDS,
    WARN,
    RollingPercentiles,
    WindowCounts,
    drop_values,
    judge,
    make_report,
)

DOCS = Path(__file__).resolve().parents[1] / "docs" / "lifecycle-and-diagnostics.md"


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 1e4, allow_nan=False), min_size=1, max_size=300),
       st.integers(1, 100))
def test_percentiles_are_those_of_the_last_samples(values: list[float], size: int) -> None:
    r = RollingPercentiles(size)
    for v in values:
        r.add(v)
    last = np.asarray(values[-size:])
    for q in (50, 99):
        assert r.percentile(q) == np.percentile(last, q)
    assert r.count == len(values)


def test_percentiles_without_samples_are_nan_and_judged_ok() -> None:
    r = RollingPercentiles(10)
    assert math.isnan(r.percentile(99))
    assert judge({"decision_latency_p99_ms": r.percentile(99)},
                 ["decision_latency_p99_ms"]) == (OK, "")


def test_window_counts_report_only_what_is_new() -> None:
    w = WindowCounts()
    assert w.new({"stale_step": 2}) == {"stale_step": 2}
    assert w.new({"stale_step": 2}) == {}
    assert w.new({"stale_step": 3, "undecodable": 1}) == {"stale_step": 1, "undecodable": 1}
    values = drop_values({"stale_step": 3, "undecodable": 1}, {"undecodable": 1})
    assert values == {"dropped/stale_step": 3.0, "dropped/undecodable": 1.0,
                      "dropped_in_window": 1.0}


def test_levels_follow_the_thresholds_and_the_message_names_the_key() -> None:
    t = THRESHOLDS["decision_latency_p99_ms"]
    below, warn, error = t.warn / 2, t.warn, t.error
    for value, want in ((below, OK), (warn, WARN), (error, ERROR)):
        report = make_report("/sdhn/robot_0/actor", "/sdhn",
                             {"decision_latency_p99_ms": value, "lifecycle_state": "active"},
                             ["decision_latency_p99_ms"])
        assert report.level == want, (value, report)
        assert ("decision_latency_p99_ms" in report.message) == (want != OK), report.message
    # the floor: a node that cannot act is at least WARN, whatever its numbers
    waiting = make_report("/a", "/sdhn", {"decisions": 0}, [], "waiting for weights", floor=WARN)
    assert waiting.level == WARN and waiting.message == "waiting for weights"
    keys = dict(waiting.key_values())
    assert keys == {"decisions": "0"}


def test_docs_table_lists_every_threshold_with_the_code_values() -> None:
    """The thresholds are defined once, in code; the docs table must say the same numbers."""
    rows = {}
    for line in DOCS.read_text().splitlines():
        m = re.match(r"\|\s*`([a-z_0-9]+)`\s*\|\s*([^|]+)\|\s*([^|]+)\|", line)
        if m and m.group(1) in THRESHOLDS:
            rows[m.group(1)] = (m.group(2).strip(), m.group(3).strip())
    assert set(rows) == set(THRESHOLDS), set(THRESHOLDS) ^ set(rows)
    for key, (warn, error) in rows.items():
        t = THRESHOLDS[key]
        assert float(warn.lstrip(">= ")) == t.warn, (key, warn, t)
        assert (error == "never") if math.isinf(t.error) else float(error.lstrip(">= ")) == t.error
