"""Scripted MAIF baselines on the training and the held-out instance sets.

    .venv/bin/python scripts/eval_scripted.py maif-tiny [--instances 100] [--seed 0]

Prints, per instance set, success rate and mean makespan (over completed episodes; NC when none
completed) of the decentralised greedy policy and of the centralised prioritized planner, next to
the lower bound (mean over instances of the longest single-robot shortest path), and the return
under the named reward (second). See ``sdhn_sim.envs.maif_scripted``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

from sdhn_sim.envs.maif_scripted import evaluate_scripted


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
            t0 = time.perf_counter()
            r = evaluate_scripted(args.env, which, policy, instances=args.instances,
                                  seed=args.seed, reward=args.reward)
            wall = time.perf_counter() - t0
            if args.json:
                print(json.dumps({**dataclasses.asdict(r), "wall_s": round(wall, 1)}), flush=True)
                continue
            ms = "NC" if r.makespan is None else f"{r.makespan:.1f}"
            print(f"{r.task:10s} {which:8s} {policy:8s} success {r.success_rate:.2f}  "
                  f"makespan {ms:>5s}  (lower bound {r.lower_bound:.1f})  "
                  f"return {r.episode_return:.1f} ({r.reward})  collisions {r.collisions:.1f}  "
                  f"[{wall:.1f} s]", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
