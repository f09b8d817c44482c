#!/usr/bin/env python3
"""Deploy a shipped sdhn policy from its folder alone: ``actor.onnx``, ``actor.onnx.json`` and
``deploy.json``, with NumPy and onnxruntime. No sdhn code decides an action here: everything the
project's actor does (GRU state, feature-free raw input, argmax or sampling, the stall rule, the
final approach, the random stream) is re-implemented from the JSON, as a C++ or other-language
port would do it.

    python examples/onnx_reference/run_policy.py models/maif-10-sdhn --instances 50
    python examples/onnx_reference/run_policy.py models/maif-10-sdhn --set heldout_large \\
        --first 0 --instances 200 --seed 0

The episodes come from the project's PettingZoo environment (``sdhn_sim.envs.pettingzoo_env``,
the only sdhn import, for the world, not the policy): instance ``first + k`` of the chosen set,
one episode each; the script prints the success rate with a 95 % Wilson interval and the mean
makespan of the completed episodes. ``test/policy/test_onnx_reference.py`` holds its actions equal
to the project's actor core (``sdhn_policy.actor_core``) step for step.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort


class StallRule:
    """``deploy.json["stall_breaking"]`` for one robot: state, reset and update as listed."""

    def __init__(self, spec: dict[str, Any]) -> None:
        p, c = spec["parameters"], spec["constants"]
        self.calm_steps, self.progress_steps = p["calm_steps"], p["progress_steps"]
        self.sample_steps, self.temperature = p["sample_steps"], float(p["temperature"])
        self.robot_cell, self.eps = float(c["robot_cell"]), float(c["eps"])
        self.pos, self.goal = c["position_indices"], c["goal_indices"]
        self.neighbours = list(c["neighbour_indices"])
        self.reset()

    def reset(self) -> None:
        self.last: np.ndarray | None = None
        self.calm, self.best, self.no_progress, self.left = 0, math.inf, 0, 0

    def update(self, obs: np.ndarray) -> bool:
        """True when this step's action is to be sampled."""
        same = self.last is not None and bool(np.all(obs == self.last))
        self.calm = self.calm + 1 if same else 0
        self.last = obs.copy()
        dist = float(np.abs(obs[self.pos[0]] - obs[self.goal[0]])
                     + np.abs(obs[self.pos[1]] - obs[self.goal[1]]))  # float32 arithmetic
        off_goal = dist > self.eps
        improved = dist < self.best - self.eps
        self.best = min(self.best, dist)
        self.no_progress = 0 if improved else self.no_progress + 1
        neighbour = any(obs[i] == self.robot_cell for i in self.neighbours)
        stalled = ((self.calm >= self.calm_steps and neighbour)
                   or (self.no_progress >= self.progress_steps and off_goal))
        if stalled and self.left == 0:
            self.left = self.sample_steps
        sample = self.left > 0
        self.left = max(self.left - 1, 0)
        return sample


class FinalApproach:
    """``deploy.json["final_approach"]`` for one robot: capture, hold and path, as listed."""

    def __init__(self, spec: dict[str, Any]) -> None:
        c = spec["constants"]
        self.size, self.window = int(c["grid_size"]), int(c["window_size"])
        self.pos, self.goal = c["position_indices"], c["goal_indices"]
        self.centre, self.radius = int(c["centre_index"]), int(c["radius"])
        self.free, self.stay = float(c["free_cell"]), int(c["stay"])
        self.move = {tuple(d): int(a) for a, d in c["action_deltas (dx, dy)"].items()}

    def apply(self, obs: np.ndarray, action: int, sampled: bool) -> int:
        offset = (obs[self.goal] - obs[self.pos]) * np.float32(self.size - 1)  # float32
        dx, dy = (int(v) for v in np.rint(offset))
        if abs(dx) + abs(dy) == 1 and obs[self.centre + dx + dy * self.window] == self.free:
            return self.move[(dx, dy)]
        if dx == 0 and dy == 0 and not sampled:
            return self.stay
        if abs(dx) + abs(dy) >= 2 and max(abs(dx), abs(dy)) <= self.radius and not sampled:
            step = self.path_step(obs, dx, dy)
            if step is not None:
                return step
        return action

    def path_step(self, obs: np.ndarray, gx: int, gy: int) -> int | None:
        """Breadth-first distances from the goal over the free window cells; the first of up,
        down, left, right that is one step closer (None: the goal is taken or walled off)."""
        def free(x: int, y: int) -> bool:
            return (max(abs(x), abs(y)) <= self.radius
                    and obs[self.centre + x + y * self.window] == self.free)

        if not free(gx, gy):
            return None
        steps = ((0, -1), (0, 1), (-1, 0), (1, 0))  # up, down, left, right: the tie order
        dist = {(gx, gy): 0}
        queue = deque([(gx, gy)])
        while queue:
            x, y = queue.popleft()
            for ddx, ddy in steps:
                cell = (x + ddx, y + ddy)
                if cell not in dist and free(*cell):
                    dist[cell] = dist[(x, y)] + 1
                    queue.append(cell)
        if (0, 0) not in dist:
            return None
        for ddx, ddy in steps:
            if dist.get((ddx, ddy)) == dist[(0, 0)] - 1:
                return self.move[(ddx, ddy)]
        return None


def log_softmax32(logits: np.ndarray) -> np.ndarray:
    z = logits - logits.max(axis=-1, keepdims=True)
    return (z - np.log(np.exp(z).sum(axis=-1, keepdims=True))).astype(np.float32)


def sample(logp: np.ndarray, temperature: float, rng: np.random.Generator) -> int:
    lp = logp.astype(np.float64)
    if temperature != 1.0:
        lp = lp / temperature
        lp = lp - lp.max()
    cdf = np.cumsum(np.exp(lp))
    u = rng.random() * cdf[-1]
    return int(min(int((cdf < u).sum()), len(cdf) - 1))


class DeployedTeam:
    """N robots, each acting from its own observation, as ``deploy.json`` says."""

    def __init__(self, model_dir: Path, num_robots: int, seed: int) -> None:
        self.contract = json.loads((model_dir / "deploy.json").read_text())
        io = json.loads((model_dir / self.contract["io_contract"]).read_text())
        self.session = ort.InferenceSession(str(model_dir / self.contract["model"]),
                                            providers=["CPUExecutionProvider"])
        self.hidden_size = int(io["inputs"]["hidden"]["shape"][1])
        self.obs_size = int(self.contract["observation"]["size"])
        self.uses_id = "robot_id" in io["inputs"]
        self.mode = self.contract["mode"]
        self.n = num_robots
        self.rngs = [np.random.default_rng([seed, i]) for i in range(num_robots)]
        stall = self.contract.get("stall_breaking")
        self.stalls = [StallRule(stall) for _ in range(num_robots)] if stall else None
        approach = self.contract.get("final_approach")
        self.approach = FinalApproach(approach) if approach else None
        self.hidden = np.zeros((num_robots, self.hidden_size), np.float32)
        self.sampled = 0  # decisions drawn from the policy (not argmax), for reports and tests

    def reset(self) -> None:
        """A new episode: zero GRU state, fresh stall state (the random streams go on)."""
        self.hidden[:] = 0.0
        for s in self.stalls or []:
            s.reset()

    def act(self, obs: np.ndarray) -> np.ndarray:
        """[N, obs_size] float32 -> [N] actions."""
        feed: dict[str, np.ndarray] = {"obs": obs.astype(np.float32), "hidden": self.hidden}
        if self.uses_id:
            feed["robot_id"] = np.arange(self.n, dtype=np.int64)
        logits, self.hidden = self.session.run(["logits", "hidden_out"], feed)
        logp = log_softmax32(logits)
        actions = np.zeros(self.n, dtype=np.int64)
        for i in range(self.n):
            greedy, temperature = bool(self.mode["greedy"]), float(self.mode["temperature"])
            if self.stalls is not None and self.stalls[i].update(obs[i]):
                greedy, temperature = False, self.stalls[i].temperature
            actions[i] = int(logp[i].argmax()) if greedy else sample(logp[i], temperature,
                                                                      self.rngs[i])
            if self.approach is not None:  # after stall breaking: is this step sampled?
                actions[i] = self.approach.apply(obs[i], int(actions[i]), not greedy)
            self.sampled += not greedy
        return actions


def run_episode(env: Any, team: DeployedTeam) -> tuple[list[np.ndarray], dict[str, Any]]:
    """One episode; returns the joint actions taken and the episode's metrics."""
    obs, _ = env.reset()
    team.reset()
    taken: list[np.ndarray] = []
    while True:
        joint = team.act(np.stack([obs[a] for a in env.possible_agents]))
        taken.append(joint)
        obs, _r, _term, _trunc, infos = env.step(
            {a: int(joint[i]) for i, a in enumerate(env.possible_agents)})
        if not env.agents:
            return taken, infos[env.possible_agents[0]]["episode"]


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (max(0.0, centre - half), min(1.0, centre + half))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model_dir", type=Path)
    ap.add_argument("--env", default=None, help="default: deploy.json's env")
    ap.add_argument("--set", default="heldout_large", help="MAIF instance set")
    ap.add_argument("--first", type=int, default=0, help="first instance index")
    ap.add_argument("--instances", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0, help="seed of the robots' random streams")
    args = ap.parse_args(argv)
    from sdhn_sim.envs.pettingzoo_env import parallel_env  # the world only

    contract = json.loads((args.model_dir / "deploy.json").read_text())
    env_name = args.env or contract["env"]
    done, makespans = 0, []
    team: DeployedTeam | None = None
    for k in range(args.first, args.first + args.instances):
        env = parallel_env(env_name, seed=args.seed, instance_set=args.set,
                           instance_order="round_robin", instance_ids=[k])
        team = team or DeployedTeam(args.model_dir, len(env.possible_agents), args.seed)
        _actions, episode = run_episode(env, team)
        if episode["completed"]:
            done += 1
            makespans.append(episode["makespan"])
    lo, hi = wilson(done, args.instances)
    mean = f"{np.mean(makespans):.2f}" if makespans else "NC"
    print(f"{env_name} {args.set}[{args.first}:{args.first + args.instances}] mode "
          f"{contract['mode']['kind']}: success {done / args.instances:.3f} "
          f"[{lo:.3f}, {hi:.3f}] (95 % Wilson), makespan {mean}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
