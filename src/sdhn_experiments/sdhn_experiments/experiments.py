"""Experiment runner: a suite (methods x tasks x seeds, with a named budget) run as separate
training processes, several at once, resumable.

    run_experiments configs/suites/paper.yaml --budget quick --logdir runs/paper-quick --jobs 2
    run_experiments configs/suites/paper.yaml --budget paper --logdir /shared/paper \\
        --backend ray --address HEAD:6379   # one Ray task per run: sdhn_experiments/ray_backend.py

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

Hardening (docs/reliability-runner.md): method, task, suite and budget names are checked as path
components before anything is written (``check_name``), and every path deleted is checked to lie
inside the log directory (``inside``); one runner per log directory (``LogdirLock``, inherited by
the trainers); a run is done only with its outputs (``OUTPUTS``) and finite results.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import yaml

from sdhn_base.yaml_io import YamlError, load_yaml
from sdhn_sim.envs.registry import env_names
from sdhn_train import metrics_file
from sdhn_train.algorithms.registry import ALGO_NAMES
from sdhn_train.checkpoint import checkpoint_step, latest_checkpoint, prune_checkpoints
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


# Names become path components (LOGDIR/<task>__<method>__s<seed>, runs/<suite>-<budget>): a
# strict character set keeps every path the runner writes or deletes inside the log directory.
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
NAME_ALLOWED = "allowed: 1-64 of A-Z a-z 0-9 _ . - (not starting with . _ or -)"


def check_name(name: Any, where: str) -> str:
    """``name`` if it is a safe path component; ExperimentError (one line) otherwise."""
    if not isinstance(name, str) or not NAME_RE.fullmatch(name) or ".." in name:
        raise ExperimentError(f"{where}: {name!r} is not a valid name; {NAME_ALLOWED}")
    return name


def _names(data: Any, where: str) -> list[str]:
    """A list of names in a suite (``[a, b]``; a single name is refused: iterating the string
    ``"ab"`` would name methods ``a`` and ``b``)."""
    if not isinstance(data, list) or not all(isinstance(x, str) for x in data):
        raise ExperimentError(f"{where}: expected a list of names, e.g. [sdhn, mappo], "
                              f"got {data!r}")
    return data


def _seeds(data: Any, where: str) -> list[int]:
    ok = (isinstance(data, list) and bool(data)
          and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in data))
    if not ok:
        raise ExperimentError(f"{where}: seeds must be a non-empty list of integers >= 0, "
                              f"got {data!r}")
    twice = sorted({s for s in data if data.count(s) > 1})
    if twice:
        raise ExperimentError(f"{where}: seed {twice[0]} given twice; each seed once")
    return list(data)


# What each level of a suite file may hold. Anything else is refused: a key the loader does not
# read (an override written beside `algo` instead of under `set`, a misspelt `seed:`) would
# otherwise be dropped unseen and the runs trained on the defaults under a name that says not.
SUITE_KEYS = {"name": "the suite's name", "methods": "name -> {algo, set}",
              "tasks": "name -> config overrides", "seeds": "the default seeds",
              "budgets": "name -> {set, seeds}", "experiments": "a list of {methods, tasks, seeds}"}
METHOD_KEYS = {"algo": "the algorithm", "set": "config overrides"}
BUDGET_KEYS = {"set": "config overrides", "seeds": "seeds that replace the suite's"}
GROUP_KEYS = {"methods": "method names", "tasks": "task names", "seeds": "this group's seeds"}


def _section(data: Any, where: str, allowed: dict[str, str]) -> dict[str, Any]:
    """``data`` as a mapping (``_mapping``) holding only ``allowed`` keys; ExperimentError
    (one line naming the allowed ones) otherwise."""
    data = _mapping(data, where)
    unknown = [str(k) for k in data if k not in allowed]
    if unknown:
        raise ExperimentError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: "
                              + "; ".join(f"{k} ({v})" for k, v in allowed.items()))
    return data


def read_suite(path: Path) -> dict[str, Any]:
    """The suite file's top-level mapping; ExperimentError (one line) for an unreadable, binary,
    malformed or empty file, duplicate keys or an alias bomb."""
    try:
        data = load_yaml(path, what="suite")
    except YamlError as e:
        raise ExperimentError(str(e)) from None
    if data is None:
        raise ExperimentError(f"suite {path}: the file is empty; a suite names methods, tasks "
                              "and budgets (see configs/suites/quick.yaml)")
    return _mapping(data, f"suite {path}")


def load_suite(path: str | Path, budget: str) -> list[RunSpec]:
    """The runs of suite ``path`` under budget ``budget``, in a stable order (seed-major, so a
    partial suite has every method on every task before more seeds). Every name is checked
    (``check_name``) and every run validated before anything is written."""
    path = Path(path)
    data = _section(read_suite(path), str(path), SUITE_KEYS)
    name = check_name(data.get("name", path.stem), f"{path}: name")
    methods = _mapping(data.get("methods"), f"{path}: methods")
    tasks = _mapping(data.get("tasks"), f"{path}: tasks")
    budgets = _mapping(data.get("budgets"), f"{path}: budgets")
    for b_name in budgets:
        check_name(b_name, f"{path}: budgets")
    for m in methods:
        check_name(m, f"{path}: methods")
    for t in tasks:
        check_name(t, f"{path}: tasks")
    check_name(budget, "--budget")
    if budget not in budgets:
        raise ExperimentError(f"--budget {budget!r}: {path} defines {', '.join(budgets) or 'none'}")
    b = _section(budgets[budget], f"{path}: budgets.{budget}", BUDGET_KEYS)
    seeds = _seeds(b.get("seeds", data.get("seeds", [1])), f"{path}: budgets.{budget}")
    for m, spec in methods.items():
        algo = _section(spec, f"{path}: methods.{m}", METHOD_KEYS).get("algo")
        if algo not in ALGO_NAMES:
            raise ExperimentError(f"{path}: methods.{m}.algo = {algo!r}; allowed: "
                                  f"{', '.join(ALGO_NAMES)}")
    for t in tasks:
        if t not in env_names():
            raise ExperimentError(f"{path}: task {t!r}; allowed: {', '.join(env_names())}")
    groups = data.get("experiments") or [{"methods": list(methods), "tasks": list(tasks)}]
    if not isinstance(groups, list):
        raise ExperimentError(f"{path}: experiments: expected a list of {{methods: [..], "
                              f"tasks: [..]}}, got {groups!r}")
    pairs: list[tuple[str, str]] = []
    group_seeds: dict[tuple[str, str], list[int]] = {}  # a group's own seeds (protocol suites)
    for i, group in enumerate(groups):
        g = _section(group, f"{path}: experiments[{i}]", GROUP_KEYS)
        gs = _seeds(g["seeds"], f"{path}: experiments[{i}].seeds") if "seeds" in g else seeds
        if "seeds" in b:  # a budget's seeds (e.g. a quick check's one seed) win
            gs = seeds
        for t in _names(g.get("tasks", []), f"{path}: experiments[{i}].tasks"):
            for m in _names(g.get("methods", []), f"{path}: experiments[{i}].methods"):
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
                          {str(k): overrides[k] for k in sorted(overrides, key=str)})
            try:
                run.config(Path("."))
            except ConfigError as e:
                raise ExperimentError(f"{path}: run {run.name}: {e}") from e
            runs.append(run)
    if not runs:
        raise ExperimentError(f"{path}: budget {budget!r} selects no runs (no experiments, "
                              "methods or tasks)")
    return runs


def _seed_order(seeds: list[int]) -> Any:
    """Sort key: the suite's seeds in their listed order, then any others ascending."""
    pos = {x: i for i, x in enumerate(seeds)}
    return lambda x: (pos.get(x, len(pos)), x)


# --- one run ----------------------------------------------------------------------------------


OUTPUTS = (SPEC, "config.yaml", "metrics.csv", "train.log")  # what a finished run must hold
LOCK = ".runner.lock"  # in LOGDIR: held by the runner (and its trainers) while they write


def run_dir(run: RunSpec, logdir: Path) -> Path:
    """``LOGDIR/<run>``, checked to lie inside ``logdir`` once both are resolved (the names are
    checked already; this holds the guarantee where paths are made)."""
    d = logdir / check_name(run.name, "run name")
    inside(d, logdir)
    return d


def inside(path: Path, logdir: Path) -> Path:
    """``path`` if it resolves strictly inside ``logdir``; ExperimentError otherwise. Called on
    every path the runner deletes, right before deleting it."""
    real, root = path.resolve(), logdir.resolve()
    if real == root or not real.is_relative_to(root):
        raise ExperimentError(f"{path} resolves to {real}, outside the log directory {root}: "
                              "refusing to touch it")
    return path


def _remove_tree(path: Path, logdir: Path) -> None:
    if path.is_symlink():  # a link planted in the log directory: remove the link, not its target
        inside(path.parent, logdir)
        path.unlink()
        return
    shutil.rmtree(inside(path, logdir))


def missing_outputs(d: Path) -> list[str]:
    """The files a finished run must hold that ``d`` lacks."""
    return [f for f in OUTPUTS if not (d / f).is_file()]


def read_spec(d: Path) -> dict[str, Any]:
    """A run directory's ``run.json``; ExperimentError (one line) if it is unreadable."""
    spec_file = d / SPEC
    try:
        old = json.loads(spec_file.read_bytes())
    except (OSError, ValueError) as e:  # UnicodeDecodeError and JSONDecodeError included
        raise ExperimentError(f"{spec_file}: unreadable run spec ({type(e).__name__}); it is "
                              f"written by this runner: delete {d} to run it again") from None
    if not isinstance(old, dict):
        raise ExperimentError(f"{spec_file}: not a run spec (expected a JSON object); delete {d} "
                              "to run it again")
    return old


def run_state(run: RunSpec, logdir: Path) -> str:
    """'done' (marker and every output present), 'partial' (started, not finished, or marked
    done with outputs missing) or 'new'; ExperimentError on a spec mismatch or an unreadable
    spec."""
    d = run_dir(run, logdir)
    if not d.exists():
        return "new"
    if (d / SPEC).exists():
        old = read_spec(d)
        if old != run.to_json():
            raise ExperimentError(
                f"{d} holds a run with a different spec ({old} != {run.to_json()}): use another "
                "--logdir for another budget or suite, or delete that run")
    if (d / DONE).exists() and not missing_outputs(d):
        return "done"
    if (d / "metrics.csv").is_file() and latest_checkpoint(d) is not None:
        metrics_rows(d / "metrics.csv")  # it will be resumed: refuse garbage now, not midway
    return "partial"


def list_line(run: RunSpec, logdir: Path) -> str:
    """One line of ``--list``: the run's state and name, and for a partial run how far its
    latest checkpoint got (where a resume starts), so a suite carried over days shows what is
    left without opening every run directory."""
    state = run_state(run, logdir)
    line = f"{state:8s} {run.name}"
    ckpt = latest_checkpoint(run_dir(run, logdir)) if state == "partial" else None
    if ckpt is not None:
        total = run.config(logdir).train.total_steps
        line += f"  checkpoint at {checkpoint_step(ckpt):,} of {total:,} steps"
    return line


def metrics_rows(csv_path: Path) -> list[list[str]]:
    """The rows of a trainer ``metrics.csv`` (header first) that parse (:mod:`the one reader
    <sdhn_train.metrics_file>`); ExperimentError (one line) for a file that is not a metrics CSV
    at all."""
    try:
        return metrics_file.read_rows(csv_path)
    except (OSError, metrics_file.MetricsFileError) as e:
        raise ExperimentError(f"{e if isinstance(e, metrics_file.MetricsFileError) else csv_path}"
                              f"; delete {csv_path.parent} to run it again") from None


def truncate_metrics(csv_path: Path, max_step: int) -> None:
    """Drop rows logged after ``max_step`` (written after the checkpoint a run resumes from) and
    rows that do not parse (cut off by a crash), atomically."""
    metrics_rows(csv_path)  # not a metrics file at all: one line, nothing rewritten
    metrics_file.trim(csv_path, max_step)


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _checkpoint_step(ckpt: Path) -> int | None:
    try:
        return int(json.loads(ckpt.with_suffix(".json").read_bytes())["global_step"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def prepare(run: RunSpec, logdir: Path) -> list[str]:
    """Create or clean the run directory; return the training command line. A run resumes from
    its latest checkpoint only if its metrics survived (else its curves would start midway);
    otherwise it starts again from scratch."""
    d = run_dir(run, logdir)
    ckpt = latest_checkpoint(d) if d.exists() else None
    step = _checkpoint_step(ckpt) if ckpt is not None else None
    if ckpt is not None and step is None:
        raise ExperimentError(f"{ckpt.with_suffix('.json')}: unreadable checkpoint; delete it "
                              f"(or {d}) to resume from an earlier one")
    if step is not None and not (d / "metrics.csv").is_file():
        step = None  # its curves are gone: a resumed run would have half a log
    if step is None and (d.exists() or d.is_symlink()):
        _remove_tree(d, logdir)  # started, nothing to resume from: start again from scratch
    d.mkdir(parents=True, exist_ok=True)
    inside(d, logdir)
    (d / DONE).unlink(missing_ok=True)  # a marker whose outputs went missing: run again
    _write_atomic(d / SPEC, json.dumps(run.to_json(), indent=1))
    cfg_path = d / "run_config.yaml"
    _write_atomic(cfg_path, yaml.safe_dump(run.config(logdir).to_dict(), sort_keys=False))
    cmd = [sys.executable, "-m", "sdhn_train.cli", "--config", str(cfg_path), "--no-progress"]
    if ckpt is not None and step is not None:
        truncate_metrics(d / "metrics.csv", step)
        for snap in (d / PH_DIR).glob("ph_*.npz"):
            if not snap.stem[3:].isdigit() or int(snap.stem[3:]) > step:
                snap.unlink()
        cmd += ["--resume", str(ckpt)]
    return cmd


def finish(run: RunSpec, logdir: Path, wall: float) -> dict[str, Any]:
    """Write the run's completion marker and return it; ExperimentError (no marker) if the run
    lacks an output (its directory removed while it ran) or its results are not finite."""
    d = run_dir(run, logdir)
    missing = missing_outputs(d)
    if missing:
        raise ExperimentError(f"finished without {', '.join(missing)} (was {d} removed while it "
                              "ran?)")
    try:
        summary = json.loads((d / "summary.json").read_bytes()) \
            if (d / "summary.json").exists() else {}
    except ValueError:
        raise ExperimentError(f"{d / 'summary.json'} is unreadable") from None
    if not isinstance(summary, dict):
        summary = {}
    marker = {"run": run.name, "wall_seconds": round(wall, 1),
              **{k: v for k, v in summary.items() if k.startswith("eval/") or k == "reward"}}
    bad = [k for k, v in marker.items()
           if isinstance(v, float) and not math.isfinite(v)]
    if bad:
        raise ExperimentError(f"non-finite results ({', '.join(f'{k}={marker[k]}' for k in bad)})"
                              f"; see {d / 'train.log'}")
    tmp = d / (DONE + ".tmp")
    tmp.write_text(json.dumps(marker, indent=1))
    tmp.replace(d / DONE)  # atomic: a marker is complete or absent
    # A finished run resumes only to be extended (more steps), from its newest checkpoint; the
    # older ones are dead weight, and a QMIX or HGCN-MIX checkpoint holds its replay buffer
    # (2.6 GB on maif-20): three of them per finished run filled a 250 GB disk mid-suite.
    # A suite that set log.keep_checkpoints: 0 asked to keep them all (prune's 0), and does.
    prune_checkpoints(d, keep=min(run.config(logdir).log.keep_checkpoints, 1))
    return marker


class LogdirLock:
    """An exclusive ``flock`` on ``LOGDIR/.runner.lock``, taken without waiting: a second runner
    on the same log directory is refused (one line) instead of deleting or resuming the first
    one's runs. The runner passes the descriptor to its training processes, so the lock holds
    until the last of them has exited, even if the runner itself is killed."""

    GRACE_S = 10.0  # processes killed a moment ago may still hold it while they exit

    def __init__(self, logdir: Path) -> None:
        self.path = logdir / LOCK
        self.fd = -1

    def __enter__(self) -> LogdirLock:
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.GRACE_S
        while True:
            try:
                fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() < deadline:
                    time.sleep(0.1)
                    continue
                holder = os.read(self.fd, 200).decode(errors="replace").strip() or "unknown"
                os.close(self.fd)
                raise ExperimentError(f"{self.path.parent} is in use by another run_experiments "
                                      f"or its training processes ({holder}); wait for it to "
                                      "finish or use another --logdir") from None
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, f"pid {os.getpid()} on {os.uname().nodename}".encode(), 0)
        return self

    def __exit__(self, *exc: object) -> None:
        os.close(self.fd)  # children holding it keep the lock until they exit


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


def check_jobs(jobs: int | None) -> int:
    """``jobs`` (None: CPU cores); ExperimentError below 1 (the queue would never start)."""
    if jobs is None:
        return os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ExperimentError(f"--jobs {jobs}: allowed: an integer >= 1 (runs at once)")
    return jobs


def check_runs(runs: list[RunSpec]) -> None:
    if not runs:
        raise ExperimentError("no runs to run")
    if len({r.name for r in runs}) != len(runs):
        raise ExperimentError("the suite names the same run twice")
    for r in runs:
        for what in ("suite", "budget", "method", "task"):
            check_name(getattr(r, what), what)


def run_suite(runs: list[RunSpec], logdir: Path, jobs: int | None = None,
              out: TextIO = sys.stderr, env: dict[str, str] | None = None) -> dict[str, int]:
    """Run every unfinished run, up to ``jobs`` at once (default: CPU cores). Returns counts
    {'done', 'skipped', 'failed'}; a failed run keeps its directory (and log) without a marker.
    Holds ``LogdirLock`` throughout: a second runner on ``logdir`` is refused."""
    jobs = check_jobs(jobs)
    check_runs(runs)
    logdir.mkdir(parents=True, exist_ok=True)
    with LogdirLock(logdir) as lock:
        return _run_suite_locked(runs, logdir, jobs, out=out, env=env, lock_fd=lock.fd)


def _run_suite_locked(runs: list[RunSpec], logdir: Path, jobs: int, *, out: TextIO,
                      env: dict[str, str] | None, lock_fd: int) -> dict[str, int]:
    states = {r.name: run_state(r, logdir) for r in runs}  # spec mismatches fail here, up front
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
                log = open(run_dir(run, logdir) / "train.log", "ab")  # noqa: SIM115
                # The trainer inherits the log directory's lock: a runner started while it
                # still writes (this one killed) is refused.
                proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=child_env,
                                        pass_fds=(lock_fd,))
                running.append(_Running(run, proc, log, time.perf_counter()))
            time.sleep(0.2)
            for r in [r for r in running if r.proc.poll() is not None]:
                running.remove(r)
                r.log.close()
                wall = time.perf_counter() - r.start
                result = None
                if r.proc.returncode == 0:
                    try:
                        result = result_line(finish(r.run, logdir, wall))
                        counts["done"] += 1
                    except ExperimentError as e:
                        result = f"FAILED ({e})"
                else:
                    result = (f"FAILED (exit {r.proc.returncode}; see "
                              f"{logdir / r.run.name / 'train.log'})")
                if result.startswith("FAILED"):
                    counts["failed"] += 1
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
