"""The experiment runner on a Ray cluster: each (method, task, seed) run is one Ray task that
asks for the run's declared CPU count (``train.threads`` per data-parallel rank, times
``train.learner_processes``).

    run_experiments configs/suites/paper.yaml --budget paper --logdir /shared/runs/paper \\
        --backend ray --address ray://head:10001

Without ``--address`` (and without ``RAY_ADDRESS``) a local Ray is started and stopped again,
bound to 127.0.0.1 only (Ray has no authentication: whoever reaches its ports can run code). A
cluster started by ``ray start`` is the user's: keep it on a private network or behind a firewall
(docs/reliability-runner.md). The driver holds ``LOGDIR/.runner.lock`` like the local runner, so
two runners never share a log directory.
``--logdir`` must be a path every node sees (a shared file system mounted at the same path): each
task writes its run directory there, with the same files and guarantees as the local runner.

A task prepares its run on the worker (resuming from the run's latest checkpoint, as the local
runner does), trains in a child process that dies with the worker (``PR_SET_PDEATHSIG``), and
writes ``DONE.json`` atomically. A task whose worker dies (SIGKILL, node lost) is retried by Ray
and resumes from the last checkpoint. Two attempts never write the same run at once: each holds
an exclusive ``flock`` on ``LOGDIR/.<run>.lock``, inherited by its training process, so a retry
waits until the previous training process is gone. Every attempt appends a line to the run's
``attempts.jsonl`` (host, Ray node id, pid, the step it resumed from).

Ray is imported only here, and only by ``--backend ray``.
"""

from __future__ import annotations

import fcntl
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, TextIO

from sdhn_experiments.experiments import (
    DONE,
    ExperimentError,
    LogdirLock,
    RunSpec,
    check_runs,
    finish,
    prepare,
    result_line,
    run_dir,
    run_state,
)
from sdhn_train.sections import TrainConfig

ATTEMPTS = "attempts.jsonl"
MAX_RETRIES = 3  # per task, on a worker's or node's death
LOOPBACK = "127.0.0.1"  # what a Ray started here binds to (GCS, raylet, workers)


# Prefix of the training command: ask the kernel to SIGKILL the process when the Ray worker that
# started it dies (PR_SET_PDEATHSIG, Linux), exit if it already has, then exec the trainer. (Not
# a preexec_fn: a Ray worker has threads.)
_WITH_PARENT = ("import ctypes, os, sys; ctypes.CDLL(None).prctl(1, 9); "
                "os.getppid() == int(sys.argv[1]) or sys.exit(137); "
                "os.execv(sys.argv[2], sys.argv[2:])")


def run_one(spec: dict[str, Any], logdir: str) -> dict[str, Any]:
    """One run, start to finish or resumed: the body of a Ray task (also callable directly)."""
    run = RunSpec(**spec)
    check_runs([run])  # names are path components: checked again where they are used
    root = Path(logdir)
    root.mkdir(parents=True, exist_ok=True)
    d = run_dir(run, root)
    with open(root / f".{run.name}.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # a previous attempt's trainer may still be exiting
        if run_state(run, root) == "done":  # finished by an attempt that died afterwards
            return {"run": run.name, "ok": True, "wall": 0.0,
                    "marker": json.loads((d / DONE).read_text())}
        cmd = prepare(run, root)
        resume_step = None
        if "--resume" in cmd:
            ckpt = Path(cmd[cmd.index("--resume") + 1])
            resume_step = int(json.loads(ckpt.with_suffix(".json").read_text())["global_step"])
        attempt = {"host": socket.gethostname(), "node": _ray_node(), "pid": os.getpid(),
                   "time": time.time(), "resume_step": resume_step}
        with open(d / ATTEMPTS, "a") as f:
            f.write(json.dumps(attempt) + "\n")
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        start = time.perf_counter()
        with open(d / "train.log", "ab") as log:
            proc = subprocess.Popen([sys.executable, "-c", _WITH_PARENT, str(os.getpid()), *cmd],
                                    stdout=log, stderr=subprocess.STDOUT, env=env,
                                    pass_fds=(lock.fileno(),))
            rc = proc.wait()
        wall = time.perf_counter() - start
        if rc != 0:
            return {"run": run.name, "ok": False, "wall": wall, "rc": f"exit {rc}"}
        try:
            return {"run": run.name, "ok": True, "wall": wall, "marker": finish(run, root, wall)}
        except ExperimentError as e:
            return {"run": run.name, "ok": False, "wall": wall, "rc": str(e)}


def _ray_node() -> str | None:
    """The Ray node this attempt runs on (None when called outside Ray)."""
    import ray

    return ray.get_runtime_context().get_node_id() if ray.is_initialized() else None


def _cpus(train: TrainConfig) -> int:
    """CPUs a run uses: its intra-op threads in each of its data-parallel ranks."""
    return train.threads * train.learner_processes


def _fmt_time(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m{seconds % 60:02d}s"


def run_suite_ray(runs: list[RunSpec], logdir: Path, address: str | None = None, *,
                  num_cpus: int | None = None, out: TextIO = sys.stderr,
                  max_retries: int = MAX_RETRIES) -> dict[str, int]:
    """Run every unfinished run as a Ray task. ``address``: an existing cluster (else
    ``RAY_ADDRESS``, else a local Ray with ``num_cpus`` CPUs, started and stopped here).
    Returns counts {'done', 'skipped', 'failed'} like ``run_suite``."""
    import ray  # only the Ray backend needs it

    if num_cpus is not None and num_cpus < 1:
        raise ExperimentError(f"--num-cpus {num_cpus}: allowed: an integer >= 1")
    check_runs(runs)
    logdir = logdir.resolve()
    logdir.mkdir(parents=True, exist_ok=True)
    with LogdirLock(logdir):
        return _run_suite_ray_locked(ray, runs, logdir, address=address, num_cpus=num_cpus,
                                     out=out, max_retries=max_retries)


def _start_ray(ray: Any, address: str | None, num_cpus: int | None) -> None:
    """Connect to ``address`` / ``RAY_ADDRESS``, or start a local Ray bound to loopback only:
    Ray has no authentication, so a local one must not listen where others can reach it. Keeps
    this process's SIGTERM handler (Ray's own dumps a C++ stack and exits 1)."""
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                              "configure_logging": False}
    on_term = signal.getsignal(signal.SIGTERM)
    if address or os.environ.get("RAY_ADDRESS"):
        ray.init(address=address, **kwargs)
    else:
        ray.init(num_cpus=num_cpus, _node_ip_address=LOOPBACK, **kwargs)
    if threading.current_thread() is threading.main_thread() and on_term is not None:
        signal.signal(signal.SIGTERM, on_term)


def _largest_node_cpus(ray: Any) -> int:
    return max((int(n.get("Resources", {}).get("CPU", 0)) for n in ray.nodes() if n.get("Alive")),
               default=0)


def _run_suite_ray_locked(ray: Any, runs: list[RunSpec], logdir: Path, *, address: str | None,
                          num_cpus: int | None, out: TextIO,
                          max_retries: int) -> dict[str, int]:
    states = {r.name: run_state(r, logdir) for r in runs}
    todo = [r for r in runs if states[r.name] != "done"]
    counts = {"done": 0, "skipped": len(runs) - len(todo), "failed": 0}
    cpus = {r.name: max(1, _cpus(r.config(logdir).train)) for r in todo}
    if num_cpus is not None and todo and max(cpus.values()) > num_cpus:
        big = max(todo, key=lambda r: cpus[r.name])
        raise ExperimentError(f"--num-cpus {num_cpus}: run {big.name} needs {cpus[big.name]} "
                              "CPUs (train.threads x train.learner_processes); it would wait "
                              "forever")

    started_here = not ray.is_initialized()
    if started_here:
        _start_ray(ray, address, num_cpus)
    try:
        largest = _largest_node_cpus(ray)
        too_big = [r for r in todo if cpus[r.name] > largest]
        if too_big:
            raise ExperimentError(f"run {too_big[0].name} needs {cpus[too_big[0].name]} CPUs; "
                                  f"the largest Ray node has {largest}: it would wait forever")
        total_cpus = int(ray.cluster_resources().get("CPU", 0))
        print(f"[experiments] {len(runs)} runs: {counts['skipped']} finished earlier, "
              f"{sum(states[r.name] == 'partial' for r in todo)} to resume, "
              f"{sum(states[r.name] == 'new' for r in todo)} new; Ray cluster with "
              f"{total_cpus} CPUs -> {logdir}", file=out, flush=True)
        task = ray.remote(run_one)
        pending = {task.options(num_cpus=cpus[r.name], max_retries=max_retries,
                                retry_exceptions=False).remote(r.to_json(), str(logdir)): r
                   for r in todo}
        t_start = time.perf_counter()
        cpu_seconds = 0.0
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                run = pending.pop(ready[0])
                try:
                    res = ray.get(ready[0])
                except ray.exceptions.RayError as e:  # retries exhausted
                    res = {"run": run.name, "ok": False, "wall": 0.0,
                           "rc": f"{type(e).__name__}"}
                cpu_seconds += res["wall"] * cpus[run.name]
                if res["ok"]:
                    counts["done"] += 1
                    result = result_line(res["marker"])
                else:
                    counts["failed"] += 1
                    result = (f"FAILED ({res['rc']}; see {logdir / run.name / 'train.log'})")
                finished = counts["done"] + counts["failed"]
                elapsed = time.perf_counter() - t_start
                eta = elapsed / finished * (len(todo) - finished)
                print(f"[experiments] {run.name}: {result} in {res['wall']:.0f}s", file=out,
                      flush=True)
                print(f"[experiments] {finished}/{len(todo)} runs done, "
                      f"{cpu_seconds / 3600:.3f} CPU-hours, elapsed {_fmt_time(elapsed)}, "
                      f"ETA {_fmt_time(eta)}", file=out, flush=True)
        except BaseException:
            for ref in pending:  # only the tasks this call submitted
                ray.cancel(ref, force=True)
            raise
    finally:
        if started_here:
            ray.shutdown()
    print(f"[experiments] finished: {counts}", file=out, flush=True)
    return counts
