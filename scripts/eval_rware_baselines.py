#!/usr/bin/env python3
"""RWARE baselines: deliveries and return per episode of a random and a scripted policy.

    .venv/bin/python scripts/eval_rware_baselines.py [rware-3 rware-6 rware-9] [--episodes 10]

One episode (500 steps, rware's limit) from each of the seeds ``--seed .. --seed+episodes-1``;
prints mean ± std (population std over those episodes) of the requested shelves delivered and of
the return under rware's own reward (individual: +1 to the robot on the goal per delivery, so the
two agree). ``scripted`` is the centralised fetch-deliver-return heuristic of
``sdhn_sim.envs.rware_scripted``; ``random`` draws the 5 actions uniformly.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings

import numpy as np

from sdhn_sim.envs import make_env
from sdhn_sim.envs.api import reward_name
from sdhn_sim.envs.rware_env import RwareEnv
from sdhn_sim.envs.rware_scripted import RandomPolicy, ScriptedPolicy, run_episodes

POLICIES = {"random": RandomPolicy, "scripted": ScriptedPolicy}


def evaluate(name: str, policy: str, *, episodes: int, seed: int) -> dict[str, object]:
    env = make_env(name, num_envs=episodes, seed=seed)
    assert isinstance(env, RwareEnv)
    t0 = time.perf_counter()
    eps = run_episodes(env, POLICIES[policy](seed), seed=seed)
    wall = time.perf_counter() - t0
    deliveries = np.array([e.deliveries for e in eps], dtype=float)
    returns = np.array([e.episode_return for e in eps])
    return {"env": name, "policy": policy, "episodes": len(eps),
            "seeds": f"{seed}..{seed + episodes - 1}",
            "deliveries_mean": float(deliveries.mean()), "deliveries_std": float(deliveries.std()),
            "return_mean": float(returns.mean()), "return_std": float(returns.std()),
            "reward": f"{reward_name(env)} (rware's individual reward)", "wall_s": round(wall, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("envs", nargs="*", default=["rware-3"], help="RWARE tasks (default rware-3)")
    p.add_argument("--episodes", type=int, default=10, help="one episode per seed")
    p.add_argument("--seed", type=int, default=0, help="first seed")
    p.add_argument("--policies", default="random,scripted")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    # rware 2.0.0 returns its rewards as a list, which gymnasium's checker warns about
    warnings.filterwarnings("ignore", message=".*reward returned by")
    for name in args.envs:
        for policy in args.policies.split(","):
            r = evaluate(name, policy, episodes=args.episodes, seed=args.seed)
            if args.json:
                print(json.dumps(r), flush=True)
                continue
            print(f"{name:8s} {policy:8s} deliveries {r['deliveries_mean']:5.1f} ± "
                  f"{r['deliveries_std']:4.1f}  return {r['return_mean']:5.1f} ± "
                  f"{r['return_std']:4.1f} ({r['reward']})  seeds {r['seeds']}  "
                  f"[{r['wall_s']} s]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
