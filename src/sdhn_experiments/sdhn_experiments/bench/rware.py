"""RWARE env-steps per second: the real ``rware`` package vs the NumPy batched env, side by side.

    nice -n 10 .venv/bin/python scripts/bench_rware.py [--robots 3 9] [--batch 1 32 64]
        [--seconds 3] [--forward 0.2] [--json]

For each team size and batch size B, both backends (``rware``: B real warehouses stepped in a
loop behind the adapter; ``batched``: ``RwareBatchedEnv``) step random actions (FORWARD with
probability ``--forward``, the other four equally likely; 0.2 = uniform) for about ``--seconds``
of CPU time each, on rware-small (the rware-N tasks' warehouse), auto-reset included. Prints
env-steps per CPU-second (B x batched steps), the ratio batched/rware, the share of env-steps
whose move conflicts the batched env handed to networkx (equally deep chains into one cell;
more FORWARD, more of them) and the load average around each measurement (the machine is
shared: compare ratios, not absolutes).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

import numpy as np

from sdhn_sim.envs.rware_batched import RwareBatchedEnv
from sdhn_sim.envs.rware_env import RwareEnv


def env_steps_per_s(env: RwareEnv | RwareBatchedEnv, seconds: float, forward: float,
                    seed: int = 0) -> tuple[float, int]:
    """Batched steps of random actions for ~``seconds`` of CPU time; (env-steps per CPU second
    (process time, so other processes on a shared machine distort less), env-steps taken)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    other = (1.0 - forward) / 4
    acts = rng.choice(5, size=(256, env.num_envs, env.num_robots),
                      p=[other, forward, other, other, other]).astype(np.int64)
    steps = 0
    t0 = time.process_time()
    while True:
        for k in range(16):
            env.step(acts[(steps + k) % 256])
        steps += 16
        dt = time.process_time() - t0
        if dt >= seconds:
            return steps * env.num_envs / dt, steps * env.num_envs


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, nargs="+", default=[3, 9])
    p.add_argument("--batch", type=int, nargs="+", default=[1, 32, 64])
    p.add_argument("--seconds", type=float, default=3.0, help="CPU seconds per measurement")
    p.add_argument("--forward", type=float, default=0.2,
                   help="probability of FORWARD (0.2 = uniform over the 5 actions)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    if not 0.0 <= args.forward <= 1.0:
        print(f"--forward must be in [0, 1], got {args.forward}", file=sys.stderr)
        return 2
    warnings.filterwarnings("ignore", message=".*reward returned by")
    if not args.json:
        print(f"{'robots':>6} {'B':>4} {'rware/s':>10} {'batched/s':>10} {'ratio':>7} "
              f"{'ties':>6}  load avg")
    for n in args.robots:
        for b in args.batch:
            load0 = os.getloadavg()[0]
            real, _ = env_steps_per_s(RwareEnv(n, num_envs=b), args.seconds, args.forward)
            batched = RwareBatchedEnv(n, num_envs=b)
            fast, taken = env_steps_per_s(batched, args.seconds, args.forward)
            ties = batched.ties_resolved_by_networkx / taken
            load = (load0 + os.getloadavg()[0]) / 2
            row = {"robots": n, "B": b, "forward": args.forward, "rware_steps_per_s": round(real),
                   "batched_steps_per_s": round(fast), "ratio": round(fast / real, 1),
                   "networkx_tie_share": round(ties, 4), "load_avg_1min": round(load, 2)}
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"{n:>6} {b:>4} {real:>10.0f} {fast:>10.0f} {fast / real:>6.1f}x "
                      f"{ties:>6.2%}  {load:.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
