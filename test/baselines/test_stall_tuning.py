"""Choosing a stall rule on the validation set: scores paired with greedy play and the choice
among rules, on synthetic records with known answers."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sdhn_experiments import stall_rule_cli
from sdhn_experiments.heldout_eval import InstanceResult
from sdhn_experiments.stall_tuning import RuleScore, choose, pool, ranked, rule_grid, score
from sdhn_policy.stall_breaker import StallRule

ROOT = Path(__file__).resolve().parents[2]


def _recs(makespans: list[int | None], deadlocks: int = 0) -> list[InstanceResult]:
    return [InstanceResult(instance=i, map=i // 2, success=m is not None, makespan=m,
                           length=m or 500, wedged=int(m is None and i < deadlocks),
                           deadlock=m is None and i < deadlocks)
            for i, m in enumerate(makespans)]


def test_score_pairs_makespans_with_greedy_only_where_both_complete() -> None:
    greedy = _recs([10, 20, None, 40])
    rule = _recs([15, 20, 90, None], deadlocks=4)
    s = score(StallRule(), rule, greedy)
    assert s.success_rate == 0.75
    assert s.paired_instances == 2  # instance 2 (greedy failed) and 3 (rule failed) left out
    assert s.slowdown == pytest.approx((1.5 + 1.0) / 2)
    assert s.deadlocks == 1


def test_score_refuses_records_of_other_instances() -> None:
    with pytest.raises(ValueError, match="different instances"):
        score(StallRule(), _recs([10, 20]), _recs([10, 20, 30]))


def _scored(success: float, slowdown: float | None, calm: int) -> RuleScore:
    n = 1000
    wins = round(success * n)
    greedy = _recs([100] * n)
    rule = _recs([round(100 * (slowdown or 1))] * wins + [None] * (n - wins))
    return score(StallRule(calm, 5, 3), rule, greedy)


def test_choose_takes_the_fastest_rule_near_the_best_success() -> None:
    a = _scored(0.990, 1.20, calm=2)   # the most successful, but slow
    b = _scored(0.986, 1.05, calm=3)   # within 0.005 of it, and faster: chosen
    c = _scored(0.950, 1.00, calm=5)   # fastest, but too far below
    assert choose([a, b, c]).rule.calm_steps == 3
    assert [s.rule.calm_steps for s in ranked([a, b, c])] == [3, 2, 5]
    assert choose([a, b, c], tolerance=0.0).rule.calm_steps == 2


def test_choose_breaks_ties_by_grid_order_and_refuses_nothing_to_choose() -> None:
    a, b = _scored(0.99, 1.1, calm=2), _scored(0.99, 1.1, calm=3)
    assert choose([a, b]).rule.calm_steps == 2
    assert choose([b, a]).rule.calm_steps == 3
    with pytest.raises(ValueError, match="no rules"):
        choose([])
    with pytest.raises(ValueError, match="tolerance"):
        choose([a], tolerance=-1)


def test_rule_grid_is_every_valid_combination_smallest_first() -> None:
    grid = rule_grid(calm=[3, 2], progress=[5], sample=[1, 3], temperatures=[0.5, 1.0])
    assert [r.text() for r in grid] == ["2,5,1", "2,5,3", "3,5,1", "3,5,3",
                                        "2,5,1,0.5", "2,5,3,0.5", "3,5,1,0.5", "3,5,3,0.5"]
    with pytest.raises(ValueError, match="calm_steps"):
        rule_grid(calm=[0])


def test_script_chooses_on_validation_and_reports_on_heldout(tmp_path: Path) -> None:
    """sdhn_experiments.stall_rule_cli (scripts/tune_stall_rule.py) on the lone maif-solo robot
    (seconds): every grid rule is scored on the validation set, the choice is one of them, and
    the held-out report has greedy play, the default rule and the choice, with intervals and
    paired makespans."""
    tune = stall_rule_cli
    out, md = tmp_path / "stall.json", tmp_path / "stall.md"
    argv = [str(ROOT / "models" / "maif-solo-mappo"), "--calm", "3", "--progress", "5", "8",
            "--sample", "3", "--refine-top", "0", "--planner-cache", str(tmp_path / "plan"),
            "--out", str(out), "--markdown", str(md)]
    assert tune.main(argv) == 0
    (res,) = json.loads(out.read_text())
    v = res["validation"]
    assert v["set"] == "validation" and {s["rule"] for s in v["scores"]} == {"3,5,3", "3,8,3"}
    assert v["chosen"] == v["scores"][0]["rule"]
    modes = res["heldout_large"]["modes"]
    assert modes[0]["mode"] == "greedy" and all(m["set"] == "heldout_large" for m in modes)
    assert len(modes) == (2 if v["chosen"] == StallRule().text() else 3)
    for m in modes:
        lo, hi = m["summary"]["success_ci95_maps"]
        assert lo <= m["summary"]["success_rate"] <= hi and m["makespan_ratio_paired"] >= 1.0
    assert f"chosen: **{v['chosen']}**" in md.read_text()
    # the tables again from the JSON, evaluating nothing; two policies get a pooled choice
    out.write_text(json.dumps([res, {**res, "model": "again"}]))
    assert tune.main(["--from-json", str(out), "--markdown", str(md)]) == 0
    assert "One rule for all: maif-solo-mappo, again" in md.read_text()


def test_script_refuses_a_bad_grid_before_evaluating(capsys: pytest.CaptureFixture[str]) -> None:
    tune = stall_rule_cli
    assert tune.main([str(ROOT / "models" / "maif-solo-mappo"), "--sample", "0"]) == 2
    assert "sample_steps" in capsys.readouterr().err
    assert tune.main([str(ROOT / "models" / "rware-3-mappo")]) == 2
    assert "not a MAIF task" in capsys.readouterr().err
    assert tune.main([]) == 2 and "at least one model" in capsys.readouterr().err


def test_pool_averages_the_rules_every_policy_scored() -> None:
    a = [_scored(0.99, 1.10, calm=2), _scored(0.95, 1.00, calm=3), _scored(0.97, 1.0, calm=5)]
    b = [_scored(0.91, 1.30, calm=3), _scored(0.97, 1.20, calm=2)]  # no calm=5 rule
    pooled = pool([a, b])
    assert [s.rule.calm_steps for s in pooled] == [2, 3]  # a's order, only the common rules
    two, three = pooled
    assert two.success_rate == pytest.approx(0.98) and two.slowdown == pytest.approx(1.15)
    assert three.success_rate == pytest.approx(0.93) and three.slowdown == pytest.approx(1.15)
    assert two.paired_instances == 990 + 970
    assert choose(pooled).rule.calm_steps == 2
    assert pool([]) == []
