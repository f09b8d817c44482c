"""Experiment runner: a suite (methods x tasks x seeds, with a named budget) run as separate
training processes, several at once, resumable.

    run_experiments configs/suites/paper.yaml --budget quick --logdir runs/paper-quick --jobs 2
    run_experiments configs/suites/paper.yaml --budget paper --logdir /shared/paper \\
        --backend ray --address HEAD:6379   # one Ray task per run: analysis/ray_backend.py

Suite YAML (see ``configs/suites/paper.yaml``)::

    name: paper
    methods:                       # method label -> algorithm + config overrides
      sdhn: {algo: sdhn}
      sdhn_wo_lsk: {algo: sdhn, set: {sdhn.skew_loss: false}}
    tasks:                         # task (env name) -> overrides for that task ({} = none)
      maif-10: {}
    experiments:                   # which methods run on which tasks (a group may name its
      - {methods: [sdhn, sdhn_wo_lsk], tasks: [maif-10]}  # own seeds: seeds: [1, ..., 10])
    seeds: [1, 2, 3]
    budgets:                       # --budget NAME: overrides for every run (+ optional seeds)
      quick: {seeds: [1], set: {train.total_steps: 2048}}
      paper: {set: {train.total_steps: 2000000}}

Every run gets ``LOGDIR/<task>__<method>__s<seed>/`` with ``run.json`` (its spec), the trainer's
``config.yaml``, ``metrics.csv``, checkpoints, ``train.log`` and, once finished, the completion
marker ``DONE.json``. A rerun skips runs with the marker; an interrupted run resumes from its
latest checkpoint (``metrics.csv`` cut back to that step, so the finished log equals an
uninterrupted one) or, without a checkpoint, starts again from scratch. A run directory whose
``run.json`` differs from the suite's spec (other budget, other overrides) is an error, never
silently mixed.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import yaml

from sdhn_sim.envs.registry import env_names
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.checkpoint import latest_checkpoint
from sdhn_train.config import Config, ConfigError, set_field, validate
from sdhn_train.evaluation import headline
from sdhn_train.runs import PH_DIR

DONE = "DONE.json"
SPEC = "run.json"


class ExperimentError(ValueError):
    """A bad suite file or a log directory that does not match the suite."""


@dataclass(frozen=True)
class RunSpec:
    suite: str
    budget: str
    method: str
    task: str
    seed: int
    algo: str
    overrides: dict[str, Any] = field(default_factory=dict)  # "section.field" -> value

    @property
    def name(self) -> str:
        return f"{self.task}__{self.method}__s{self.seed}"

    def to_json(self) -> dict[str, Any]:
        return {"suite": self.suite, "budget": self.budget, "method": self.method,
                "task": self.task, "seed": self.seed, "algo": self.algo,
                "overrides": self.overrides}

    def config(self, logdir: Path) -> Config:
        cfg = Config()
        for key, value in self.overrides.items():
            set_field(cfg, key, value)
        cfg.env.name, cfg.algo.name, cfg.train.seed = self.task, self.algo, self.seed
        cfg.log.root, cfg.log.run_name, cfg.log.progress = str(logdir), self.name, False
        validate(cfg)
        return cfg


def _mapping(data: Any, where: str) -> dict[str, Any]:
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ExperimentError(f"{where}: expected a mapping, got {data!r}")
    return data


def load_suite(path: str | Path, budget: str) -> list[RunSpec]:
    """The runs of suite ``path`` under budget ``budget``, in a stable order (seed-major, so a
    partial suite has every method on every task before more seeds)."""
    path = Path(path)
    data = _mapping(yaml.safe_load(path.read_text()), str(path))
    name = str(data.get("name", path.stem))
    methods = _mapping(data.get("methods"), f"{path}: methods")
    tasks = _mapping(data.get("tasks"), f"{path}: tasks")
    budgets = _mapping(data.get("budgets"), f"{path}: budgets")
    if budget not in budgets:
        raise ExperimentError(f"--budget {budget!r}: {path} defines {', '.join(budgets) or 'none'}")
    b = _mapping(budgets[budget], f"{path}: budgets.{budget}")
    seeds = b.get("seeds", data.get("seeds", [1]))
    if not isinstance(seeds, list) or not all(isinstance(s, int) for s in seeds) or not seeds:
        raise ExperimentError(f"{path}: seeds must be a non-empty list of integers, got {seeds!r}")
    for m, spec in methods.items():
        algo = _mapping(spec, f"{path}: methods.{m}").get("algo")
        if algo not in ALGO_NAMES:
            raise ExperimentError(f"{path}: methods.{m}.algo = {algo!r}; allowed: "
                                  f"{', '.join(ALGO_NAMES)}")
    for t in tasks:
        if t not in env_names():
            raise ExperimentError(f"{path}: task {t!r}; allowed: {', '.join(env_names())}")
    groups = data.get("experiments") or [{"methods": list(methods), "tasks": list(tasks)}]
    pairs: list[tuple[str, str]] = []
    group_seeds: dict[tuple[str, str], list[int]] = {}  # a group's own seeds (protocol suites)
    for i, group in enumerate(groups):
        g = _mapping(group, f"{path}: experiments[{i}]")
        gs = g.get("seeds", seeds)
        if not isinstance(gs, list) or not all(isinstance(x, int) for x in gs) or not gs:
            raise ExperimentError(f"{path}: experiments[{i}].seeds must be a non-empty list of "
                                  f"integers, got {gs!r}")
        if "seeds" in b:  # a budget's seeds (e.g. a quick check's one seed) win
            gs = seeds
        for t in g.get("tasks", []):
            for m in g.get("methods", []):
                if m not in methods:
                    raise ExperimentError(f"{path}: experiments[{i}] names method {m!r}, "
                                          f"not in methods ({', '.join(methods)})")
                if t not in tasks:
                    raise ExperimentError(f"{path}: experiments[{i}] names task {t!r}, "
                                          f"not in tasks ({', '.join(tasks)})")
                if (t, m) not in pairs:
                    pairs.append((t, m))
                group_seeds[(t, m)] = sorted(set(group_seeds.get((t, m), [])) | set(gs))
    runs = []
    for seed in sorted({x for v in group_seeds.values() for x in v}, key=_seed_order(seeds)):
        for t, m in pairs:
            if seed not in group_seeds[(t, m)]:
                continue
            overrides = {**_mapping(b.get("set"), f"budgets.{budget}.set"),
                         **_mapping(tasks[t], f"tasks.{t}"),
                         **_mapping(methods[m].get("set"), f"methods.{m}.set")}
            run = RunSpec(name, budget, m, t, int(seed), methods[m]["algo"],
                          {k: overrides[k] for k in sorted(overrides)})
            try:
                run.config(Path("."))
            except ConfigError as e:
                raise ExperimentError(f"{path}: run {run.name}: {e}") from e
            runs.append(run)
    return runs


def _seed_order(seeds: list[int]) -> Any:
    """Sort key: the suite's seeds in their listed order, then any others ascending."""
    pos = {x: i for i, x in enumerate(seeds)}
    return lambda x: (pos.get(x, len(pos)), x)


# --- one run ----------------------------------------------------------------------------------


def run_state(run: RunSpec, logdir: Path) -> str:
    """'done', 'partial' (started, not finished) or 'new'; ExperimentError on a spec mismatch."""
    d = logdir / run.name
    spec_file = d / SPEC
    if not d.exists():
        return "new"
    if spec_file.exists():
        old = json.loads(spec_file.read_text())
        if old != run.to_json():
            raise ExperimentError(
                f"{d} holds a run with a different spec ({old} != {run.to_json()}): use another "
                "--logdir for another budget or suite, or delete that run")
    return "done" if (d / DONE).exists() else "partial"


def truncate_metrics(csv_path: Path, max_step: int) -> None:
    """Drop rows logged after ``max_step`` (written after the checkpoint a run resumes from)."""
    if not csv_path.exists():
        return
    with open(csv_path, newline="") as f:
        rows = list(csv.reader(f))
    keep = [rows[0], *(r for r in rows[1:] if int(r[0]) <= max_step)]
    tmp = csv_path.with_suffix(".tmp")
    with open(tmp, "w", newline="") as f:
        csv.writer(f).writerows(keep)
    tmp.replace(csv_path)


def prepare(run: RunSpec, logdir: Path) -> list[str]:
    """Create or clean the run directory; return the training command line."""
    d = logdir / run.name
    ckpt = latest_checkpoint(d) if d.exists() else None
    if ckpt is None and d.exists():
        shutil.rmtree(d)  # started, no checkpoint: start again from scratch
    d.mkdir(parents=True, exist_ok=True)
    (d / SPEC).write_text(json.dumps(run.to_json(), indent=1))
    cfg_path = d / "run_config.yaml"
    cfg_path.write_text(yaml.safe_dump(run.config(logdir).to_dict(), sort_keys=False))
    cmd = [sys.executable, "-m", "sdhn_train.cli", "--config", str(cfg_path), "--no-progress"]
    if ckpt is not None:
        step = int(json.loads(ckpt.with_suffix(".json").read_text())["global_step"])
        truncate_metrics(d / "metrics.csv", step)
        for snap in (d / PH_DIR).glob("ph_*.npz"):
            if int(snap.stem[3:]) > step:
                snap.unlink()
        cmd += ["--resume", str(ckpt)]
    return cmd


def finish(run: RunSpec, logdir: Path, wall: float) -> dict[str, Any]:
    d = logdir / run.name
    summary = json.loads((d / "summary.json").read_text()) if (d / "summary.json").exists() \
        else {}
    marker = {"run": run.name, "wall_seconds": round(wall, 1),
              **{k: v for k, v in summary.items() if k.startswith("eval/") or k == "reward"}}
    tmp = d / (DONE + ".tmp")
    tmp.write_text(json.dumps(marker, indent=1))
    tmp.replace(d / DONE)  # atomic: a marker is complete or absent
    return marker


# --- the suite --------------------------------------------------------------------------------


@dataclass
class _Running:
    run: RunSpec
    proc: subprocess.Popen[bytes]
    log: Any
    start: float


def result_line(marker: dict[str, Any]) -> str:
    """A finished run in one line: success and makespan first where the task has them (MAIF),
    then return under the reward it was trained with."""
    reward = f" ({marker['reward']} reward)" if marker.get("reward") else ""
    if "eval/success_rate" in marker:
        return headline(marker) + reward
    ret = marker.get("eval/episodic_return")
    return f"return {ret:.2f}{reward}" if isinstance(ret, float) else "finished"


def run_suite(runs: list[RunSpec], logdir: Path, jobs: int | None = None,
              out: TextIO = sys.stderr, env: dict[str, str] | None = None) -> dict[str, int]:
    """Run every unfinished run, up to ``jobs`` at once (default: CPU cores). Returns counts
    {'done', 'skipped', 'failed'}; a failed run keeps its directory (and log) without a marker."""
    jobs = jobs or os.cpu_count() or 1
    logdir.mkdir(parents=True, exist_ok=True)
    states = {r.name: run_state(r, logdir) for r in runs}  # spec mismatches fail here, up front
    if len({r.name for r in runs}) != len(runs):
        raise ExperimentError("the suite names the same run twice")
    todo = [r for r in runs if states[r.name] != "done"]
    counts = {"done": 0, "skipped": len(runs) - len(todo), "failed": 0}
    print(f"[experiments] {len(runs)} runs: {counts['skipped']} finished earlier, "
          f"{sum(states[r.name] == 'partial' for r in todo)} to resume, "
          f"{sum(states[r.name] == 'new' for r in todo)} new; {jobs} at a time -> {logdir}",
          file=out, flush=True)
    child_env = dict(os.environ if env is None else env)
    child_env.setdefault("PYTHONPATH", os.pathsep.join(p for p in sys.path if p))
    running: list[_Running] = []
    queue = list(todo)
    t_start = time.perf_counter()
    try:
        while queue or running:
            while queue and len(running) < jobs:
                run = queue.pop(0)
                cmd = prepare(run, logdir)
                log = open(logdir / run.name / "train.log", "ab")  # noqa: SIM115
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=child_env)
                running.append(_Running(run, proc, log, time.perf_counter()))
            time.sleep(0.2)
            for r in [r for r in running if r.proc.poll() is not None]:
                running.remove(r)
                r.log.close()
                wall = time.perf_counter() - r.start
                if r.proc.returncode == 0:
                    marker = finish(r.run, logdir, wall)
                    counts["done"] += 1
                    result = result_line(marker)
                else:
                    counts["failed"] += 1
                    result = (f"FAILED (exit {r.proc.returncode}; see "
                              f"{logdir / r.run.name / 'train.log'})")
                finished = counts["done"] + counts["failed"]
                elapsed = time.perf_counter() - t_start
                eta = elapsed / finished * (len(todo) - finished)
                print(f"[experiments] {finished}/{len(todo)} {r.run.name}: {result} in "
                      f"{wall:.0f}s; {len(running)} running, ETA {eta:.0f}s",
                      file=out, flush=True)
    except BaseException:
        for r in running:  # only the processes this function started
            r.proc.send_signal(signal.SIGTERM)
        for r in running:
            r.proc.wait()
            r.log.close()
        raise
    print(f"[experiments] finished: {counts}", file=out, flush=True)
    return counts
