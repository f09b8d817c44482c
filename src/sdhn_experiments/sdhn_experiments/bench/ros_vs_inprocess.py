"""Does training over ROS learn like training in process? (issue 15)

    ROS_DOMAIN_ID=61 .venv/bin/python scripts/compare_ros_training.py --steps 32768 --seeds 1 2

For each seed, SDHN on maif-tiny (reward ``corrected``, features ``maif-ego/1``) is trained twice
from the same warm start (``--init-from``, default the shipped one-robot actor), each for
exactly ``--steps`` team transitions learned:

- ``inprocess``: ``python -m sdhn_train.cli`` with one environment, ``ppo.rollout_len`` =
  ``--rollout-steps`` and one minibatch: the batch per update the ROS trainer node uses.
- ``ros``: ``python -m sdhn_bringup`` in train mode (simulator node, one sampling actor process
  per robot, trainer node with ``rollout_steps``, ``init_from`` and ``total_steps``); once the
  trainer's status file says the learner has learned ``--steps`` transitions, the launcher is
  stopped. The simulator keeps stepping while the learner updates, so it makes more steps than
  are learned (rollouts the busy learner dropped, and what it made before the stop): the table
  shows both.

Every resulting actor, and the warm start itself, is then evaluated the same way
(``sdhn_policy.deploy_eval``: greedy, NumPy runtime, ``--instances`` training and held-out
instances). Prints a table (success and makespan first, NC when no episode completed, then the
return under the reward named) and writes ``table.md`` and ``results.json`` into ``--out``.
Exit codes: 0 done, 1 a run failed, 2 bad arguments.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from sdhn_experiments.bench import CHECKOUT

REPO = CHECKOUT
ENV, ALGO, REWARD, FEATURES = "maif-tiny", "sdhn", "corrected", "maif-ego/1"
DEFAULT_INIT = REPO / "models/maif-solo-mappo/actor.safetensors"
MODES = ("inprocess", "ros")


@dataclass
class RunResult:
    mode: str  # "init" (the warm start, untrained), "inprocess" or "ros"
    seed: int | None
    steps: int  # transitions learned
    sim_steps: int | None = None  # ros: steps the simulator had made when the learner was done
    wall_s: float = 0.0
    actor: str = ""
    reward: str = REWARD
    eval: dict[str, dict[str, Any]] = field(default_factory=dict)
    notes: str = ""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=32768,
                   help="team transitions each run learns from (a multiple of --rollout-steps)")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2], help="seeds, each >= 0")
    p.add_argument("--rollout-steps", type=int, default=128,
                   help="transitions per update, both modes (the ROS trainer's rollout_steps)")
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    p.add_argument("--init-from", type=Path, default=DEFAULT_INIT,
                   help="exported actor both modes start from")
    p.add_argument("--instances", type=int, default=100,
                   help="evaluation instances 0..k-1 of the training and the held-out set")
    p.add_argument("--out", type=Path, default=None,
                   help="output directory (default runs/compare-ros-<time>; must not exist)")
    p.add_argument("--run-timeout", type=float, default=1800.0,
                   help="seconds one training run may take before it counts as failed")
    args = p.parse_args(argv)
    problems = check_args(args)
    if problems:
        p.error("; ".join(problems))
    return args


def check_args(args: argparse.Namespace) -> list[str]:
    """Every invalid argument, each naming the flag and what is allowed."""
    out = []
    if args.rollout_steps < 2:
        out.append(f"--rollout-steps: {args.rollout_steps}; allowed: an integer >= 2")
    elif args.steps < args.rollout_steps or args.steps % args.rollout_steps:
        out.append(f"--steps: {args.steps}; allowed: a positive multiple of --rollout-steps "
                   f"({args.rollout_steps}), so both modes stop after the same update")
    if any(s < 0 for s in args.seeds) or len(set(args.seeds)) != len(args.seeds):
        out.append(f"--seeds: {args.seeds}; allowed: distinct integers >= 0")
    if not 1 <= args.instances <= 100:
        out.append(f"--instances: {args.instances}; allowed: 1..100")
    if not args.init_from.is_file():
        out.append(f"--init-from: no such file {str(args.init_from)!r}; allowed: an exported "
                   "actor .safetensors")
    if args.out is not None and args.out.exists():
        out.append(f"--out: {args.out} exists; allowed: a new directory")
    if args.run_timeout <= 0:
        out.append(f"--run-timeout: {args.run_timeout}; allowed: > 0")
    return out


# -- the two training modes ----------------------------------------------------------------------


def train_inprocess(args: argparse.Namespace, seed: int, out: Path) -> RunResult:
    name = f"inprocess-s{seed}"
    cmd = [sys.executable, "-m", "sdhn_train.cli", "--env", ENV, "--algo", ALGO,
           "--seed", str(seed), "--total-steps", str(args.steps), "--num-envs", "1",
           "--run-name", name, "--no-progress",
           "--set", f"log.root={out}", "--set", f"ppo.rollout_len={args.rollout_steps}",
           "--set", "ppo.num_minibatches=1", "--set", "eval.interval=0",
           "--set", "log.tensorboard=false", "--set", "log.checkpoint_interval=0",
           "--set", f"env.reward={REWARD}", "--set", f"env.features={FEATURES}",
           "--set", f"actor.init_from={args.init_from.resolve()}"]
    t0 = time.monotonic()
    with (out / f"{name}.log").open("w") as log:
        done = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO,
                              timeout=args.run_timeout, check=False)
    wall = time.monotonic() - t0
    if done.returncode != 0:
        raise RunFailed(f"{name}: train exited {done.returncode} (see {out / name}.log)")
    summary = json.loads((out / name / "summary.json").read_text())
    return RunResult("inprocess", seed, int(summary["global_step"]), None, wall,
                     str(out / name / "actor.safetensors"), str(summary["reward"]))


class RunFailed(RuntimeError):
    pass


def ros_launch_config(args: argparse.Namespace, seed: int, out: Path) -> dict[str, Any]:
    trainer_yaml = out / "ros-trainer.yaml"
    if not trainer_yaml.is_file():  # the in-process config fields the node does not set
        trainer_yaml.write_text(yaml.safe_dump({
            "env": {"reward": REWARD, "features": FEATURES}, "log": {"tensorboard": False}}))
    return {"env": ENV, "mode": "train", "seed": seed, "episodes": 0, "recorder": False,
            "run_dir": str(out / f"ros-s{seed}"),
            "trainer": {"algo": ALGO, "rollout_steps": args.rollout_steps,
                        "init_from": str(args.init_from.resolve()),
                        "total_steps": args.steps, "config": str(trainer_yaml)}}


def train_ros(args: argparse.Namespace, seed: int, out: Path) -> RunResult:
    name = f"ros-s{seed}"
    config = out / f"{name}.yaml"
    config.write_text(yaml.safe_dump(ros_launch_config(args, seed, out), sort_keys=False))
    run_dir = out / name
    status_file = run_dir / "status" / "trainer.status.json"
    t0 = time.monotonic()
    with (out / f"{name}.log").open("w") as log:
        proc = subprocess.Popen([sys.executable, "-m", "sdhn_bringup", str(config)],
                                stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        status: dict[str, Any] = {}
        try:
            while True:
                if proc.poll() is not None:
                    raise RunFailed(f"{name}: the launcher exited {proc.returncode} before the "
                                    f"learner was done (see {out / name}.log)")
                if time.monotonic() - t0 > args.run_timeout:
                    raise RunFailed(f"{name}: not done after {args.run_timeout:.0f} s; last "
                                    f"status {status}")
                status = read_json(status_file) or status
                if int(status.get("transitions_learned", 0)) >= args.steps:
                    break
                time.sleep(1.0)
        finally:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)  # every child stops; exit 0 when all cleanly
                try:
                    proc.wait(timeout=90)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    wall = time.monotonic() - t0
    learned = int(status["transitions_learned"])
    actor = run_dir / "trainer" / "actor.safetensors"
    if learned != args.steps or not actor.is_file():
        raise RunFailed(f"{name}: learned {learned} transitions, expected {args.steps}")
    drops = {k: v for k, v in status.get("dropped", {}).items() if v}
    notes = "; ".join(f"{k}: {v}" for k, v in sorted(drops.items()))
    if proc.returncode != 0:
        notes = f"launcher exit {proc.returncode}; " + notes
    return RunResult("ros", seed, learned, int(status.get("transitions", 0)), wall, str(actor),
                     sim_reward(run_dir), notes=notes)


def read_json(path: Path) -> dict[str, Any] | None:
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def sim_reward(run_dir: Path) -> str:
    """The reward the simulator computed, from its events file ("started" event)."""
    events = run_dir / "status" / "sim-events.jsonl"
    for line in events.read_text().splitlines() if events.is_file() else []:
        event = json.loads(line)
        if event.get("event") == "started":
            return str(event.get("reward", "?"))
    return "?"


# -- the table -----------------------------------------------------------------------------------


def _cell(value: Any, digits: int = 2) -> str:
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def table(results: list[RunResult]) -> str:
    """Markdown: one row per run, success and makespan first, then the return (reward named)."""
    rewards = sorted({r.reward for r in results})
    lines = [f"| mode | seed | steps learned | sim steps | success | held-out success | "
             f"makespan | held-out makespan | return ({'/'.join(rewards)}) | held-out return |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        tr, ho = r.eval.get("train", {}), r.eval.get("heldout", {})
        lines.append(
            f"| {r.mode} | {'—' if r.seed is None else r.seed} | {r.steps:,} | "
            f"{'—' if r.sim_steps is None else f'{r.sim_steps:,}'} | "
            f"{_cell(tr.get('success_rate', '?'))} | {_cell(ho.get('success_rate', '?'))} | "
            f"{_cell(tr.get('makespan', '?'), 1)} | {_cell(ho.get('makespan', '?'), 1)} | "
            f"{_cell(tr.get('return', '?'), 1)} | {_cell(ho.get('return', '?'), 1)} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out = args.out or REPO / "runs" / f"compare-ros-{time.strftime('%Y%m%d-%H%M%S')}"
    out.mkdir(parents=True)
    from sdhn_policy.deploy_eval import evaluate_actor  # after the cheap argument checks

    load = os.getloadavg()[0]
    print(f"[compare] {ENV} {ALGO}, reward {REWARD}, features {FEATURES}, {args.steps} steps "
          f"per run, rollout {args.rollout_steps} x 1 env, seeds {args.seeds}, out {out}; "
          f"load average {load:.1f}", flush=True)
    results = [RunResult("init", None, 0, None, 0.0, str(args.init_from))]
    failed = False
    for seed in args.seeds:
        for mode in args.modes:
            print(f"[compare] training {mode} seed {seed} ...", flush=True)
            try:
                run = (train_inprocess if mode == "inprocess" else train_ros)(args, seed, out)
            except (RunFailed, subprocess.TimeoutExpired) as e:
                print(f"[compare] FAILED: {e}", flush=True)
                failed = True
                continue
            print(f"[compare] {mode} seed {seed}: {run.steps} steps learned in "
                  f"{run.wall_s:.0f} s{f' ({run.notes})' if run.notes else ''}", flush=True)
            results.append(run)
    for r in results:
        r.eval = evaluate_actor(r.actor, ENV, REWARD, args.instances)
        if r.reward != REWARD:
            r.notes = f"trained under reward {r.reward}; " + r.notes
    loads = os.getloadavg()
    text = table(results)
    notes = [f"- {r.mode} seed {r.seed}: {r.notes}" for r in results if r.notes]
    walls = ", ".join(f"{r.mode} s{r.seed} {r.wall_s:.0f} s" for r in results if r.wall_s)
    footer = (f"\n\nGreedy, NumPy runtime, instances 0..{args.instances - 1} of each set; "
              f"makespan over completed episodes (NC: none). Wall time: {walls}. Load average "
              f"at the start {load:.1f}, at the end {loads[0]:.1f} / {loads[1]:.1f} / "
              f"{loads[2]:.1f}.\n" + "\n".join(notes))
    print(text + footer, flush=True)
    (out / "table.md").write_text(text + footer + "\n")
    (out / "results.json").write_text(json.dumps(
        {"args": {k: str(v) for k, v in vars(args).items()}, "load_start": load,
         "load_end": loads, "runs": [asdict(r) for r in results]}, indent=1) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
