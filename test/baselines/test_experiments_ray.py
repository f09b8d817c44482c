"""The experiment runner on Ray (issue 18): a local 2-CPU Ray runs a 2-method x 2-seed suite to
the same numbers as the local backend, and a SIGKILLed Ray worker's run is retried and resumed
from its last checkpoint, never restarted."""

from __future__ import annotations

import csv
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import pytest

from sdhn_train.analysis.experiments import DONE, RunSpec, load_suite, run_suite
from sdhn_train.analysis.figures import load_runs, results_table

pytest.importorskip("ray")

from sdhn_train.analysis.ray_backend import ATTEMPTS, run_suite_ray

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


def _rows(run_dir: Path) -> list[tuple[str, str, str]]:
    with open(run_dir / "metrics.csv", newline="") as f:
        return [(r["step"], r["tag"], r["value"]) for r in csv.DictReader(f)
                if r["tag"] != "charts/steps_per_second"]


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
        assert _rows(logdir / r.name) == _rows(ref / r.name), f"{r.name} differs from local"
    assert results_table(load_runs(logdir)) == results_table(load_runs(ref))


def test_local_backend_does_not_import_ray() -> None:
    code = ("import sys; from sdhn_train.analysis import experiments, experiments_cli; "
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
    final = int(_rows(d)[-1][0])
    assert attempts[1]["resume_step"] is not None and 0 < attempts[1]["resume_step"] < final, \
        (attempts, final)  # resumed from a checkpoint, not restarted
    assert attempts[1]["pid"] != attempts[0]["pid"]
    # No row twice where the uninterrupted run has it once (the final eval repeats the last
    # interval eval's step in both).
    seen = Counter((s, t) for s, t, _ in _rows(d))
    assert seen == Counter((s, t) for s, t, _ in _rows(ref / killed[0])), "duplicated rows"
    for r in runs:
        if r.name not in killed:
            assert len((logdir / r.name / ATTEMPTS).read_text().splitlines()) == 1
    _same_as_local(runs, logdir, ref)
