#!/usr/bin/env python3
"""End-to-end training throughput: team env-steps/s (rollouts + PPO updates) per env x algorithm,
and the share of wall time spent in env stepping, actor forward (acting), critic (target values
+ critic forward/backward/step) and the actor's PPO update.

    .venv/bin/python scripts/bench_train.py \
        --envs maif-10 maif-20 --algos sdhn mappo --iterations 3
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from sdhn_train.config import Config, set_field, validate
from sdhn_train.trainer import Trainer


def bench(env: str, algo: str, iterations: int, sets: list[str], threads: int) -> dict[str, float]:
    cfg = Config()
    cfg.env.name, cfg.algo.name = env, algo
    cfg.eval.interval, cfg.log.tensorboard, cfg.log.progress = 0, False, False
    cfg.train.threads = threads
    for item in sets:
        key, value = item.split("=", 1)
        set_field(cfg, key, value)
    validate(cfg)
    tr = Trainer(cfg, run_dir=Path("/tmp/bench_train"))
    tr.train_iteration()  # warm-up (allocations, first-call overheads)
    col, lrn = tr.collector.timings, tr.learner.timings
    col.env = col.actor = col.update = 0.0
    lrn["critic"] = lrn["actor_update"] = 0.0
    step0, t0, c0 = tr.global_step, time.perf_counter(), time.process_time()
    for _ in range(iterations):
        tr.train_iteration()
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    steps = tr.global_step - step0
    parts = {"env": col.env, "actor_forward": col.actor, "critic": lrn["critic"],
             "actor_update": lrn["actor_update"]}
    parts["other"] = wall - sum(parts.values())
    # On a shared machine wall time includes waiting for a core; CPU time says what the
    # process itself needs (== wall time on an idle machine with --threads 1).
    return {"env_name": env, "algo": algo, "team_steps_per_s": steps / wall,  # type: ignore[dict-item]
            "team_steps_per_cpu_s": steps / cpu,
            **{f"share_{k}": v / wall for k, v in parts.items()},
            "hours_per_10M": 1e7 / (steps / wall) / 3600}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", nargs="+", default=["maif-10", "maif-20"])
    p.add_argument("--algos", nargs="+", default=["sdhn", "mappo"])
    p.add_argument("--iterations", type=int, default=3, help="measured rollout+update iterations")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--set", action="append", default=[], help="config override SECTION.FIELD=V")
    p.add_argument("--json", type=Path, help="also write the results here")
    args = p.parse_args(argv)
    rows = []
    for env in args.envs:
        for algo in args.algos:
            row = bench(env, algo, args.iterations, args.set, args.threads)
            rows.append(row)
            shares = " ".join(f"{k[6:]}={v:.0%}" for k, v in row.items() if k.startswith("share_"))
            print(f"{env:8s} {algo:6s} {row['team_steps_per_s']:8.0f} team-steps/s wall, "
                  f"{row['team_steps_per_cpu_s']:8.0f} per CPU-s  "
                  f"10M steps: {row['hours_per_10M']:.2f} h  {shares}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
