#!/usr/bin/env python3
"""RWARE env-steps per second: the real ``rware`` package vs the NumPy batched env, side by side.

    nice -n 10 .venv/bin/python scripts/bench_rware.py [--robots 3 9] [--batch 1 32 64]
        [--seconds 3] [--json]

For each team size and batch size B, both backends (``rware``: B real warehouses stepped in a
loop behind the adapter; ``batched``: ``RwareBatchedEnv``) step uniformly random actions for
about ``--seconds`` of wall time each, on rware-small (the rware-N tasks' warehouse), auto-reset
included. Prints env-steps/s (B x batched steps per second), the ratio batched/rware and the
load average around each measurement (the machine is shared: compare ratios, not absolutes).
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


def env_steps_per_s(env: RwareEnv | RwareBatchedEnv, seconds: float, seed: int = 0) -> float:
    """Batched steps of random actions for ~``seconds`` of CPU time; env-steps per CPU second
    (process time, so other processes on a shared machine distort less)."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    acts = rng.integers(0, 5, size=(256, env.num_envs, env.num_robots), dtype=np.int64)
    steps = 0
    t0 = time.process_time()
    while True:
        for k in range(16):
            env.step(acts[(steps + k) % 256])
        steps += 16
        dt = time.process_time() - t0
        if dt >= seconds:
            return steps * env.num_envs / dt


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", type=int, nargs="+", default=[3, 9])
    p.add_argument("--batch", type=int, nargs="+", default=[1, 32, 64])
    p.add_argument("--seconds", type=float, default=3.0, help="CPU seconds per measurement")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    args = p.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*reward returned by")
    if not args.json:
        print(f"{'robots':>6} {'B':>4} {'rware/s':>10} {'batched/s':>10} {'ratio':>7}  load avg")
    for n in args.robots:
        for b in args.batch:
            load0 = os.getloadavg()[0]
            real = env_steps_per_s(RwareEnv(n, num_envs=b), args.seconds)
            fast = env_steps_per_s(RwareBatchedEnv(n, num_envs=b), args.seconds)
            load = (load0 + os.getloadavg()[0]) / 2
            row = {"robots": n, "B": b, "rware_steps_per_s": round(real),
                   "batched_steps_per_s": round(fast), "ratio": round(fast / real, 1),
                   "load_avg_1min": round(load, 2)}
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"{n:>6} {b:>4} {real:>10.0f} {fast:>10.0f} {fast / real:>6.1f}x  "
                      f"{load:.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
