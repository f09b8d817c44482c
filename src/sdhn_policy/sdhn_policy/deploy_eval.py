"""Greedy evaluation of an exported actor as it deploys (the torch-free NumPy runtime).

MAIF: one episode per instance of the training and the held-out instance sets, success and
makespan first. RWARE: one 500-step episode per evaluation seed, requested shelves delivered.

    results = evaluate_actor(path, "maif-tiny", reward="corrected", instances=100)
    results["train"]["success_rate"], results["heldout"]["makespan"]   # makespan: "NC" if none
    rt = ActorRuntime.from_file(path)
    rware_deliveries(rt, "rware-tiny-2ag", episodes=100, seed=RWARE_EVAL_SEED)["deliveries_mean"]

Used by ``scripts/ship_model.py`` (model cards) and ``scripts/compare_ros_training.py``.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from sdhn_policy.actor_runtime import ActorRuntime
from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import BatchedEnv, EpisodeStats
from sdhn_sim.envs.maif import MaifEnv

SETS = ("train", "heldout")
RWARE_EVAL_SEED = 1_000_000
"""First seed of a shipped RWARE card's evaluation episodes: far from the seeds training and its
periodic evaluations draw (train.seed and a few above), so they are episodes never trained on."""


def instance_env(env_name: str, which: str, instances: int, seed: int, reward: str) -> MaifEnv:
    """A batch of ``instances`` envs, env b playing instance b of the set ``which``."""
    env = make_env(env_name, num_envs=instances, seed=seed, instance_order="round_robin",
                   instance_ids=list(range(instances)), instance_set=which, reward=reward)
    if not isinstance(env, MaifEnv):
        raise ValueError(f"env: {env_name!r} has no instance sets; allowed: a MAIF env")
    return env


def run_actor(rt: ActorRuntime, env: BatchedEnv, seed: int) -> list[EpisodeStats]:
    """One greedy episode per env of the batch (MAIF: env b plays instance b; RWARE: env b
    starts from seed ``seed + b``), NumPy runtime only."""
    b, n = env.num_envs, env.num_robots
    obs, _ = env.reset(seed=seed)
    h = rt.initial_state(b * n)
    ids = np.tile(np.arange(n), b)
    rng = np.random.default_rng(seed)
    first: dict[int, EpisodeStats] = {}
    while len(first) < b:
        act, _, h = rt.act(obs.reshape(b * n, -1), h, greedy=True, rng=rng,
                           robot_id=ids if rt.spec.use_robot_id else None)
        res = env.step(act.reshape(b, n))
        for ep in res.episodes:
            first.setdefault(ep.env_index, ep)
            h[ep.env_index * n:(ep.env_index + 1) * n] = 0.0  # a new episode starts there
        obs = res.obs
    return [first[i] for i in range(b)]


def summarise(eps: list[EpisodeStats]) -> dict[str, Any]:
    """Success rate, makespan over completed episodes ("NC" when none), return, collisions."""
    done = [e.makespan for e in eps if e.makespan is not None]
    return {"success_rate": float(np.mean([e.completed for e in eps])),
            "makespan": round(float(np.mean(done)), 2) if done else "NC",
            "return": round(float(np.mean([e.episode_return for e in eps])), 2),
            "collisions": round(float(np.mean([e.collisions for e in eps])), 2)}


def evaluate_actor(actor: str | os.PathLike[str], env_name: str, reward: str,
                   instances: int = 100, seed: int = 0) -> dict[str, dict[str, Any]]:
    """{set: summary} for the actor file on instances 0..instances-1 of each set."""
    rt = ActorRuntime.from_file(actor)
    return {which: summarise(run_actor(rt, instance_env(env_name, which, instances, seed,
                                                        reward), seed))
            for which in SETS}


def rware_deliveries(rt: ActorRuntime, env_name: str, episodes: int, seed: int
                     ) -> dict[str, Any]:
    """Greedy deliveries per RWARE episode (mean, population std, each episode's) and return, one
    episode from each seed ``seed .. seed + episodes - 1``."""
    env = make_env(env_name, num_envs=episodes, seed=seed)
    if isinstance(env, MaifEnv):
        raise ValueError(f"env: {env_name!r} is a MAIF env; allowed: an RWARE env")
    eps = run_actor(rt, env, seed)
    d = np.array([e.deliveries or 0 for e in eps], dtype=float)
    return {"episodes": len(eps), "seeds": f"{seed}..{seed + episodes - 1}",
            "deliveries_mean": round(float(d.mean()), 3),
            "deliveries_std": round(float(d.std()), 3),
            "deliveries": [int(x) for x in d],
            "return": round(float(np.mean([e.episode_return for e in eps])), 3)}
