#!/usr/bin/env python3
"""Scripted MAIF baselines on the training and the held-out instance sets.

    .venv/bin/python scripts/eval_scripted.py maif-tiny [--instances 100] [--seed 0]

Prints, per instance set, success rate and mean makespan (over completed episodes; NC when none
completed) of the decentralised greedy policy and of the centralised prioritized planner, next to
the lower bound (mean over instances of the longest single-robot shortest path), and the return
under the named reward (second). See ``sdhn_sim.envs.maif_scripted``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from sdhn_sim.envs import make_env
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_scripted import GreedyPolicy, PlannerPolicy, lower_bound, run_episodes


def evaluate(name: str, which: str, policy: str, *, instances: int, seed: int,
             reward: str) -> dict[str, object]:
    env = make_env(name, num_envs=instances, seed=seed, instance_order="round_robin",
                   instance_ids=list(range(instances)), instance_set=which, reward=reward)
    assert isinstance(env, MaifEnv)
    pol = GreedyPolicy(seed) if policy == "greedy" else PlannerPolicy(seed)
    t0 = time.perf_counter()
    eps = run_episodes(env, pol, seed=seed)
    wall = time.perf_counter() - t0
    env.reset(seed=seed)
    done = [e.makespan for e in eps if e.makespan is not None]
    return {"env": name, "set": which, "policy": policy,
            "success_rate": float(np.mean([e.success for e in eps])),
            "makespan": float(np.mean(done)) if done else "NC",
            "lower_bound": lower_bound(env), "return": float(np.mean([e.episode_return
                                                                      for e in eps])),
            "reward": reward, "collisions": float(np.mean([e.collisions for e in eps])),
            "wall_s": round(wall, 1)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("env", help="a MAIF config, e.g. maif-tiny, maif-10")
    p.add_argument("--instances", type=int, default=100, help="instances 0..k-1 of each set")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--reward", default="corrected", choices=["corrected", "reference"])
    p.add_argument("--policies", default="greedy,planner")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    for which in ("train", "heldout"):
        for policy in args.policies.split(","):
            r = evaluate(args.env, which, policy, instances=args.instances, seed=args.seed,
                         reward=args.reward)
            if args.json:
                print(json.dumps(r), flush=True)
                continue
            ms = r["makespan"]
            ms_s = ms if isinstance(ms, str) else f"{ms:.1f}"
            print(f"{r['env']:10s} {which:8s} {policy:8s} success {r['success_rate']:.2f}  "
                  f"makespan {ms_s:>5s}  (lower bound {r['lower_bound']:.1f})  "
                  f"return {r['return']:.1f} ({args.reward})  collisions {r['collisions']:.1f}  "
                  f"[{r['wall_s']} s]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
