"""Train MAIF through a team-size curriculum, each stage warm-started from the previous actor.

    .venv/bin/python scripts/train_curriculum.py --algo sdhn --seed 1 --out runs/curriculum
    .venv/bin/python scripts/train_curriculum.py --stages maif-solo:100000,maif-tiny:300000

Every MAIF team size shares the 57-float observation and the ``maif-ego/1`` features, so the
actor of one stage starts the next (``actor.init_from``); each critic starts fresh. From scratch
on maif-tiny every method first learns to wait (success 0 for ~300k steps; MAPPO still 0 at
600k); from a one-robot actor that plateau is skipped.

Re-running the same command continues: a finished stage is skipped only if it was trained with
exactly this stage's spec (env, algo, seed, steps, warm start, ``--set`` options; recorded in
its ``curriculum_stage.json``), an interrupted stage with that spec resumes from its last
checkpoint, and a stage directory trained otherwise is refused (one line, exit 2): use another
``--out``. Extra ``--set`` options go to every stage.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

DEFAULT_STAGES = "maif-solo:100000,maif-tiny:600000,maif-10:2000000"
SOLO = ["--set", "env.num_envs=16", "--set", "ppo.rollout_len=64",
        "--set", "ppo.num_minibatches=2", "--set", "env.max_steps=100"]
STAGE_SPEC = "curriculum_stage.json"  # in each stage's run directory: what it was asked to be


class CurriculumError(ValueError):
    """Bad arguments or a stage directory trained differently; one line, exit 2."""


@dataclass(frozen=True)
class Stage:
    env: str
    algo: str
    seed: int
    total_steps: int
    init_from: str | None  # the previous stage's actor
    flags: tuple[str, ...]  # every other trainer flag (--set ...), in order

    @property
    def name(self) -> str:
        return f"{self.env}__{self.algo}__{self.seed}"

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "flags": list(self.flags)}


def parse_stages(text: str) -> list[tuple[str, int]]:
    """``ENV:STEPS,...`` -> [(env, steps)]; every env a MAIF env (they share the observation the
    warm start relies on), every STEPS an integer >= 1."""
    from sdhn_sim.envs.registry import env_names

    maif = [e for e in env_names() if e.startswith("maif")]
    out = []
    for item in text.split(","):
        env, sep, steps = item.strip().partition(":")
        if not sep or not re.fullmatch(r"[0-9]+", steps.strip()) or int(steps) < 1:
            raise CurriculumError(f"--stages {item!r}: expected ENV:STEPS with STEPS an integer "
                                  ">= 1, e.g. maif-solo:100000")
        if env.strip() not in maif:
            raise CurriculumError(f"--stages {item!r}: env {env.strip()!r}; allowed: "
                                  f"{', '.join(maif)}")
        out.append((env.strip(), int(steps)))
    return out


def stage_state(stage: Stage, run_dir: Path) -> str:
    """'done' (finished with exactly this spec), 'resume' (started with this spec), 'new';
    CurriculumError if the directory holds a stage trained with another spec (other steps,
    --set options, warm start) or one whose spec is unknown."""
    if not run_dir.exists():
        return "new"
    spec_file = run_dir / STAGE_SPEC
    try:
        recorded = json.loads(spec_file.read_bytes()) if spec_file.is_file() else None
    except ValueError:
        recorded = "unreadable"
    started = any((run_dir / f).exists() for f in ("checkpoints", "summary.json", "metrics.csv",
                                                     "actor.safetensors"))
    if recorded is None and not started:
        return "new"
    if recorded != stage.to_json():
        diff = ("no recorded stage spec" if recorded is None else "an unreadable stage spec"
                if recorded == "unreadable" else ", ".join(
                    f"{k}: {recorded.get(k)!r} there, {v!r} now"
                    for k, v in stage.to_json().items() if recorded.get(k) != v))
        raise CurriculumError(f"stage {stage.name}: {run_dir} holds a stage trained otherwise "
                              f"({diff}); use another --out or delete {run_dir}")
    done = (run_dir / "summary.json").is_file() and (run_dir / "actor.safetensors").is_file()
    return "done" if done else "resume" if started else "new"


def main(argv: list[str] | None = None) -> int:
    from sdhn_train.algorithms.registry import ALGO_NAMES

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algo", default="sdhn", choices=ALGO_NAMES)
    p.add_argument("--seed", default=1, type=int)
    p.add_argument("--out", type=Path, default=Path("runs/curriculum"))
    p.add_argument("--stages", default=DEFAULT_STAGES, help="ENV:STEPS,... in order")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE")
    args = p.parse_args(argv)
    try:
        if args.seed < 0:
            raise CurriculumError(f"--seed {args.seed}: allowed: an integer >= 0")
        return run_curriculum(args)
    except CurriculumError as e:
        print(f"train_curriculum: {e}", file=sys.stderr)
        return 2


def run_curriculum(args: argparse.Namespace) -> int:
    previous: Path | None = None
    for env, steps in parse_stages(args.stages):
        algo = "mappo" if env == "maif-solo" else args.algo  # one robot: the critic is moot
        flags = [*(SOLO if env == "maif-solo" else []),
                 *(x for item in args.set for x in ("--set", item))]
        stage = Stage(env, algo, args.seed, steps, None if previous is None else str(previous),
                      tuple(flags))
        run_dir = args.out / stage.name
        actor = run_dir / "actor.safetensors"
        state = stage_state(stage, run_dir)
        if state == "done":
            print(f"[curriculum] {stage.name}: done, skipped", flush=True)
            previous = actor
            continue
        cmd = [sys.executable, "-m", "sdhn_train.cli", "--no-progress", "--env", env,
               "--algo", algo, "--seed", str(args.seed), "--total-steps", str(steps),
               "--set", f"log.root={args.out}", "--run-name", stage.name,
               "--set", "env.instance_set=large", *flags]
        if previous is not None:
            cmd += ["--set", f"actor.init_from={previous}"]
        if state == "resume" and any((run_dir / "checkpoints").glob("*.json")):
            cmd += ["--resume", str(run_dir)]  # same flags: the config is not in the checkpoint
        run_dir.mkdir(parents=True, exist_ok=True)
        tmp = run_dir / (STAGE_SPEC + ".tmp")
        tmp.write_text(json.dumps(stage.to_json(), indent=1))
        tmp.replace(run_dir / STAGE_SPEC)
        print(f"[curriculum] {stage.name}: {' '.join(cmd[1:])}", flush=True)
        rc = subprocess.call(cmd)
        if rc != 0:
            print(f"[curriculum] {stage.name} failed with exit code {rc}", file=sys.stderr)
            return rc
        previous = actor
    return 0


if __name__ == "__main__":
    sys.exit(main())
