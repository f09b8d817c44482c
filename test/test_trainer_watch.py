"""The launcher's watch for a deaf trainer (sdhn_bringup.trainer_watch): silence counts only while
the same trainer process's counters stand still and the simulator plays on."""

from __future__ import annotations

import pytest

from sdhn_base.ros.qos import STEP_DEPTH
from sdhn_bringup.trainer_watch import MIN_STEPS, TrainerWatch


def test_min_steps_is_twice_the_settle_window() -> None:
    assert MIN_STEPS == 2 * STEP_DEPTH


def test_standing_counters_while_the_simulator_plays_are_deaf() -> None:
    w = TrainerWatch(timeout=10.0, min_steps=100)
    assert w.observe(0.0, 7, "c0", 0) is None
    assert w.observe(9.9, 7, "c0", 500) is None  # not yet the timeout
    assert w.observe(10.0, 7, "c0", 500) == pytest.approx(10.0)
    assert w.steps_since(500) == 500


@pytest.mark.parametrize("what", ["counters move", "new process", "no status",
                                  "simulator idle", "watch off"])
def test_what_is_not_deaf(what: str) -> None:
    w = TrainerWatch(timeout=0.0 if what == "watch off" else 10.0, min_steps=100)
    w.observe(0.0, 7, "c0", 0)
    seen = []
    for t in range(1, 40):
        pid = 8 if what == "new process" and t >= 20 else 7
        counters = (None if what == "no status" else f"c{t}" if what == "counters move"
                    else "c0")
        steps = 50 if what == "simulator idle" else 100 * t
        seen.append(w.observe(float(t), pid, counters, steps))
    if what == "new process":  # the clock starts again at the new pid
        assert all(s is None for s in seen[:9]) and seen[9] is not None
        assert seen[19] is None and all(s is None for s in seen[20:29])
        assert seen[29] == pytest.approx(10.0)
    else:
        assert all(s is None for s in seen), seen


@pytest.mark.parametrize("bad", [-1.0, float("nan")])
def test_a_bad_timeout_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="deaf_trainer_s"):
        TrainerWatch(timeout=bad)
