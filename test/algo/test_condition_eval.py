"""Evaluation under deployment conditions (sdhn_experiments.condition_eval): the ideal world
reproduces the held-out evaluation, and dead reckoning is measured against plain play."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from sdhn_experiments import condition_eval_cli, condition_figures
from sdhn_experiments.condition_eval import Mode, card_mode, evaluate_under, summarise_under
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_eval import instance_env, run_actor
from sdhn_policy.stall_breaker import StallRule
from sdhn_sim.envs.conditions import Conditions

ACTOR = "models/maif-tiny-sdhn/actor.safetensors"


def test_the_ideal_world_reproduces_the_deployed_evaluation() -> None:
    rt = ActorRuntime.from_file(ACTOR)
    got = evaluate_under(rt, "maif-tiny", Conditions(), Mode(), which="heldout", instances=20)
    want = run_actor(rt, instance_env("maif-tiny", "heldout", 20, 0, "corrected"), 0)
    assert [(r.success, r.makespan) for r in got] == [(e.completed, e.makespan) for e in want]
    s = summarise_under(got, got, num_formations=10)
    assert s["makespan_over_ideal"] == 1.0 and s["success_rate"] == s["team_success_rate"]


def test_survivors_success_is_reported_beside_the_team_success_under_failure() -> None:
    rt = ActorRuntime.from_file(ACTOR)
    recs = evaluate_under(rt, "maif-tiny", Conditions(failures=1, failure_horizon=5),
                          Mode(stall=StallRule()), instances=20, which="heldout")
    s = summarise_under(recs, None, num_formations=10)
    assert all(r.failed == 1 for r in recs if not r.team_success)
    assert s["success_rate"] > s["team_success_rate"]


def test_card_mode_reads_the_deployment_mode() -> None:
    m = card_mode("models/maif-10-sdhn")
    assert m.greedy and m.stall == StallRule.parse("2,10,2")
    # the shipped cards deploy dead reckoning (it changes nothing on current observations)
    assert card_mode("models/maif-20-sdhn") == Mode(greedy=False, temperature=0.25,
                                                    dead_reckon=True)
    with pytest.raises(ValueError, match="stall breaking"):
        Mode(greedy=False, stall=StallRule()).check()


def test_dead_reckoning_holds_up_under_two_steps_of_latency() -> None:
    rt = ActorRuntime.from_file(ACTOR)
    mode = Mode(stall=StallRule())
    late = Conditions(latency=2)
    kw = {"instances": 30, "which": "heldout", "max_steps": 150}
    ideal = evaluate_under(rt, "maif-tiny", Conditions(), mode, **kw)
    plain = summarise_under(evaluate_under(rt, "maif-tiny", late, mode, **kw), ideal, 10)
    reck = summarise_under(evaluate_under(rt, "maif-tiny", late,
                                          dataclasses.replace(mode, dead_reckon=True), **kw),
                           ideal, 10)
    assert reck["success_rate"] >= plain["success_rate"]
    assert reck["makespan_over_ideal"] < 0.5 * plain["makespan_over_ideal"]


def test_the_scripts_sweep_a_condition_and_draw_the_figure(tmp_path: Path) -> None:
    out = tmp_path / "cond.json"
    ev = condition_eval_cli
    assert ev.main(["models/maif-tiny-sdhn", "--instances", "10", "--set", "heldout",
                    "--conditions", "failures", "--severities", "1", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["condition"], r["severity"]) for r in rows] == [("ideal", "-"), ("failures", "1")]
    assert len(rows[1]["records"]) == 10
    fig, md = tmp_path / "fig.png", tmp_path / "table.md"
    assert condition_figures.main(
        [str(out), "--figure", str(fig), "--markdown", str(md)]) == 0
    assert fig.stat().st_size > 1000 and md.read_text().count("| maif-tiny-sdhn |") == 2
    assert ev.main(["models/maif-tiny-sdhn", "--block", "{latency: -1}"]) == 2
