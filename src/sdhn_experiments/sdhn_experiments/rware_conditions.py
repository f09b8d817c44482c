"""RWARE policies under deployment conditions: deliveries per episode, and why latency costs them.

    res = play_rware(learned(rt), "rware-3", Conditions(latency=1), episodes=20)
    res = play_rware(scripted("rware-3"), "rware-3", Conditions(latency=1), episodes=20,
                     dead_reckon=True)
    res.deliveries, res.mechanism       # per episode; counts of what the robots did

One 500-step episode per env, env ``b`` from seed ``seed + b`` (the robustness suite's and the
model cards' episodes with ``seed = RWARE_EVAL_SEED``), the condition model seeded as the
robustness suite seeds it (the env's seed). Policies: a learned actor (the NumPy runtime,
greedy unless told) or the decentralised scripted policy (``sdhn_sim.envs.rware_decentralised``,
which reads nothing but the robot's own observation, so it sees the same stale world).

**The mechanism** (``Mechanism``): rware's actions are relative to the robot's heading and load,
so an action chosen on a stale observation is an action on a world that is gone. For every
action the world executes it compares what the robot saw with what is true at that step:

- ``forward_off_heading``: a FORWARD taken while the true heading differs from the one the robot
  saw (it moves somewhere it did not choose);
- ``turn_off_target``: a LEFT/RIGHT whose resulting heading differs from the heading the robot
  meant (the turn applied to the heading it saw): it turns past (or short of) its target;
- ``toggle_off_load``: a TOGGLE_LOAD taken while the true load differs from the one seen (a
  pick-up that becomes a put-down, or the reverse);
- ``pickups_undone``: a shelf picked up and put down again within two steps.

With ``dead_reckon`` each robot first moves its stale observation forward by the actions it sent
since (``sdhn_policy.dead_reckoning.RwareDeadReckoner``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from sdhn_experiments.condition_eval import mean_ci
from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_policy.dead_reckoning import RwareDeadReckoner
from sdhn_policy.team_size import for_team
from sdhn_policy.weights import decode_weights, load_actor_file
from sdhn_sim.envs.conditions import ConditionedEnv, Conditions
from sdhn_sim.envs.registry import make_env
from sdhn_sim.envs.rware_batched import (
    _TURN_LEFT,
    _TURN_RIGHT,
    FORWARD,
    LEFT,
    RIGHT,
    TOGGLE,
    RwareBatchedEnv,
)
from sdhn_sim.envs.rware_decentralised import DecentralisedPolicy

IntArray = npt.NDArray[np.int64]
# policy(obs [B, N, D], episode rows that just restarted) -> actions [B, N]
Act = Callable[[npt.NDArray[np.float32], list[int]], IntArray]


@dataclass
class Mechanism:
    """Counts over every robot-step whose action the world executed (see the module docstring)."""

    steps: int = 0
    forwards: int = 0
    forward_off_heading: int = 0
    turns: int = 0
    turn_off_target: int = 0
    toggles: int = 0
    toggle_off_load: int = 0
    pickups: int = 0
    pickups_undone: int = 0
    seen_off_cell: int = 0  # steps the robot saw itself on another cell than the true one

    def rates(self) -> dict[str, float | None]:
        def r(a: int, b: int) -> float | None:
            return round(a / b, 4) if b else None

        return {"forward_off_heading": r(self.forward_off_heading, self.forwards),
                "turn_off_target": r(self.turn_off_target, self.turns),
                "toggle_off_load": r(self.toggle_off_load, self.toggles),
                "pickups_undone": r(self.pickups_undone, self.pickups),
                "seen_off_cell": r(self.seen_off_cell, self.steps)}


@dataclass
class RwareResult:
    deliveries: list[int]
    mechanism: Mechanism = field(default_factory=Mechanism)

    def summary(self) -> dict[str, Any]:
        mean, ci = mean_ci(self.deliveries)
        return {"episodes": len(self.deliveries), "deliveries_mean": mean,
                "deliveries_ci95": ci, "deliveries": self.deliveries,
                "mechanism": asdict(self.mechanism), "rates": self.mechanism.rates()}


def learned(rt: ActorRuntime, num_envs: int, num_robots: int, *, greedy: bool = True,
            temperature: float = 1.0, seed: int = 0) -> Act:
    """A learned actor on every robot of every env (its GRU state reset per episode)."""
    n = num_robots
    h = rt.initial_state(num_envs * n)
    ids = np.tile(np.arange(n), num_envs) if rt.spec.use_robot_id else None
    rng = np.random.default_rng(seed)

    def act(obs: npt.NDArray[np.float32], restarted: list[int]) -> IntArray:
        nonlocal h
        for e in restarted:
            h[e * n:(e + 1) * n] = 0.0
        a, _, h = rt.act(obs.reshape(num_envs * n, -1), h, greedy=greedy, rng=rng,
                         robot_id=ids, temperature=temperature)
        return np.asarray(a, dtype=np.int64).reshape(num_envs, n)

    return act


def scripted(task: str, num_robots: int, seed: int = 0) -> Act:
    """The decentralised scripted policy, its memory forgotten at each env's new episode."""
    env = make_env(task, num_envs=1)
    assert isinstance(env, RwareBatchedEnv)
    pol = DecentralisedPolicy(env.layout, num_robots, seed=seed)

    def act(obs: npt.NDArray[np.float32], restarted: list[int]) -> IntArray:
        for e in restarted:
            pol.forget(e)
        return pol.act(obs)

    return act


def play_rware(make_policy: Callable[[int, int], Act], task: str, cond: Conditions, *,
               episodes: int, seed: int, dead_reckon: bool = False,
               trace: bool = True, max_steps: int = 500) -> RwareResult:
    """Deliveries of one episode per env under ``cond`` (env b from seed ``seed + b``).
    ``make_policy(num_envs, num_robots)`` builds the policy; ``trace`` counts the mechanism;
    ``max_steps`` shortens the episodes (tests)."""
    inner = make_env(task, num_envs=episodes, seed=seed, max_steps=max_steps)
    if not isinstance(inner, RwareBatchedEnv):
        raise ValueError(f"task: {task!r} is not an RWARE task")
    env = ConditionedEnv(inner, cond)
    b, n = env.num_envs, env.num_robots
    policy = make_policy(b, n)
    reck = RwareDeadReckoner(b * n, inner.layout, inner.sensor_range) if dead_reckon else None
    obs, _ = env.reset(seed=seed)
    out: dict[int, int] = {}
    mech = Mechanism()
    restarted: list[int] = list(range(b))
    picked_at = np.full((b, n), -10, dtype=np.int64)  # step of each robot's last pick-up
    t = 0
    while len(out) < b:
        seen = obs.reshape(b * n, -1)
        if reck is not None:
            seen = reck.correct(seen, env.obs_age.reshape(-1))
        seen3 = seen.reshape(b, n, -1)
        a = policy(seen3, restarted)
        if reck is not None:
            reck.record(a.reshape(-1))
        # the world's true state before it executes them
        dir0, carry0 = inner.dir.copy(), inner.carry.copy()
        xy0 = inner._xy[inner.cell]
        res = env.step(a)
        if trace:  # envs whose episode ended at this step were reset: not counted
            _count(mech, seen3, a, dir0=dir0, carry0=carry0, xy0=xy0, env=inner,
                   picked_at=picked_at, t=t, done=set(out) | {ep.env_index for ep in res.episodes})
        restarted = []
        for o in env.outcomes:
            out.setdefault(o.env_index, int(o.deliveries or 0))
        for ep in res.episodes:
            restarted.append(ep.env_index)
            if reck is not None:
                reck.reset(range(ep.env_index * n, (ep.env_index + 1) * n))
        obs = res.obs
        t += 1
    return RwareResult([out[e] for e in range(b)], mech)


def _count(m: Mechanism, seen: npt.NDArray[np.float32], a: IntArray, *, dir0: IntArray,
           carry0: IntArray, xy0: IntArray, env: RwareBatchedEnv, picked_at: IntArray, t: int,
           done: set[int]) -> None:
    """Add one step's robot-steps to ``m`` (envs whose episode already ended are skipped)."""
    live = np.ones(a.shape, dtype=bool)
    for e in done:
        live[e] = False
    seen_dir = np.argmax(seen[:, :, 3:7], axis=2)
    seen_load = seen[:, :, 2] > 0.5
    load0 = carry0 >= 0
    m.steps += int(live.sum())
    m.seen_off_cell += int((live & np.any(np.rint(seen[:, :, 0:2]).astype(np.int64) != xy0,
                                          axis=2)).sum())
    fw = live & (a == FORWARD)
    m.forwards += int(fw.sum())
    m.forward_off_heading += int((fw & (seen_dir != dir0)).sum())
    for turn, table in ((LEFT, _TURN_LEFT), (RIGHT, _TURN_RIGHT)):
        tr = live & (a == turn)
        m.turns += int(tr.sum())
        m.turn_off_target += int((tr & (table[seen_dir] != table[dir0])).sum())
    tg = live & (a == TOGGLE)
    m.toggles += int(tg.sum())
    m.toggle_off_load += int((tg & (seen_load != load0)).sum())
    load1 = env.carry >= 0
    picked = live & ~load0 & load1
    dropped = live & load0 & ~load1
    m.pickups += int(picked.sum())
    m.pickups_undone += int((dropped & (t - picked_at <= 2)).sum())
    picked_at[picked] = t


SCRIPTED = "scripted"  # the policy name of the decentralised scripted policy


def policy_maker(model: str, mode_greedy: bool = True, temperature: float = 1.0
                 ) -> tuple[str, Callable[[int, int], Act]]:
    """(name, make_policy) for a model directory or ``scripted:TASK`` (the task is the
    caller's to check)."""
    if model.startswith(f"{SCRIPTED}:"):
        task = model.split(":", 1)[1]
        return SCRIPTED, lambda b, n: scripted(task, n)
    from pathlib import Path

    spec, tensors = decode_weights(load_actor_file(Path(model) / "actor.safetensors"))

    def make(b: int, n: int) -> Act:
        # another team than it trained with: its one-hot ids moved as warm start moves them
        return learned(ActorRuntime(*for_team(spec, tensors, n)), b, n, greedy=mode_greedy,
                       temperature=temperature)

    return Path(model).name, make


def markdown_rows(rows: list[dict[str, Any]]) -> str:
    out = ["| policy | task | mode | condition | severity | deliveries / episode [95 % CI] | "
           "turns off target | forwards off heading | toggles off load |",
           "|---|---|---|---|---|---|---|---|---|"]

    def pct(v: float | None) -> str:
        return "-" if v is None else f"{100 * v:.0f} %"

    for r in rows:
        s = r["summary"]
        lo, hi = s["deliveries_ci95"]
        rates = s["rates"]
        out.append(f"| {r['policy']} | {r['task']} | {r['mode']} | {r['condition']} | "
                   f"{r['severity']} | {s['deliveries_mean']:.1f} [{lo:.1f}, {hi:.1f}] | "
                   f"{pct(rates['turn_off_target'])} | {pct(rates['forward_off_heading'])} | "
                   f"{pct(rates['toggle_off_load'])} |")
    return "\n".join(out) + "\n"
