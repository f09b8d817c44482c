"""Learning quality of a speed option at equal env-steps: greedy success, makespan and return on
maif-tiny after the same number of team env-steps, per seed, with and without the option.
One training process at a time (a shared 2-core machine).

    .venv/bin/python scripts/bench_learning.py --steps 65536 --seeds 1 2 3 \
        --variant paper= --variant gen1=sdhn.generator_layers=1

Settings are test/algo/test_learning.py's (16 envs, 100-step episodes, T = 64, 2 minibatches,
reward scale 0.1); --set adds overrides common to every variant. Evaluation: the 16 fixed
instances of eval.seed, one greedy episode each.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path


def run(sets: list[str], seed: int, steps: int, algo: str) -> dict[str, float]:
    from sdhn_train.config import Config, set_field, validate
    from sdhn_train.trainer import Trainer

    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.env.max_steps = "maif-tiny", 16, 100
    cfg.algo.name = algo
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches, cfg.ppo.reward_scale = 64, 2, 0.1
    cfg.train.seed, cfg.train.total_steps = seed, steps
    cfg.eval.interval, cfg.eval.episodes = 1 << 40, 16  # evaluated once, at the end
    cfg.log.tensorboard, cfg.log.progress = False, False
    for item in sets:
        key, value = item.split("=", 1)
        set_field(cfg, key, value)
    validate(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        tr = Trainer(cfg, run_dir=Path(tmp))
        c0 = time.process_time()
        while tr.global_step < steps:
            tr.train_iteration()
        cpu = time.process_time() - c0
        result = tr.evaluate()
    return {"success": result["eval/success_rate"],
            "makespan": result.get("eval/makespan", float("nan")),
            "return": result["eval/episodic_return"], "cpu_s": cpu}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=65_536)
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    p.add_argument("--algo", default="sdhn")
    p.add_argument("--variant", action="append", required=True,
                   help="NAME=[FIELD=V,FIELD=V...] (empty = the defaults)")
    p.add_argument("--set", action="append", default=[], help="override for every variant")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    rows = []
    for spec in args.variant:
        name, _, rest = spec.partition("=")
        sets = args.set + [s for s in rest.split(",") if s]
        per_seed = [run(sets, seed, args.steps, args.algo) for seed in args.seeds]
        row = {"variant": name, "sets": sets, "seeds": args.seeds, "per_seed": per_seed}
        rows.append(row)
        fmt = " ".join(f"s{sd}: succ {r['success']:.2f} mk {r['makespan']:.1f} ret "
                       f"{r['return']:.1f}" for sd, r in zip(args.seeds, per_seed, strict=True))
        mean_ret = statistics.mean(r["return"] for r in per_seed)
        mean_succ = statistics.mean(r["success"] for r in per_seed)
        cpu = statistics.mean(r["cpu_s"] for r in per_seed)
        print(f"{name:10s} success {mean_succ:.2f} return {mean_ret:6.1f}  [{fmt}]  "
              f"{args.steps / cpu:.0f} steps/CPU-s", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
