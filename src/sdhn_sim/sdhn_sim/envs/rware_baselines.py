"""Deliveries per episode of RWARE's reference policies: random, the centralised scripted
heuristic and the decentralised scripted one (each robot on its own observation).

One 500-step episode (rware's limit) from each seed ``seed .. seed + episodes - 1``. Used by
``scripts/eval_rware_baselines.py`` (the baseline table) and ``scripts/ship_model.py`` (the
baselines beside a shipped RWARE policy on its card).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import reward_name
from sdhn_sim.envs.rware_batched import RwareBatchedEnv
from sdhn_sim.envs.rware_decentralised import DecentralisedPolicy
from sdhn_sim.envs.rware_scripted import ObsPolicy, RandomPolicy, ScriptedPolicy, run_episodes

POLICIES = ("random", "scripted", "decentralised")
LABELS = {"random": "random", "scripted": "scripted (centralised)",
          "decentralised": "scripted (decentralised, own observation)"}


def evaluate_baseline(name: str, policy: str, *, episodes: int, seed: int) -> dict[str, Any]:
    """Deliveries and return per episode (mean, population std, and each episode's)."""
    if policy not in POLICIES:
        raise ValueError(f"policy {policy!r}; allowed: {', '.join(POLICIES)}")
    # the centralised heuristic reads rware's Warehouse objects: the real package's backend
    backend = "rware" if policy == "scripted" else "batched"
    env = make_env(name, num_envs=episodes, seed=seed, backend=backend)
    actor: ScriptedPolicy | ObsPolicy
    if policy == "scripted":
        actor = ScriptedPolicy(seed)
    elif policy == "decentralised":
        assert isinstance(env, RwareBatchedEnv)
        actor = DecentralisedPolicy(env.layout, env.num_robots, seed)
    else:
        actor = RandomPolicy(seed)
    eps = run_episodes(env, actor, seed=seed)
    deliveries = np.array([e.deliveries for e in eps], dtype=float)
    returns = np.array([e.episode_return for e in eps])
    return {"env": name, "policy": policy, "episodes": len(eps),
            "seeds": f"{seed}..{seed + episodes - 1}",
            "deliveries_mean": float(deliveries.mean()), "deliveries_std": float(deliveries.std()),
            "deliveries": [int(d) for d in deliveries],
            "return_mean": float(returns.mean()), "return_std": float(returns.std()),
            "reward": f"{reward_name(env)} (rware's individual reward)"}
