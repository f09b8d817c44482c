"""End-to-end training throughput of the in-process trainer: team env-steps/s wall and per
CPU-second, peak RSS, and the split of wall time into env stepping, action selection, critic
(target values + critic forward/backward/step), actor update and periodic greedy evaluation,
per env x algorithm; ``--load K`` runs K busy processes beside it (a shared machine).

    .venv/bin/python scripts/bench_train.py --envs maif-10 maif-20 --algos sdhn mappo
    .venv/bin/python scripts/bench_train.py --envs maif-10 --algos sdhn --load 2 --repeat 3
    .venv/bin/python scripts/bench_train.py --set ppo.fused_gru=false      # the nn.GRU path
    .venv/bin/python scripts/bench_train.py --envs maif-10 --learner-processes 2

Each measurement runs in its own process (so peak RSS is that run's) after one warm-up
iteration. Evaluation is timed once (one ``Trainer.evaluate``, eval.episodes greedy episodes)
and charged at the configured rate: every ``eval.interval`` env-steps, as ``Trainer.run`` does.
Per CPU-second figures are what the process itself needs (on an idle machine with 1 thread they
equal the wall figures); with --repeat, min and median over the repeats are printed. With
``--set ppo.concurrent_actor_critic=true`` the critic and actor-update shares overlap (they run
at the same time), so they sum past 100 % and "other" goes negative. With
``--learner-processes K`` CPU seconds and peak RSS are summed over the K processes and the time
split is rank 0's.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

PARTS = ("env", "act", "critic", "actor_upd", "eval", "other")


def measure(env: str, algo: str, iterations: int, sets: list[str]) -> dict[str, object]:
    """One measurement in this process (the child side)."""
    from sdhn_train.config import Config, set_field, validate
    from sdhn_train.ranks import gather_usage, learner_ranks
    from sdhn_train.trainer import Trainer

    cfg = Config()
    cfg.env.name, cfg.algo.name = env, algo
    cfg.log.tensorboard, cfg.log.progress = False, False
    for item in sets:
        key, value = item.split("=", 1)
        set_field(cfg, key, value)
    validate(cfg)
    run_dir = Path("/tmp/bench_train")
    with learner_ranks(cfg, run_dir) as group:  # train.learner_processes - 1 more processes
        tr = Trainer(cfg, run_dir=run_dir, group=group)
        tr.train_iteration()  # warm-up (allocations, first-call overheads)
        col, lrn = tr.collector.timings, tr.learner.timings
        col.env = col.actor = col.update = 0.0
        for k in lrn:
            lrn[k] = 0.0
        u0 = gather_usage(group)
        step0, t0 = tr.global_step, time.perf_counter()
        for _ in range(iterations):
            tr.train_iteration()
        wall = time.perf_counter() - t0
        u1 = gather_usage(group)  # CPU seconds summed over the data-parallel ranks
        cpu = sum(b.cpu_s - a.cpu_s for a, b in zip(u0, u1, strict=True))
        steps = tr.global_step - step0
        eval_wall = eval_cpu = 0.0
        if tr.eval_env is not None:  # rank 0 alone evaluates
            e0, ec0 = time.perf_counter(), time.process_time()
            tr.evaluate()
            evals = steps / cfg.eval.interval  # evaluations Trainer.run does in `steps` steps
            eval_wall = (time.perf_counter() - e0) * evals
            eval_cpu = (time.process_time() - ec0) * evals
        peak_rss = sum(u.peak_rss_mib for u in gather_usage(group))  # after the evaluation
    wall_all, cpu_all = wall + eval_wall, cpu + eval_cpu
    parts = {"env": col.env, "act": col.actor, "critic": lrn.get("critic", 0.0),
             "actor_upd": lrn.get("actor_update", 0.0), "eval": eval_wall}
    parts["other"] = wall_all - sum(parts.values())
    return {"env": env, "algo": algo, "steps": steps, "threads": cfg.train.threads,
            "learner_processes": cfg.train.learner_processes,
            "steps_per_s": steps / wall_all, "steps_per_cpu_s": steps / cpu_all,
            "train_steps_per_s": steps / wall, "train_steps_per_cpu_s": steps / cpu,
            "peak_rss_mib": peak_rss,  # summed over the data-parallel ranks
            "share": {k: v / wall_all for k, v in parts.items()},
            "hours_per_10M": 1e7 / (steps / wall_all) / 3600}


def start_load(k: int) -> list[subprocess.Popen[bytes]]:
    """K CPU-bound processes (pure-Python spin loops), stopped by ``stop_load``."""
    code = "while True: pass"
    return [subprocess.Popen([sys.executable, "-c", code]) for _ in range(k)]


def stop_load(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        p.terminate()
    for p in procs:
        p.wait()


def run_child(env: str, algo: str, args: argparse.Namespace) -> dict[str, object]:
    cmd = [sys.executable, "-m", "sdhn_experiments.bench.train", "--child", env, algo,
           "--iterations", str(args.iterations)]
    for s in args.set:
        cmd += ["--set", s]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=os.environ).stdout
    row: dict[str, object] = json.loads(out.strip().splitlines()[-1])
    return row


def load_average() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} {five:.2f} {fifteen:.2f} on {os.cpu_count()} CPUs"


def summarise(rows: list[dict[str, object]], load: int) -> dict[str, object]:
    """min / median of the repeats; shares and RSS from the median run (by steps per CPU-s)."""
    def vals(key: str) -> list[float]:
        return [float(r[key]) for r in rows]  # type: ignore[arg-type]

    by_cpu = sorted(rows, key=lambda r: float(r["steps_per_cpu_s"]))  # type: ignore[arg-type]
    mid = by_cpu[len(by_cpu) // 2]
    out = {k: mid[k] for k in ("env", "algo", "threads", "learner_processes", "share",
                               "hours_per_10M")}
    for key in ("steps_per_s", "steps_per_cpu_s", "train_steps_per_s", "train_steps_per_cpu_s"):
        out[key + "_min"], out[key + "_median"] = min(vals(key)), statistics.median(vals(key))
    out["peak_rss_mib"] = max(vals("peak_rss_mib"))
    out["load"], out["repeats"] = load, len(rows)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", nargs="+", default=["maif-10", "maif-20"])
    p.add_argument("--algos", nargs="+", default=["sdhn", "mappo"])
    p.add_argument("--iterations", type=int, default=4,
                   help="measured rollout+update iterations per run (B*T env-steps each)")
    p.add_argument("--repeat", type=int, default=1, help="runs per env x algo (min/median)")
    p.add_argument("--load", type=int, default=0, help="busy processes running beside it")
    p.add_argument("--learner-processes", type=int, default=1,
                   help="train.learner_processes: K data-parallel ranks (CPU "
                        "seconds and peak RSS summed over them)")
    p.add_argument("--set", action="append", default=[],
                   help="config override SECTION.FIELD=V (e.g. train.threads=2)")
    p.add_argument("--json", type=Path, help="also write the results here")
    p.add_argument("--child", nargs=2, metavar=("ENV", "ALGO"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.set = [f"train.learner_processes={args.learner_processes}", *args.set]
    if args.child:
        env, algo = args.child
        print(json.dumps(measure(env, algo, args.iterations, args.set)), flush=True)
        return 0

    print(f"# start: {load_average()}; --load {args.load}; overrides {args.set or 'none'}",
          flush=True)
    load = start_load(args.load)
    rows = []
    try:
        for env in args.envs:
            for algo in args.algos:
                row = summarise([run_child(env, algo, args) for _ in range(args.repeat)],
                                args.load)
                rows.append(row)
                share = row["share"]
                assert isinstance(share, dict)
                shares = " ".join(f"{k}={share[k]:.0%}" for k in PARTS)
                print(f"{env:8s} {algo:6s} K={row['learner_processes']} steps/s wall "
                      f"{row['steps_per_s_median']:7.0f} "
                      f"(min {row['steps_per_s_min']:.0f})  per CPU-s "
                      f"{row['steps_per_cpu_s_median']:7.0f} (min {row['steps_per_cpu_s_min']:.0f})"
                      f"  RSS {row['peak_rss_mib']:.0f} MiB  10M: {row['hours_per_10M']:.2f} h"
                      f"  [{shares}]", flush=True)
    finally:
        stop_load(load)
    print(f"# end: {load_average()}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
