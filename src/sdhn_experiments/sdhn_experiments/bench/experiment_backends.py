"""Runs/hour and scheduling overhead per run of run_experiments' backends (issue 18): the same
tiny 2-method x 2-seed suite (``SUITE`` below, which test/baselines/test_experiments_ray.py
runs too) with --backend local (--jobs 2) and --backend ray (a local Ray with 2 CPUs, its
start included).

    .venv/bin/python scripts/bench_experiment_backends.py [--runs-dir /tmp/bench]

Overhead per run = (suite wall x 2 slots - sum of the runs' own training walls) / runs.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from sdhn_experiments.experiments import DONE, load_suite, run_suite

SUITE = """
name: ray
methods:
  sdhn: {algo: sdhn}
  mappo: {algo: mappo}
tasks:
  maif-tiny: {env.max_steps: 40}
seeds: [1, 2]
budgets:
  tiny:
    set:
      train.total_steps: 384
      env.num_envs: 4
      ppo.rollout_len: 32
      ppo.num_minibatches: 2
      eval.interval: 192
      eval.episodes: 2
      log.checkpoint_interval: 128
      log.tensorboard: false
"""
"""The tiny suite both backends run here, and the Ray test too."""


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs-dir", type=Path, default=None)
    args = p.parse_args(argv)
    tmp = args.runs_dir or Path(tempfile.mkdtemp(prefix="bench_backends_"))
    tmp.mkdir(parents=True, exist_ok=True)
    suite = tmp / "suite.yaml"
    suite.write_text(SUITE)
    runs = load_suite(suite, "tiny")
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    for backend in ("local", "ray"):
        logdir = tmp / backend
        t0 = time.perf_counter()
        if backend == "ray":
            from sdhn_experiments.ray_backend import run_suite_ray
            counts = run_suite_ray(runs, logdir, num_cpus=2, out=io.StringIO())
        else:
            counts = run_suite(runs, logdir, jobs=2, out=io.StringIO())
        wall = time.perf_counter() - t0
        assert counts["done"] == len(runs), counts
        run_walls = [json.loads((logdir / r.name / DONE).read_text())["wall_seconds"]
                     for r in runs]
        overhead = (wall * 2 - sum(run_walls)) / len(runs)
        print(f"{backend}: {len(runs)} runs in {wall:.1f}s = {len(runs) / wall * 3600:.0f} "
              f"runs/h; mean run {sum(run_walls) / len(runs):.1f}s; overhead/run "
              f"{overhead:.1f}s; load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
