"""A MAIF policy under deployment conditions (``sdhn_sim.envs.conditions``), as it deploys.

    mode = card_mode("models/maif-10-sdhn")                # the card's deployment mode
    recs = evaluate_under(rt, "maif-10", cond, mode, instances=200)
    ideal = evaluate_under(rt, "maif-10", Conditions(), mode, instances=200)
    row = summarise_under(recs, ideal, num_formations=5)   # success, makespan, / ideal, 95 % CIs

One episode per instance of a fixed set (the large held-out set by default; env ``b`` plays
instance ``b``, all in one vectorised batch), the robots acting on what the conditions let them
see, the world executing what the conditions let through. An episode's outcome is taken at its
end or, under robot failures, when every surviving robot first stands on its goal (the failed
robots' goals dropped): **success** is then the survivors' success, and the ideal-team success
(every robot on its goal) is kept beside it. Makespan: mean over the successful episodes;
**makespan over ideal**: per instance, the makespan under the condition divided by the same
policy's makespan in the ideal world, over the instances both complete (paired, so a condition
is not charged for the instances it fails), mean with a 95 % bootstrap interval over instances.
The success interval bootstraps over maps (``heldout_eval``: formations of one map correlate).

Deployment modes (``Mode``): greedy, greedy with stall breaking (``StallRule``), sampled at a
temperature, each optionally with dead reckoning (``sdhn_policy.dead_reckoning``: the robot moves
its stale observation forward by the actions it sent since).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from sdhn_experiments.heldout_eval import Policy, map_bootstrap_interval, set_instances
from sdhn_policy.actor_runtime import check_temperature
from sdhn_policy.dead_reckoning import DeadReckoner
from sdhn_policy.stall_breaker import StallBreaker, StallRule
from sdhn_sim.envs.conditions import ConditionedEnv, Conditions
from sdhn_sim.envs.maif import MaifEnv

DEFAULT_SET = "heldout_large"


@dataclass(frozen=True)
class Mode:
    """How the robots choose actions."""

    greedy: bool = True
    temperature: float = 1.0  # sampled play (greedy false)
    stall: StallRule | None = None  # greedy with stall breaking
    dead_reckon: bool = False

    def label(self) -> str:
        base = ("greedy" if self.greedy and self.stall is None else
                f"greedy, stall breaking {self.stall.text()}" if self.greedy and self.stall
                else f"sampled at T={self.temperature:g}")
        return base + (", dead reckoning" if self.dead_reckon else "")

    def check(self) -> Mode:
        check_temperature(self.temperature)
        if self.stall is not None and not self.greedy:
            raise ValueError("mode: stall breaking is a greedy mode (greedy must be true)")
        return self


def card_mode(model_dir: str | Path) -> Mode:
    """The deployment mode a model card names (``heldout_large.deploy`` of card.json)."""
    card = json.loads((Path(model_dir) / "card.json").read_text())
    d = card.get("heldout_large", {}).get("deploy")
    if d is None:
        return Mode()
    return Mode(greedy=bool(d["greedy"]), temperature=float(d.get("temperature", 1.0)),
                stall=StallRule.of_mode(d), dead_reckon=bool(d.get("dead_reckoning", False))
                ).check()


@dataclass(frozen=True)
class ConditionResult:
    """One instance's episode under a condition."""

    instance: int
    map: int
    success: bool  # survivors' success (= the ideal-team success without failures)
    makespan: int | None  # survivors' makespan
    team_success: bool  # every robot on its goal (the ideal-team criterion)
    failed: int  # robots failed when the outcome was taken
    length: int


def evaluate_under(policy: Policy, task: str, cond: Conditions, mode: Mode, *,
                   instances: int | None = None, which: str = DEFAULT_SET, seed: int = 0,
                   reward: str = "corrected", max_steps: int = 500) -> list[ConditionResult]:
    """One episode per instance 0..instances-1 of set ``which`` under ``cond`` (see the module
    docstring); the condition model is seeded ``seed`` (env ``b`` draws as a simulator seeded
    ``seed + b`` replaying instance ``b``)."""
    mode.check()
    inst = set_instances(task, which)
    b = inst.num_instances if instances is None else min(int(instances), inst.num_instances)
    base = MaifEnv(inst, num_envs=b, seed=seed, name=task, instance_order="round_robin",
                   instance_ids=list(range(b)), reward=reward, max_steps=max_steps)
    env = ConditionedEnv(base, cond)
    n = env.num_robots
    obs, _ = env.reset(seed=seed)
    h = policy.initial_state(b * n)
    ids = np.tile(np.arange(n), b) if policy.spec.use_robot_id else None
    rng = np.random.default_rng(seed)
    breaker = StallBreaker(mode.stall, b * n) if mode.stall is not None else None
    dr = DeadReckoner(b * n, base.size) if mode.dead_reckon else None
    out: dict[int, ConditionResult] = {}
    while len(out) < b:
        flat = obs.reshape(b * n, -1)
        if dr is not None:
            flat = dr.correct(flat, env.obs_age.reshape(-1))
        act, _, h_next = policy.act(flat, h, greedy=mode.greedy, rng=rng, robot_id=ids,
                                    temperature=mode.temperature)
        if breaker is not None:
            act = breaker.resample(policy, flat, h, act, rng=rng, robot_id=ids)
        h = h_next
        if dr is not None:
            dr.record(act)
        res = env.step(act.reshape(b, n))
        for o in env.outcomes:
            e = o.env_index
            if e not in out:
                out[e] = ConditionResult(
                    instance=e, map=e // inst.num_formations, success=o.survivors_completed,
                    makespan=o.survivors_makespan, team_success=o.completed, failed=o.failed,
                    length=o.length)
        for ep in res.episodes:
            rows = slice(ep.env_index * n, (ep.env_index + 1) * n)
            h[rows] = 0.0
            if breaker is not None:
                breaker.reset(rows)
            if dr is not None:
                dr.reset(rows)
        obs = res.obs
    return [out[e] for e in range(b)]


def _mean_ci(x: list[float], seed: int = 0) -> tuple[float | None, tuple[float, float] | None]:
    if not x:
        return None, None
    a = np.asarray(x, dtype=np.float64)
    if len(a) < 2 or np.all(a == a[0]):
        return float(a.mean()), (float(a.mean()), float(a.mean()))
    r = stats.bootstrap((a,), np.mean, confidence_level=0.95, n_resamples=5000,
                       method="percentile", random_state=np.random.default_rng(seed))
    return float(a.mean()), (float(r.confidence_interval.low), float(r.confidence_interval.high))


def summarise_under(recs: list[ConditionResult], ideal: list[ConditionResult] | None,
                    num_formations: int) -> dict[str, Any]:
    """Success [95 % CI over maps], team success, makespan [CI], makespan over ideal [CI]."""
    success = np.array([r.success for r in recs])
    maps = np.array([r.map for r in recs])
    per_map = np.array([success[maps == m].mean() for m in np.unique(maps)])
    mk, mk_ci = _mean_ci([float(r.makespan) for r in recs if r.makespan is not None])
    out: dict[str, Any] = {
        "instances": len(recs), "maps": len(per_map), "formations_per_map": num_formations,
        "success_rate": float(success.mean()),
        "success_ci95_maps": map_bootstrap_interval(per_map),
        "team_success_rate": float(np.mean([r.team_success for r in recs])),
        "makespan_mean": mk, "makespan_ci95": mk_ci,
        "failed_robots_mean": float(np.mean([r.failed for r in recs])),
    }
    if ideal is not None:
        ratios = [r.makespan / i.makespan for r, i in zip(recs, ideal, strict=True)
                  if r.makespan is not None and i.makespan]
        m, ci = _mean_ci(ratios)
        out.update({"makespan_over_ideal": m, "makespan_over_ideal_ci95": ci,
                    "paired_instances": len(ratios)})
    return out


def records_json(recs: list[ConditionResult]) -> list[dict[str, Any]]:
    return [asdict(r) for r in recs]
