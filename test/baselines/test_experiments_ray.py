"""The experiment runner on Ray (issue 18): a local 2-CPU Ray runs a 2-method x 2-seed suite to
the same numbers as the local backend; a SIGKILLed Ray worker's run, and the runs of a whole
worker node lost, are retried and resumed from their last checkpoints, never restarted."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path
from typing import Any

import pytest

from sdhn_experiments.experiments import DONE, RunSpec, load_suite, run_suite
from sdhn_experiments.figures import load_runs, results_table

pytest.importorskip("ray")

from sdhn_experiments.bench.experiment_backends import SUITE
from sdhn_experiments.ray_backend import ATTEMPTS, run_suite_ray

from .run_rows import metric_rows


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[RunSpec], Path]:
    """The suite and its local-backend reference run."""
    tmp = tmp_path_factory.mktemp("ray_suite")
    path = tmp / "ray.yaml"
    path.write_text(SUITE)
    runs = load_suite(path, "tiny")
    assert len(runs) == 4
    ref = tmp / "local"
    assert run_suite(runs, ref, jobs=2, out=io.StringIO())["done"] == 4
    return runs, ref


def _same_as_local(runs: list[RunSpec], logdir: Path, ref: Path) -> None:
    for r in runs:
        assert (logdir / r.name / DONE).exists(), r.name
        assert metric_rows(logdir / r.name) == metric_rows(ref / r.name), (
            f"{r.name} differs from local")
    assert results_table(load_runs(logdir)) == results_table(load_runs(ref))


def test_local_backend_does_not_import_ray() -> None:
    code = ("import sys; from sdhn_experiments import experiments, experiments_cli; "
            "assert 'ray' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True,
                   env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})


def test_ray_suite_equals_local(suite: tuple[list[RunSpec], Path], tmp_path: Path) -> None:
    runs, ref = suite
    out = io.StringIO()
    counts = run_suite_ray(runs, tmp_path / "ray", num_cpus=2, out=out)
    assert counts == {"done": 4, "skipped": 0, "failed": 0}, out.getvalue()
    _same_as_local(runs, tmp_path / "ray", ref)
    assert "4/4 runs done" in out.getvalue() and "CPU-hours" in out.getvalue(), out.getvalue()
    # A second call skips every run.
    again = run_suite_ray(runs, tmp_path / "ray", num_cpus=2, out=io.StringIO())
    assert again == {"done": 0, "skipped": 4, "failed": 0}


def test_killed_ray_worker_resumes(suite: tuple[list[RunSpec], Path], tmp_path: Path) -> None:
    runs, ref = suite
    logdir = tmp_path / "ray"
    killed: list[str] = []

    def killer() -> None:
        """SIGKILL the Ray worker of the first run with a checkpoint before its budget (384)."""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            for r in runs:
                d = logdir / r.name
                steps = [int(c.stem.split("_")[1]) for c in (d / "checkpoints").glob("*.json")]
                # mid-run: a checkpoint to resume from, none yet at the budget (a run past its
                # last checkpoint but before its DONE marker would resume at the final step)
                if (d / ATTEMPTS).exists() and steps and max(steps) < 384 \
                        and not (d / DONE).exists():
                    pid = json.loads((d / ATTEMPTS).read_text().splitlines()[0])["pid"]
                    os.kill(pid, signal.SIGKILL)
                    killed.append(r.name)
                    return
            time.sleep(0.02)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    out = io.StringIO()
    counts = run_suite_ray(runs, logdir, num_cpus=2, out=out)
    thread.join()
    assert killed, "no run was killed mid-run"
    assert counts == {"done": 4, "skipped": 0, "failed": 0}, out.getvalue()

    d = logdir / killed[0]
    attempts = [json.loads(line) for line in (d / ATTEMPTS).read_text().splitlines()]
    assert len(attempts) == 2, attempts
    assert attempts[0]["resume_step"] is None
    final = int(metric_rows(d)[-1][0])
    assert attempts[1]["resume_step"] is not None and 0 < attempts[1]["resume_step"] < final, \
        (attempts, final)  # resumed from a checkpoint, not restarted
    assert attempts[1]["pid"] != attempts[0]["pid"]
    # No row twice where the uninterrupted run has it once (the final eval repeats the last
    # interval eval's step in both).
    seen = Counter((s, t) for s, t, _ in metric_rows(d))
    assert seen == Counter((s, t) for s, t, _ in metric_rows(ref / killed[0])), "duplicated rows"
    for r in runs:
        if r.name not in killed:
            assert len((logdir / r.name / ATTEMPTS).read_text().splitlines()) == 1
    _same_as_local(runs, logdir, ref)


def _proc_table() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, start time) of every process (from /proc)."""
    table = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        table[int(stat.parent.name)] = (int(fields[1]), fields[19])
    return table


def _node_pids(node: Any) -> dict[int, str]:
    """Every process of one node of a ``ray.cluster_utils.Cluster`` (its own: raylet, agents,
    ...; and what they started: workers, and the workers' training processes), with its start
    time, so that a pid reused later by someone else's process is never signalled."""
    table = _proc_table()
    children: dict[int, list[int]] = {}
    for pid, (ppid, _) in table.items():
        children.setdefault(ppid, []).append(pid)
    todo = [info.process.pid for infos in node.all_processes.values() for info in infos]
    out: dict[int, str] = {}
    while todo:
        pid = todo.pop()
        if pid in table and pid not in out:
            out[pid] = table[pid][1]
            todo += children.get(pid, [])
    return out


def _sigkill(pids: dict[int, str]) -> None:
    """SIGKILL each process that is still the one recorded (same pid and start time)."""
    table = _proc_table()
    for pid, start in pids.items():
        if table.get(pid, (0, ""))[1] == start:
            with suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


@pytest.fixture
def two_node_cluster(monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """A local Ray cluster of its own, the driver (this process) connected: a head offering no
    CPUs (so every run goes to a worker node) and one worker node with 2 CPUs. Its files,
    sockets and address file live in a private temp dir (nobody else's ``ray.init()`` finds it),
    its API server on a free port; every process it started is stopped at the end, also on
    failure, and nothing else is touched."""
    import ray
    from ray.cluster_utils import Cluster

    tmp = tempfile.mkdtemp(prefix="sdhnray")  # short: Ray's socket paths must fit 107 bytes
    monkeypatch.setenv("RAY_TMPDIR", tmp)
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    with socket.socket() as s:  # not the default 8265, which another user's Ray may hold
        s.bind(("127.0.0.1", 0))
        api_port = s.getsockname()[1]
    cluster = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 0, "include_dashboard": False, "dashboard_port": api_port})
    try:
        # The driver joins while the head is the only node: on one machine it would otherwise
        # attach to whichever raylet it finds first, and losing that node would cut it off.
        ray.init(address=cluster.address, log_to_driver=False, configure_logging=False)
        cluster.add_node(num_cpus=2)
        yield cluster
    finally:
        ray.shutdown()
        left: dict[int, str] = {}
        for node in cluster.list_all_nodes():
            left.update(_node_pids(node))
        with suppress(Exception):
            cluster.shutdown()
        _sigkill(left)
        shutil.rmtree(tmp, ignore_errors=True)


def test_lost_worker_node_resumes(suite: tuple[list[RunSpec], Path], tmp_path: Path,
                                  two_node_cluster: Any) -> None:
    """A whole worker node lost mid-run (its raylet, workers and training processes SIGKILLed
    at once); a replacement node joins; every run ends complete, the interrupted ones resumed
    from their checkpoints on the new node, none restarted, none mixed with another. The
    suite's seed-1 runs: both run at once on the node's 2 CPUs, so both are interrupted."""
    everything, ref = suite
    runs = [r for r in everything if r.seed == 1]
    assert len(runs) == 2
    cluster = two_node_cluster
    logdir = tmp_path / "ray"
    (first,) = cluster.worker_nodes

    def mid_run() -> dict[str, int] | None:
        """Each run's last checkpoint step, once every run has one below the budget and none
        has finished."""
        going: dict[str, int] = {}
        for r in runs:
            d = logdir / r.name
            if not (d / ATTEMPTS).exists():
                continue
            steps = [int(c.stem.split("_")[1]) for c in (d / "checkpoints").glob("*.json")]
            if (d / DONE).exists() or not steps or max(steps) >= 384:
                return None
            going[r.name] = max(steps)
        return going if len(going) == len(runs) else None

    # The suite runs in a thread (its driver calls are thread-safe); Ray starts nodes only from
    # the main thread (it installs signal handlers), so the loss and the replacement happen here.
    out = io.StringIO()
    result: dict[str, Any] = {}

    def suite_thread() -> None:
        try:
            result["counts"] = run_suite_ray(runs, logdir, out=out)
        except BaseException as e:  # reported below
            result["error"] = repr(e)

    thread = threading.Thread(target=suite_thread, daemon=True)
    thread.start()
    killed: dict[str, int] | None = None
    deadline = time.monotonic() + 150
    while killed is None and thread.is_alive() and time.monotonic() < deadline:
        killed = mid_run()
        time.sleep(0.05)
    pids = _node_pids(first)
    _sigkill(pids)  # the node is lost: raylet, agents, workers, training processes at once
    t_lost = time.time()
    cluster.remove_node(first, allow_graceful=False)
    new = cluster.add_node(num_cpus=2).node_id
    t_joined = time.time()
    thread.join(timeout=240)
    assert killed, f"the node was never lost mid-run:\n{out.getvalue()}"
    assert not thread.is_alive(), f"the suite did not end:\n{out.getvalue()}"
    assert result.get("counts") == {"done": 2, "skipped": 0, "failed": 0}, (result,
                                                                            out.getvalue())
    assert sorted(killed) == sorted(r.name for r in runs), killed
    resumed_at = []
    for r in runs:
        attempts = [json.loads(x) for x in (logdir / r.name / ATTEMPTS).read_text().splitlines()]
        assert len(attempts) == 2, (r.name, attempts)
        assert attempts[0]["resume_step"] is None, attempts
        first_try, retry = attempts
        # it ran on the node that was lost, in a process killed with it
        assert first_try["node"] == first.node_id and first_try["pid"] in pids, first_try
        assert retry["node"] == new, (retry, new)
        final = int(metric_rows(logdir / r.name)[-1][0])
        assert 0 < killed[r.name] <= retry["resume_step"] < final, \
            (r.name, retry, killed, final)  # resumed from its last checkpoint, not restarted
        resumed_at.append(retry["time"] - t_lost)
        assert (logdir / r.name / DONE).exists(), r.name
        # the same rows as the uninterrupted local run: none twice, none another run's
        assert metric_rows(logdir / r.name) == metric_rows(ref / r.name), (
            f"{r.name} differs from local")
    print(f"\n[ray node lost] runs {sorted(killed)} at checkpoints {killed}; replacement joined "
          f"{t_joined - t_lost:.1f} s after the loss; their retries started "
          f"{', '.join(f'{t:.1f}' for t in sorted(resumed_at))} s after it; suite done "
          f"{time.time() - t_lost:.1f} s after it; "
          f"load {'/'.join(f'{x:.2f}' for x in os.getloadavg())}")
