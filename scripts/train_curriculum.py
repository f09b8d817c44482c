#!/usr/bin/env python3
"""Train MAIF through a team-size curriculum, each stage warm-started from the previous actor.

    .venv/bin/python scripts/train_curriculum.py --algo sdhn --seed 1 --out runs/curriculum
    .venv/bin/python scripts/train_curriculum.py --stages maif-solo:100000,maif-tiny:300000

Every MAIF team size shares the 57-float observation and the ``maif-ego/1`` features, so the
actor of one stage starts the next (``actor.init_from``); each critic starts fresh. From scratch
on maif-tiny every method first learns to wait (success 0 for ~300k steps; MAPPO still 0 at
600k); from a one-robot actor that plateau is skipped.

Re-running the same command continues: finished stages (``summary.json``) are skipped, an
interrupted stage resumes from its last checkpoint. Extra ``--set`` options go to every stage.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

DEFAULT_STAGES = "maif-solo:100000,maif-tiny:600000,maif-10:2000000"
SOLO = ["--set", "env.num_envs=16", "--set", "ppo.rollout_len=64",
        "--set", "ppo.num_minibatches=2", "--set", "env.max_steps=100"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algo", default="sdhn")
    p.add_argument("--seed", default="1")
    p.add_argument("--out", type=Path, default=Path("runs/curriculum"))
    p.add_argument("--stages", default=DEFAULT_STAGES, help="ENV:STEPS,... in order")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE")
    args = p.parse_args(argv)
    previous: Path | None = None
    for stage in args.stages.split(","):
        env, steps = stage.split(":")
        algo = "mappo" if env == "maif-solo" else args.algo  # one robot: the critic is moot
        name = f"{env}__{algo}__{args.seed}"
        run_dir = args.out / name
        actor = run_dir / "actor.safetensors"
        if (run_dir / "summary.json").exists() and actor.exists():
            print(f"[curriculum] {name}: done, skipped", flush=True)
            previous = actor
            continue
        cmd = [sys.executable, "-m", "sdhn_train.cli", "--no-progress", "--env", env,
               "--algo", algo, "--seed", args.seed, "--total-steps", steps,
               "--set", f"log.root={args.out}", "--run-name", name,
               "--set", "env.instance_set=large"]
        cmd += SOLO if env == "maif-solo" else []
        if previous is not None:
            cmd += ["--set", f"actor.init_from={previous}"]
        for item in args.set:
            cmd += ["--set", item]
        if (run_dir / "checkpoints").is_dir() and any((run_dir / "checkpoints").glob("*.json")):
            cmd += ["--resume", str(run_dir)]  # same flags: the config is not in the checkpoint
        print(f"[curriculum] {name}: {' '.join(cmd[1:])}", flush=True)
        rc = subprocess.call(cmd)
        if rc != 0:
            print(f"[curriculum] {name} failed with exit code {rc}", file=sys.stderr)
            return rc
        previous = actor
    return 0


if __name__ == "__main__":
    sys.exit(main())
