"""The pilot's comparison (sdhn_experiments.conditions_pilot): paired makespan ratios over the
policy's own and over the baseline's ideal, arms pooled over seeds, the paired difference."""

from __future__ import annotations

import pytest

from sdhn_experiments.condition_eval import ConditionResult
from sdhn_experiments.conditions_pilot import compare_arms, markdown, ratios
from sdhn_sim.envs.conditions import Conditions

PLAN = (("ideal", Conditions(), False), ("late", Conditions(latency=1), False))


def _recs(makespans: list[int | None]) -> list[ConditionResult]:
    return [ConditionResult(instance=i, map=i // 2, success=m is not None, makespan=m,
                            team_success=m is not None, failed=0, length=m or 500)
            for i, m in enumerate(makespans)]


def test_ratios_pair_instances_and_skip_the_ones_either_fails() -> None:
    assert ratios(_recs([20, None, 30]), _recs([10, 10, None])) == [2.0, None, None]


def test_arms_pool_their_seeds_and_the_difference_is_paired() -> None:
    rows = {
        "base": {"ideal": _recs([10, 10, 10, 10]), "late": _recs([20, 20, 20, None])},
        "c1": {"ideal": _recs([10, 10, 10, 10]), "late": _recs([15, 15, 15, 15])},
        "c2": {"ideal": _recs([10, 10, 10, 10]), "late": _recs([17, 13, 15, 15])},
        "r1": {"ideal": _recs([20, 20, 20, 20]), "late": _recs([24, 24, 24, 24])},
    }
    t = compare_arms(rows, {"control": ["c1", "c2"], "randomised": ["r1"]}, "base", PLAN)
    late = t["late"]
    assert late["base"]["success_rate"] == 0.75
    assert late["base"]["makespan_over_own_ideal"] == pytest.approx(2.0)
    assert late["control"]["makespan_over_own_ideal"] == pytest.approx(1.5)
    assert late["control"]["makespan_over_own_ideal_per_seed"] == pytest.approx([1.5, 1.5])
    assert late["control"]["makespan_over_own_ideal_pairs"] == 8
    # r1: 1.2x its own (slower) ideal, but 2.4x the baseline's ideal
    assert late["randomised"]["makespan_over_own_ideal"] == pytest.approx(1.2)
    assert late["randomised"]["makespan_over_baseline_ideal"] == pytest.approx(2.4)
    diff = late["difference"]["randomised - control"]
    assert diff["own"]["mean"] == pytest.approx(-0.3)
    assert diff["baseline"]["mean"] == pytest.approx(0.9)
    lo, hi = diff["own"]["ci95"]
    assert lo <= -0.3 <= hi
    assert t["ideal"]["randomised"]["makespan_over_baseline_ideal"] == pytest.approx(2.0)
    text = markdown(t, ["control", "randomised"], "base")
    assert "| late | 0.75 / 2.00×" in text and text.count("\n") == 4
