"""Evaluation under deployment conditions (sdhn_experiments.condition_eval): the ideal world
reproduces the held-out evaluation, and dead reckoning is measured against plain play."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sdhn_experiments import condition_eval_cli, condition_figures
from sdhn_experiments.condition_eval import (
    ConditionResult,
    Mode,
    PlannerError,
    card_mode,
    evaluate_planner_under,
    evaluate_under,
    mean_ci,
    relaxed_bound_under,
    summarise_under,
)
from sdhn_experiments.heldout_eval import planner_makespans
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.deploy_eval import instance_env, run_actor
from sdhn_policy.stall_breaker import StallRule
from sdhn_sim.envs import make_env
from sdhn_sim.envs.conditions import Conditions
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_scripted import lower_bound

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


def test_the_final_approach_in_the_ideal_world_is_the_evaluation_s() -> None:
    """Mode(approach=True) plays as evaluate_set(approach=True) does, instance by instance; a
    card that deploys it is read so; the rule needs stall breaking."""
    from sdhn_experiments.heldout_eval import evaluate_set

    rt = ActorRuntime.from_file(ACTOR)
    rule = StallRule.parse("2,10,2")
    got = evaluate_under(rt, "maif-tiny", Conditions(), Mode(stall=rule, approach=True),
                         which="heldout", max_steps=60)
    want = evaluate_set(rt, "maif-tiny", "heldout", stall=rule, approach=True, max_steps=60)
    assert [(r.success, r.makespan) for r in got] == [(r.success, r.makespan) for r in want]
    plain = evaluate_under(rt, "maif-tiny", Conditions(), Mode(stall=rule), which="heldout",
                           max_steps=60)
    assert [r.makespan for r in plain] != [r.makespan for r in got], "the rule changed nothing"
    assert Mode(stall=rule, approach=True).label() == \
        "greedy, stall breaking 2,10,2, final approach"
    with pytest.raises(ValueError, match="requires stall breaking"):
        Mode(approach=True).check()


def test_card_mode_reads_the_final_approach(tmp_path: Path) -> None:
    import json
    import shutil

    model = tmp_path / "m"
    shutil.copytree("models/maif-10-sdhn", model)
    card = json.loads((model / "card.json").read_text())
    card["heldout_large"]["deploy"]["final_approach"] = True
    (model / "card.json").write_text(json.dumps(card))
    m = card_mode(model)
    assert m.approach and m.stall == StallRule.parse("2,10,2")
    assert not card_mode("models/maif-10-sdhn").approach


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


# The centralised planner under the same conditions: the best-case reference of a goal.

def _makespans(recs: list[ConditionResult]) -> list[int | None]:
    return [r.makespan for r in recs]


def test_the_planner_at_severity_zero_is_its_ideal_run() -> None:
    kw = {"instances": 10, "which": "heldout"}
    want = planner_makespans("maif-tiny", "heldout", None, instances=10)
    assert _makespans(evaluate_planner_under("maif-tiny", Conditions(), **kw)) == want
    for zero in (Conditions(lost_actions=0.0), Conditions(slow_fraction=0.5, slow_rate=1.0)):
        assert _makespans(evaluate_planner_under("maif-tiny", zero, **kw)) == want
    # knowing its own moves, a planner one step behind follows its plan to the step
    late = evaluate_planner_under("maif-tiny", Conditions(latency=1), dead_reckon=True, **kw)
    assert _makespans(late) == want


@pytest.mark.parametrize("p", [0.05, 0.2])
def test_the_planner_losing_actions_is_never_faster_than_ideal(p: float) -> None:
    kw = {"instances": 20, "which": "heldout"}
    ideal = evaluate_planner_under("maif-tiny", Conditions(), **kw)
    lossy = Conditions(lost_actions=p)
    lost = evaluate_planner_under("maif-tiny", lossy, **kw)
    bound = relaxed_bound_under("maif-tiny", lossy, **kw)
    assert all(r.success for r in lost)
    pairs = [(r.makespan, i.makespan, b.makespan) for r, i, b in zip(lost, ideal, bound,
                                                                    strict=True)]
    assert all(m >= mi and m >= mb for m, mi, mb in pairs)  # type: ignore[operator]
    assert sum(m > mi for m, mi, _ in pairs) >= 5  # type: ignore[operator]
    assert summarise_under(lost, ideal, 10)["makespan_over_ideal"] > 1.0


def test_the_relaxed_bound_is_the_longest_shortest_path_in_the_ideal_world() -> None:
    env = make_env("maif-tiny", num_envs=10, seed=0, instance_order="round_robin",
                   instance_ids=list(range(10)), instance_set="heldout")
    assert isinstance(env, MaifEnv)
    env.reset(seed=0)
    got = relaxed_bound_under("maif-tiny", Conditions(), instances=10, which="heldout")
    assert np.mean(_makespans(got)) == lower_bound(env)
    slow = relaxed_bound_under("maif-tiny", Conditions(slow_fraction=0.5, slow_rate=0.5),
                               instances=10, which="heldout")
    assert all(s.makespan > g.makespan for s, g in zip(slow, got, strict=True))  # type: ignore
    with pytest.raises(PlannerError, match="relaxed bound"):
        relaxed_bound_under("maif-tiny", Conditions(latency=1), instances=2, which="heldout")


def test_the_cli_plays_the_planner_beside_the_relaxed_bound(tmp_path: Path) -> None:
    out = tmp_path / "planner.json"
    ev = condition_eval_cli
    assert ev.main(["--planner", "--task", "maif-tiny", "--instances", "10", "--set",
                    "heldout", "--conditions", "lost_actions", "latency", "--severities",
                    "1", "--dead-reckon", "both", "--out", str(out)]) == 2  # p = 1: invalid
    assert ev.main(["--planner", "--task", "maif-tiny", "--instances", "10", "--set",
                    "heldout", "--conditions", "slow_half", "--severities", "0.5",
                    "--out", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [(r["policy"], r["condition"]) for r in rows] == [
        ("planner", "ideal"), ("relaxed bound", "ideal"), ("planner", "slow_half"),
        ("relaxed bound", "slow_half")]
    assert rows[2]["summary"]["makespan_over_ideal"] > 1.5
    assert ev.main(["--planner", "--task", "maif-tiny", "--set", "heldout",
                    "--conditions", "position_noise"]) == 2
    assert ev.main(["--conditions", "latency"]) == 2  # neither a model nor --planner


def test_the_cli_plays_rware_with_and_without_dead_reckoning(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]
                                                             ) -> None:
    out = tmp_path / "rware.json"
    assert condition_eval_cli.main(
        ["scripted:rware-3", "--instances", "2", "--conditions", "latency", "--severities", "1",
         "--dead-reckon", "both", "--out", str(out)]) == 0
    rows = json.loads(out.read_text())
    got = {(r["condition"], r["dead_reckon"]): r["summary"] for r in rows}
    assert set(got) == {("ideal", False), ("latency", False), ("latency", True)}
    assert got[("latency", False)]["deliveries_mean"] == 0.0  # the cliff
    assert got[("latency", True)]["deliveries_mean"] > 5  # measured 17.2 over 20 episodes
    assert got[("latency", False)]["rates"]["turn_off_target"] > 0.3
    assert "| scripted | rware-3 |" in capsys.readouterr().out
    # one family per call: an RWARE and a MAIF model together are refused
    assert condition_eval_cli.main(["scripted:rware-3", "models/maif-tiny-sdhn",
                                    "--instances", "1"]) == 2


def test_an_rware_model_plays_another_team_size_with_its_ids_moved() -> None:
    """rware-3's actors read a 3-way one-hot robot id; on rware-6 robots 3-5 get the mean of the
    trained ids' weights (sdhn_policy.team_size.for_team) instead of an out-of-range id error."""
    from sdhn_experiments.rware_conditions import play_rware, policy_maker

    name, make = policy_maker("models/rware-3-mappo")
    res = play_rware(make, "rware-6", Conditions(), episodes=2, seed=1_000_000, max_steps=200)
    assert name == "rware-3-mappo" and len(res.deliveries) == 2
    assert sum(res.deliveries) > 0  # measured: 42.4 per 500-step episode over 20


def _summaries_with_deliveries(node: object) -> list[dict[str, Any]]:
    if isinstance(node, dict):
        own = [node] if "deliveries_ci95" in node and "deliveries" in node else []
        return own + [s for v in node.values() for s in _summaries_with_deliveries(v)]
    if isinstance(node, list):
        return [s for v in node for s in _summaries_with_deliveries(v)]
    return []


@pytest.mark.parametrize("name", ["rware-latency.json", "team-size.json"])
def test_published_rware_intervals_are_the_one_bootstrap_of_their_episodes(name: str) -> None:
    """Every RWARE deliveries interval under docs/results is ``mean_ci`` (the bootstrap the MAIF
    makespans use) of the episodes stored beside it, to the 0.1 delivery the tables print
    (written by a separate bootstrap of the same resamples before; the ends moved by < 1e-12)."""
    from sdhn_experiments.rware_conditions import RwareResult

    path = Path(__file__).resolve().parents[2] / "docs" / "results" / "conditions" / name
    found = _summaries_with_deliveries(json.loads(path.read_text()))
    assert found, path
    for s in found:
        got = RwareResult(s["deliveries"]).summary()
        assert got["deliveries_mean"] == pytest.approx(s["deliveries_mean"], abs=1e-9)
        assert list(got["deliveries_ci95"]) == pytest.approx(s["deliveries_ci95"], abs=1e-9), s
        assert got["deliveries_ci95"] == mean_ci(s["deliveries"])[1]


def test_the_mean_interval_lies_within_the_episodes() -> None:
    rng = np.random.default_rng(3)
    for n in (2, 5, 20):
        x = rng.integers(0, 40, n).tolist()
        mean, ci = mean_ci(x)
        assert ci is not None and mean is not None
        assert min(x) <= ci[0] <= mean <= ci[1] <= max(x), (x, ci)
    assert mean_ci([7, 7, 7]) == (7.0, (7.0, 7.0)) and mean_ci([4]) == (4.0, (4.0, 4.0))
    assert mean_ci([]) == (None, None)
