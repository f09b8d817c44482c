"""How a MAIF actor behaves where episodes are won: on its goal and one cell from it.

Plays the first instances of a set with the actor (NumPy runtime, sampled at a temperature, as
the cards deploy it) and reads, at every step, the action distribution of every robot that
stands on its goal (the probability it stays) or one cell from a free goal (the probability it
steps onto it), the latter split by the side the goal lies on. MAIF's start square is the
top-left corner and its goal square the bottom-right one, so training mostly shows a robot its
goal below or to its right; a robot pushed past its goal sees it above or to its left. Success
needs every robot on its goal at once: a small leak in either probability, times many robots,
is what turns a team's success into wandering at the step limit.

    .venv/bin/python scripts/probe_arrivals.py models/maif-20-sdhn --task maif-100 --steps 400
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from sdhn_experiments.evaluate_policy import resolve
from sdhn_experiments.heldout_eval import set_instances
from sdhn_policy.actor_runtime import ActorRuntime, check_temperature, choose_actions, log_softmax
from sdhn_policy.weights import WeightsError
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.registry import INSTANCE_SETS

STAY = 0
# the action that moves a robot onto a goal one cell away, by the side the goal lies on
SIDES = {"up": 1, "down": 2, "left": 3, "right": 4}


@dataclass
class Tally:
    """A probability summed over robot-steps, and how many there were."""

    count: int = 0
    total: float = 0.0

    def add(self, p: npt.NDArray[np.floating]) -> None:
        self.count += int(p.size)
        self.total += float(p.sum())

    @property
    def mean(self) -> float | None:
        return self.total / self.count if self.count else None


@dataclass
class ArrivalProbe:
    """P(stay | on goal) and P(step onto goal | one cell from a free goal), per side."""

    task: str
    set: str
    instances: int
    steps: int
    temperature: float
    on_goal: Tally = field(default_factory=Tally)
    one_away: dict[str, Tally] = field(default_factory=lambda: {s: Tally() for s in SIDES})
    completed: int = 0

    def any_side(self) -> Tally:
        """One cell from a free goal, whichever side it lies on."""
        return Tally(sum(t.count for t in self.one_away.values()),
                     sum(t.total for t in self.one_away.values()))

    def summary(self) -> dict[str, object]:
        d = asdict(self)
        d["on_goal"] = {"robot_steps": self.on_goal.count, "p_stay": self.on_goal.mean}
        d["one_away"] = {side: {"robot_steps": t.count, "p_onto_goal": t.mean}
                         for side, t in {**self.one_away, "all": self.any_side()}.items()}
        return d


def probe(policy: ActorRuntime, task: str, which: str = "heldout", *, instances: int = 10,
          steps: int = 400, temperature: float = 0.25, seed: int = 0) -> ArrivalProbe:
    """One episode on each of the first ``instances`` instances of set ``which``, ``steps``
    steps or until it completes (then its robots stop counting)."""
    t = check_temperature(temperature)
    inst = set_instances(task, which)
    if not 1 <= instances <= inst.num_instances:
        raise ValueError(f"instances: {instances}; allowed: 1..{inst.num_instances} "
                         f"(the size of {task}/{which})")
    if steps < 1:
        raise ValueError(f"steps: {steps}; allowed: an integer >= 1")
    b = instances
    env = MaifEnv(inst, num_envs=b, seed=seed, name=task, instance_order="round_robin",
                  max_steps=steps + 1)  # no episode times out inside the probe
    n = env.num_robots
    obs, _ = env.reset(seed=seed)
    h = policy.initial_state(b * n)
    ids = np.tile(np.arange(n), b) if policy.spec.use_robot_id else None
    rng = np.random.default_rng(seed)
    out = ArrivalProbe(task, which, b, steps, t)
    live = np.ones(b, dtype=bool)
    for _ in range(steps):
        logits, h = policy.step(obs.reshape(b * n, -1), h, ids)
        logp = log_softmax(logits)
        p = np.exp(log_softmax(logits / np.float32(t)))  # what play at temperature t draws from
        pos, goal = env.positions, env.goals  # [B, N, 2] (x, y)
        d = goal - pos
        dist = np.abs(d).sum(axis=2)
        occupied = np.zeros((b, env.size, env.size), dtype=bool)  # [b, y, x]
        occupied[np.repeat(np.arange(b), n), pos[..., 1].ravel(), pos[..., 0].ravel()] = True
        goal_free = ~occupied[np.arange(b)[:, None], goal[..., 1], goal[..., 0]]
        counted = live[:, None]
        on = ((dist == 0) & counted).ravel()
        out.on_goal.add(p[on, STAY])
        near = ((dist == 1) & goal_free & counted).ravel()
        dx, dy = d[..., 0].ravel(), d[..., 1].ravel()
        for side, where in (("up", dy < 0), ("down", dy > 0), ("left", dx < 0), ("right", dx > 0)):
            out.one_away[side].add(p[near & where, SIDES[side]])
        act = choose_actions(logp, False, rng, t)
        res = env.step(act.reshape(b, n))
        for ep in res.episodes:
            if live[ep.env_index] and ep.completed:
                out.completed += 1
            live[ep.env_index] = False
        obs = res.obs
        if not live.any():
            break
    return out


def table(p: ArrivalProbe) -> str:
    rows = [("on its goal: stays", p.on_goal),
            *((f"goal one cell {side}, free: steps onto it", t) for side, t in p.one_away.items()),
            ("one cell from a free goal (any side)", p.any_side())]
    lines = [f"{p.task}/{p.set}, {p.instances} instances, {p.steps} steps, sampled at "
             f"T={p.temperature:g}: {p.completed} completed",
             "| where | robot-steps | probability |", "|---|---|---|"]
    lines += [f"| {label} | {t.count} | {'—' if t.mean is None else f'{t.mean:.3f}'} |"
              for label, t in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("actor", type=Path, help="a model directory or an actor file")
    ap.add_argument("--task", help="MAIF task (model directories name theirs)")
    ap.add_argument("--set", default="heldout",
                    choices=[s for s in INSTANCE_SETS if s != "procedural"])
    ap.add_argument("--instances", type=int, default=10, help="the set's first K instances")
    ap.add_argument("--steps", type=int, default=400, help="steps per episode probed")
    ap.add_argument("--temperature", type=float, default=0.25,
                    help="sampled play at this temperature; the probabilities are its own")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, help="JSON with the figures")
    args = ap.parse_args(argv)
    try:
        label, path, task = resolve(args.actor, args.task)
        result = probe(ActorRuntime.from_file(path), task, args.set, instances=args.instances,
                       steps=args.steps, temperature=args.temperature, seed=args.seed)
    except WeightsError as e:
        print(f"probe_arrivals: actor: {e.reason}", file=sys.stderr)
        return 2
    except ValueError as e:
        print(f"probe_arrivals: {e}", file=sys.stderr)
        return 2
    print(f"{label}: {table(result)}")
    if args.out:
        args.out.write_text(json.dumps({"actor": label, **result.summary()}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
