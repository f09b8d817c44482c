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

The centralised reference (``evaluate_planner_under``): the scripted planner the makespan ratios
of the protocol are taken against (``sdhn_sim.envs.maif_scripted.PlannerPolicy``: it knows the
map, every start and goal, and replans everyone from the true state whenever the world deviates
from its plan), played under the same condition model, seeds and instances. Lost actions and
slow robots reach it as they reach a policy (the world executes what the conditions let
through); under observation latency it acts on the state as the robots' observations saw it
(each robot where its observation, ``obs_age`` steps old, put it), optionally moved forward by
the moves it sent since (its own dead reckoning). It is the best case a policy could hope for
under a condition by this measure, not an optimum: it does not know which actions will be lost
or which robots are slow, and prioritized planning is not optimal. Beside it, the **relaxed
bound** (``relaxed_bound_under``): each robot alone on its shortest path, moving on every step
the conditions let its action through (the same draws); the team's time is its slowest robot's.
No policy completes an instance under those draws sooner, so its ratio to its ideal (the longest
shortest path) is the delay the condition itself imposes on the critical path.

Deployment modes (``Mode``): greedy, greedy with stall breaking (``StallRule``; optionally with
the final approach after it, ``sdhn_policy.final_approach``), sampled at a temperature, each
optionally with dead reckoning (``sdhn_policy.dead_reckoning``: the robot moves
its stale observation forward by the actions it sent since).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import stats

from sdhn_experiments.heldout_eval import Policy, map_bootstrap_interval, set_instances
from sdhn_policy.actor_runtime import check_temperature
from sdhn_policy.dead_reckoning import DeadReckoner
from sdhn_policy.final_approach import FinalApproach
from sdhn_policy.stall_breaker import StallBreaker, StallRule
from sdhn_sim.envs.conditions import STAY, ConditionedEnv, ConditionModel, Conditions
from sdhn_sim.envs.maif import ACTION_DELTAS, MaifEnv, MaifWorld
from sdhn_sim.envs.maif_scripted import PlannerPolicy, bfs_distances

DEFAULT_SET = "heldout_large"


@dataclass(frozen=True)
class Mode:
    """How the robots choose actions."""

    greedy: bool = True
    temperature: float = 1.0  # sampled play (greedy false)
    stall: StallRule | None = None  # greedy with stall breaking
    approach: bool = False  # with stall breaking: the final approach after it
    dead_reckon: bool = False

    def label(self) -> str:
        base = ("greedy" if self.greedy and self.stall is None else
                f"greedy, stall breaking {self.stall.text()}" if self.greedy and self.stall
                else f"sampled at T={self.temperature:g}")
        return (base + (", final approach" if self.approach else "")
                + (", dead reckoning" if self.dead_reckon else ""))

    def check(self) -> Mode:
        check_temperature(self.temperature)
        if self.stall is not None and not self.greedy:
            raise ValueError("mode: stall breaking is a greedy mode (greedy must be true)")
        if self.approach and self.stall is None:
            raise ValueError("mode: the final approach requires stall breaking")
        return self


def card_mode(model_dir: str | Path) -> Mode:
    """The deployment mode a model card names (``heldout_large.deploy`` of card.json)."""
    card = json.loads((Path(model_dir) / "card.json").read_text())
    d = card.get("heldout_large", {}).get("deploy")
    if d is None:
        return Mode()
    return Mode(greedy=bool(d["greedy"]), temperature=float(d.get("temperature", 1.0)),
                stall=StallRule.of_mode(d), approach=bool(d.get("final_approach", False)),
                dead_reckon=bool(d.get("dead_reckoning", False))).check()


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


def keep_outcomes(env: ConditionedEnv, out: dict[int, ConditionResult],
                  num_formations: int) -> None:
    """Each env's first finished episode (instance b played by env b) into ``out``."""
    for o in env.outcomes:
        if o.env_index not in out:
            out[o.env_index] = ConditionResult(
                instance=o.env_index, map=o.env_index // num_formations,
                success=o.survivors_completed, makespan=o.survivors_makespan,
                team_success=o.completed, failed=o.failed, length=o.length)


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
    approach = FinalApproach(base.size) if mode.approach else None
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
            if approach is not None:
                act = approach.apply(flat, act, breaker.sampling)
        h = h_next
        if dr is not None:
            dr.record(act)
        res = env.step(act.reshape(b, n))
        keep_outcomes(env, out, inst.num_formations)
        for ep in res.episodes:
            rows = slice(ep.env_index * n, (ep.env_index + 1) * n)
            h[rows] = 0.0
            if breaker is not None:
                breaker.reset(rows)
            if dr is not None:
                dr.reset(rows)
        obs = res.obs
    return [out[e] for e in range(b)]


PLANNER = "planner"  # the policy name of the centralised planner's rows
PLANNER_MODE = "centralised, replans from the true state"
RELAXED = "relaxed bound"  # the policy name of the relaxed bound's rows
RELAXED_MODE = "each robot alone on its shortest path"


class PlannerError(ValueError):
    """A condition the centralised planner cannot be played under."""


class DelayedWorld:
    """The planner's view of a ``MaifEnv`` under observation latency (a ``PlannerView``): each
    robot where its latest observation saw it, ``age`` steps ago, and with ``dead_reckon`` moved
    forward by the moves the planner sent since, each taken unless an obstacle or the grid's
    edge is in its way (other robots ignored, as ``sdhn_policy.dead_reckoning`` does); goals,
    obstacles and the clock as they are. Call ``record_state`` after reset and every step,
    ``update(ages)`` before the planner acts and ``record_actions`` with what it chose."""

    def __init__(self, env: MaifEnv, depth: int, dead_reckon: bool) -> None:
        self.env = env
        self.size = env.size
        self.num_envs = env.num_envs
        self.num_robots = env.num_robots
        self.instances = env.instances
        self.dead_reckon = dead_reckon
        self._depth = int(depth)
        slots = self._depth + 1
        b, n = env.num_envs, env.num_robots
        self._pos = np.zeros((slots, b, n, 2), dtype=np.int64)  # ring: state of global step g
        self._act = np.zeros((slots, b, n), dtype=np.int64)  # ring: actions sent at step g
        self._g = 0
        self._view = env.positions
        self._obstacles: dict[int, npt.NDArray[np.bool_]] = {}

    def record_state(self) -> None:
        self._pos[self._g % len(self._pos)] = self.env.positions

    def record_actions(self, actions: npt.NDArray[np.int64]) -> None:
        self._act[self._g % len(self._act)] = actions
        self._g += 1

    def update(self, ages: npt.NDArray[np.int64]) -> None:
        slots = len(self._pos)
        b, n = np.indices(ages.shape)
        pos = self._pos[(self._g - ages) % slots, b, n].copy()  # [B, N, 2]
        if self.dead_reckon and self._depth:
            blocked = np.stack([self._grid(int(k)) for k in self.env.instance_id])
            for s in range(self._depth):
                moving = s < ages
                d = ACTION_DELTAS[self._act[(self._g - ages + s) % slots, b, n]]
                nxt = pos + d
                inside = np.all((nxt >= 0) & (nxt < self.size), axis=2)
                nx, ny = np.clip(nxt[..., 0], 0, self.size - 1), np.clip(nxt[..., 1], 0,
                                                                           self.size - 1)
                free = inside & ~blocked[b, ny, nx]
                pos = np.where((moving & free)[..., None], nxt, pos)
        self._view = pos

    def _grid(self, k: int) -> npt.NDArray[np.bool_]:
        if k not in self._obstacles:
            self._obstacles[k] = self.instances.instance(k)[0]
        return self._obstacles[k]

    @property
    def positions(self) -> npt.NDArray[np.int64]:
        return self._view.copy()

    @property
    def step_count(self) -> npt.NDArray[np.int64]:
        return self.env.step_count

    def world(self, b: int = 0) -> MaifWorld:
        return replace(self.env.world(b), positions=self._view[b].copy())


def evaluate_planner_under(task: str, cond: Conditions, *, dead_reckon: bool = False,
                           instances: int | None = None, which: str = DEFAULT_SET,
                           seed: int = 0, max_steps: int = 500) -> list[ConditionResult]:
    """The centralised planner, one episode per instance 0..instances-1 of set ``which`` under
    ``cond`` (the condition model seeded ``seed``, as ``evaluate_under``); ``dead_reckon``: under
    latency it moves the stale state forward by the moves it sent (see ``DelayedWorld``).
    Conditions on what a robot reads (position noise, misread cells) do not reach a planner
    that reads the state, and it would plan for failed robots: both are refused."""
    for name in ("position_noise", "cell_misread", "failures"):
        if getattr(cond, name):
            raise PlannerError(f"planner: {name} is not modelled for the centralised planner "
                               "(allowed: latency, latency_random, lost_actions, slow robots)")
    inst = set_instances(task, which)
    b = inst.num_instances if instances is None else min(int(instances), inst.num_instances)
    base = MaifEnv(inst, num_envs=b, seed=seed, name=task, instance_order="round_robin",
                   instance_ids=list(range(b)), reward="corrected", max_steps=max_steps)
    env = ConditionedEnv(base, cond)
    env.reset(seed=seed)
    planner = PlannerPolicy(seed)
    view = DelayedWorld(base, cond.latency, dead_reckon) if cond.latency else None
    if view is not None:
        view.record_state()
    out: dict[int, ConditionResult] = {}
    while len(out) < b:
        if view is not None:
            view.update(env.obs_age)
            act = planner.act(view)
            view.record_actions(act)
        else:
            act = planner.act(base)
        env.step(act)
        if view is not None:
            view.record_state()
        keep_outcomes(env, out, inst.num_formations)
    return [out[e] for e in range(b)]


def relaxed_bound_under(task: str, cond: Conditions, *, instances: int | None = None,
                        which: str = DEFAULT_SET, seed: int = 0,
                        max_steps: int = 500) -> list[ConditionResult]:
    """The relaxed bound on instances 0..instances-1 of set ``which`` under ``cond`` (the
    condition model seeded ``seed``, drawing what it draws in ``evaluate_under``): per instance,
    the first step by which every robot has had as many executed moves as its shortest path is
    long (``makespan`` None past ``max_steps``). Only conditions on actions (lost actions, slow
    robots) delay a lone robot that knows its own moves; others are refused."""
    if cond.latency or cond.position_noise or cond.cell_misread or cond.failures:
        raise PlannerError("relaxed bound: only lost_actions and slow robots are modelled")
    inst = set_instances(task, which)
    b = inst.num_instances if instances is None else min(int(instances), inst.num_instances)
    need = []
    for k in range(b):
        obstacles, starts, goals = inst.instance(k)
        free = ~obstacles
        need.append([int(bfs_distances(free, int(gx), int(gy))[int(sy), int(sx)])
                     for (sx, sy), (gx, gy) in zip(starts.tolist(), goals.tolist(), strict=True)])
    length = np.asarray(need, dtype=np.int64)  # [B, N] moves each robot must make
    n = length.shape[1]
    model = ConditionModel(cond, b, n, seed, inst.config.size)
    model.start(None, np.zeros((b, n, 1), dtype=np.float32))
    moved = np.zeros_like(length)
    done_at = np.where(length.max(axis=1) == 0, 0, -1)
    move = np.ones((b, n), dtype=np.int64)  # any move: only whether it is let through counts
    for t in range(1, max_steps + 1):
        moved += model.act(move) != STAY
        done_at = np.where((done_at < 0) & np.all(moved >= length, axis=1), t, done_at)
        if np.all(done_at >= 0):
            break
    return [ConditionResult(instance=e, map=e // inst.num_formations, success=bool(d >= 0),
                            makespan=int(d) if d >= 0 else None, team_success=bool(d >= 0),
                            failed=0, length=int(d) if d >= 0 else max_steps)
            for e, d in enumerate(done_at.tolist())]


def mean_ci(x: Sequence[float], seed: int = 0) -> tuple[float | None, tuple[float, float] | None]:
    """The mean and its 95 % percentile bootstrap interval (5,000 resamples; makespans here,
    RWARE deliveries per episode in ``rware_conditions``); a point for one value or no spread,
    (None, None) for none."""
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
    mk, mk_ci = mean_ci([float(r.makespan) for r in recs if r.makespan is not None])
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
        m, ci = mean_ci(ratios)
        out.update({"makespan_over_ideal": m, "makespan_over_ideal_ci95": ci,
                    "paired_instances": len(ratios)})
    return out


def records_json(recs: list[ConditionResult]) -> list[dict[str, Any]]:
    return [asdict(r) for r in recs]
