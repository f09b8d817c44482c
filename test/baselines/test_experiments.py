"""Experiment runner: suite parsing, resume after a hard kill (finished runs are not repeated and
the results equal an uninterrupted suite's), and the quick suite end to end with figures."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from sdhn_experiments.experiments import (
    DONE,
    ExperimentError,
    list_line,
    load_suite,
    run_suite,
)
from sdhn_experiments.figures import make_figures
from sdhn_train.trainer import Trainer

from .run_rows import metric_rows

ROOT = Path(__file__).resolve().parents[2]
SUITES = ROOT / "configs" / "suites"

RESUME_SUITE = """
name: resume
methods:
  sdhn: {algo: sdhn}
  qmix: {algo: qmix}
  dicg: {algo: dicg}
tasks:
  maif-tiny: {env.max_steps: 40}
seeds: [1]
budgets:
  quick:
    set:
      train.total_steps: 768
      env.num_envs: 4
      ppo.rollout_len: 32
      ppo.num_minibatches: 2
      eval.interval: 256
      eval.episodes: 2
      log.checkpoint_interval: 256
      log.tensorboard: false
      qmix.batch_episodes: 4
      qmix.buffer_episodes: 16
      qmix.learning_starts: 1
"""


def test_paper_suite_lists_the_comparison() -> None:
    runs = load_suite(SUITES / "paper.yaml", "paper")
    pairs = {(r.task, r.method) for r in runs}
    for task in ("maif-10", "maif-16", "maif-20", "rware-3", "rware-6", "rware-9"):
        for method in ("sdhn", "mappo", "qmix", "dicg", "hgcn_mix"):
            assert (task, method) in pairs
    assert {m for _, m in pairs} >= {"sdhn_wo_lsk", "sdhn_wo_shr"}
    assert {r.seed for r in runs} == {1, 2, 3}
    quick = load_suite(SUITES / "paper.yaml", "quick")
    assert {r.seed for r in quick} == {1}
    ablation = next(r for r in runs if r.method == "sdhn_wo_lsk")
    assert ablation.config(Path("x")).sdhn.skew_loss is False


@pytest.mark.parametrize("suite", sorted(p.name for p in SUITES.glob("*.yaml")))
def test_every_shipped_suite_validates_and_its_warm_starts_fit(
        suite: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every budget of every suite in configs/suites gives valid configs (RunSpec.config
    validates), and every warm-start actor a suite names loads into that task's actor: a
    typo or a stale model is found here, not an hour into a suite."""
    monkeypatch.chdir(ROOT)  # init_from paths are relative to the repository root
    budgets = yaml.safe_load((SUITES / suite).read_text())["budgets"]
    checked: set[tuple[str, str]] = set()
    for budget in budgets:
        for run in load_suite(SUITES / suite, budget):
            cfg = run.config(tmp_path)
            key = (run.task, str(cfg.actor.init_from))
            if cfg.actor.init_from and key not in checked:
                checked.add(key)
                cfg.env.num_envs, cfg.eval.instances = 2, 2
                cfg.ppo.num_minibatches = 1
                Trainer(cfg, run_dir=tmp_path / run.name)  # raises ConfigError if it does not fit


def test_bad_suites_are_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("methods: {m: {algo: nope}}\ntasks: {maif-tiny: {}}\nbudgets: {quick: {}}\n")
    with pytest.raises(ExperimentError, match="algo = 'nope'"):
        load_suite(bad, "quick")
    with pytest.raises(ExperimentError, match="--budget 'huge'"):
        load_suite(SUITES / "quick.yaml", "huge")
    bad.write_text("methods: {m: {algo: sdhn}}\ntasks: {maif-tiny: {}}\n"
                   "budgets: {quick: {set: {ppo.lr: -1}}}\n")
    with pytest.raises(ExperimentError, match=r"ppo.lr"):
        load_suite(bad, "quick")


def test_resume_after_kill(tmp_path: Path) -> None:
    suite = tmp_path / "resume.yaml"
    suite.write_text(RESUME_SUITE)
    runs = load_suite(suite, "quick")
    names = [r.name for r in runs]

    # Reference: the suite without interruption.
    ref = tmp_path / "ref"
    assert run_suite(runs, ref, jobs=1, out=io.StringIO())["done"] == 3

    # Interrupted: kill the runner and its runs hard (as a crash would) once the first run is
    # finished and the second has written a checkpoint.
    logdir = tmp_path / "logs"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "sdhn_experiments.experiments_cli",
                             str(suite), "--budget", "quick", "--logdir", str(logdir),
                             "--jobs", "1"],
                            env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    second_ckpt = logdir / names[1] / "checkpoints"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (
            (logdir / names[0] / DONE).exists() and any(second_ckpt.glob("*.json"))):
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert (logdir / names[0] / DONE).exists(), "the first run did not finish in time"
    assert not (logdir / names[1] / DONE).exists(), "killed too late: the second run finished"
    # --list says where each run stands, a partial one with its checkpoint's step
    assert list_line(runs[0], logdir) == f"done     {names[0]}"
    step = int(sorted(second_ckpt.glob("*.json"))[-1].stem.removeprefix("step_"))
    assert list_line(runs[1], logdir) == (f"partial  {names[1]}  checkpoint at {step:,} of "
                                          "768 steps")
    assert list_line(runs[2], logdir) == f"new      {names[2]}"
    first_marker = (logdir / names[0] / DONE).read_text()
    first_log_size = (logdir / names[0] / "train.log").stat().st_size

    out = io.StringIO()
    counts = run_suite(runs, logdir, jobs=1, out=out)
    assert counts == {"done": 2, "skipped": 1, "failed": 0}, out.getvalue()
    assert "1 to resume" in out.getvalue() or "0 to resume" in out.getvalue(), out.getvalue()
    assert (logdir / names[0] / DONE).read_text() == first_marker  # not run again
    assert (logdir / names[0] / "train.log").stat().st_size == first_log_size
    for name in names:
        assert metric_rows(logdir / name) == metric_rows(ref / name), f"{name} differs after resume"
        assert json.loads((logdir / name / DONE).read_text())["run"] == name

    # A third call does nothing; another budget in the same log dir is refused.
    assert run_suite(runs, logdir, jobs=1, out=io.StringIO()) == {
        "done": 0, "skipped": 3, "failed": 0}
    other = load_suite(suite, "quick")
    changed = [type(r)(r.suite, "other", r.method, r.task, r.seed, r.algo, r.overrides)
               for r in other]
    with pytest.raises(ExperimentError, match="different spec"):
        run_suite(changed, logdir, jobs=1, out=io.StringIO())


def test_quick_suite_and_figures(tmp_path: Path) -> None:
    """The CI smoke test: configs/suites/quick.yaml --budget quick, then every figure."""
    logdir = tmp_path / "quick"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "run_experiments.py"),
                          str(SUITES / "quick.yaml"), "--budget", "quick", "--logdir",
                          str(logdir), "--jobs", "2"], env=env, capture_output=True, text=True,
                         timeout=600, check=False)
    assert res.returncode == 0, res.stderr[-3000:]
    assert len(list(logdir.glob(f"*/{DONE}"))) == 7, res.stderr[-3000:]
    written = {p.name for p in make_figures(logdir, tmp_path / "fig", scripted_instances=4)}
    assert {"success.png", "returns.png", "makespan.png", "skewness.png", "ablation_maif-tiny.png",
            "ph_heatmap_maif-tiny.png", "results.md"} <= written, written
