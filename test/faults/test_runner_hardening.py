"""The experiment runner as a hostile but realistic user meets it: names that would become paths
outside the log directory, two runners on one log directory, a run directory deleted while it
ran, duplicate YAML keys, hangs (--jobs -1, --num-cpus 0) and garbage where a resume reads. Each
is one line and exit 2 (or a FAILED run without a marker), nothing outside the log directory
touched, nothing lost."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sdhn_experiments import experiments_cli
from sdhn_experiments.experiments import (
    DONE,
    LOCK,
    ExperimentError,
    LogdirLock,
    finish,
    load_suite,
    prepare,
    run_state,
    truncate_metrics,
)
from sdhn_train.checkpoint import checkpoint_path, checkpoints, save_checkpoint

from .errors import one_line

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}

BUDGET = """budgets:
  quick:
    set:
      train.total_steps: 256
      env.num_envs: 2
      ppo.rollout_len: 32
      ppo.num_minibatches: 1
      eval.interval: 256
      eval.episodes: 1
      eval.instances: 2
      log.checkpoint_interval: 64
      log.tensorboard: false
"""
GOOD = ("name: h\nmethods:\n  mappo: {algo: mappo}\ntasks:\n  maif-solo: {env.max_steps: 20}\n"
        "seeds: [1]\n" + BUDGET)


def runner(*args: str | Path, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """run_experiments in a process of its own (as a user starts it)."""
    return subprocess.run([sys.executable, "-m", "sdhn_experiments.experiments_cli",
                           *map(str, args)], env=ENV, capture_output=True, text=True,
                          timeout=timeout, check=False)


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., tuple[int, str]]:
    """run_experiments' main in this process (fast; for the checks that start no training):
    (exit code, stderr). Its SIGTERM and SIGINT handlers are put back afterwards."""
    def call(*args: str | Path) -> tuple[int, str]:
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
        try:
            rc = experiments_cli.main([str(a) for a in args])
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        return rc, capsys.readouterr().err

    return call


def _suite(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "suite.yaml"
    path.write_text(text)
    return path


# --- names and paths ---------------------------------------------------------------------------

EVIL = {
    "method": GOOD.replace("  mappo: {algo: mappo}", "  '../../victim': {algo: mappo}"),
    "method-slash": GOOD.replace("  mappo: {algo: mappo}", "  'a/b': {algo: mappo}"),
    "suite": GOOD.replace("name: h", "name: ../victim"),
    "budget": GOOD.replace("  quick:", "  '../quick':"),
    "numeric-budget": GOOD.replace("  quick:", "  0:"),
    "numeric-method": GOOD.replace("  mappo: {algo: mappo}", "  7: {algo: mappo}"),
    "task": GOOD.replace("  maif-solo: {env.max_steps: 20}", "  '..': {}"),
}


@pytest.mark.parametrize("case", list(EVIL))
def test_names_that_would_be_paths_are_refused_before_anything_is_touched(
        case: str, tmp_path: Path, cli: Callable[..., tuple[int, str]]) -> None:
    logdir = tmp_path / "a" / "logs"
    victim = tmp_path / "a" / "victim"
    victim.mkdir(parents=True)
    (victim / "keep").write_text("precious")
    rc, err = cli(_suite(tmp_path, EVIL[case]), "--logdir", logdir,
                  "--budget", "../quick" if case == "budget" else "quick")
    assert rc == 2, err
    assert "not a valid name" in one_line(err)
    assert not logdir.exists() and (victim / "keep").read_text() == "precious"
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["victim"]


def test_a_run_directory_that_is_a_link_out_is_refused_not_followed(
        tmp_path: Path, cli: Callable[..., tuple[int, str]]) -> None:
    """A link planted where a run directory belongs, pointing outside the log directory: the
    runner refuses it (one line) and never deletes or writes what it points to."""
    suite = _suite(tmp_path, GOOD)
    run = load_suite(suite, "quick")[0]
    logdir = tmp_path / "logs"
    logdir.mkdir()
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "keep").write_text("precious")
    (logdir / run.name).symlink_to(outside)
    with pytest.raises(ExperimentError, match="outside the log directory"):
        prepare(run, logdir)
    rc, err = cli(suite, "--logdir", logdir)
    assert rc == 2 and "outside the log directory" in one_line(err)
    assert sorted(p.name for p in outside.iterdir()) == ["keep"]
    assert (outside / "keep").read_text() == "precious"


# --- suite checks ------------------------------------------------------------------------------

BAD_SUITES = {
    "duplicate-method": (GOOD.replace("  mappo: {algo: mappo}\n",
                                      "  mappo: {algo: sdhn}\n  mappo: {algo: mappo}\n"),
                         "duplicate key 'mappo'"),
    "empty-file": ("", "is empty"),
    "comment-only": ("# nothing here\n", "is empty"),
    "binary": (None, "not a text file"),
    "malformed": ("methods: {a: [1, 2\n", "malformed YAML"),
    "top-level-list": ("- 1\n- 2\n", "expected a mapping"),
    "repeated-seed": (GOOD.replace("seeds: [1]", "seeds: [1, 1]"), "seed 1 given twice"),
    "bool-seed": (GOOD.replace("seeds: [1]", "seeds: [true]"), "seeds must be"),
    "methods-as-string": (GOOD + "experiments:\n  - {methods: mappo, tasks: [maif-solo]}\n",
                          "expected a list of names"),
    "experiments-mapping": (GOOD + "experiments: {methods: [mappo]}\n", "experiments"),
    "override-beside-algo": (GOOD.replace("{algo: mappo}", "{algo: mappo, ppo.lr: 0.1}"),
                             "methods.mappo: unknown key(s) ppo.lr; allowed: algo"),
    "misspelt-top-level-key": (GOOD.replace("seeds: [1]", "seed: [1]"),
                               "unknown key(s) seed; allowed: name"),
    "budget-key-outside-set": (GOOD.replace("    set:\n", "    total_steps: 10\n    set:\n", 1),
                               "budgets.quick: unknown key(s) total_steps; allowed: set"),
    "group-key-misspelt": (GOOD + "experiments:\n  - {method: [mappo], tasks: [maif-solo]}\n",
                           "experiments[0]: unknown key(s) method; allowed: methods"),
    "alias-bomb": ("a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n"
        for p, c in zip("abcdefgh", "bcdefghi", strict=True)), "aliases expand"),
}


@pytest.mark.parametrize("case", list(BAD_SUITES))
@pytest.mark.parametrize("listing", [False, True], ids=["run", "list"])
def test_bad_suite_is_one_line_exit_2_for_run_and_list(
        case: str, listing: bool, tmp_path: Path, cli: Callable[..., tuple[int, str]]) -> None:
    text, expected = BAD_SUITES[case]
    path = tmp_path / "suite.yaml"
    if text is None:
        path.write_bytes(bytes(range(256)) * 8)
    else:
        path.write_text(text)
    rc, err = cli(path, "--logdir", tmp_path / "logs", *(["--list"] if listing else []))
    assert rc == 2, (rc, err)
    assert expected in one_line(err)
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize("flags", [["--jobs", "-1"], ["--jobs", "0"],
                                   ["--backend", "ray", "--num-cpus", "0"]],
                         ids=["jobs-1", "jobs0", "num-cpus0"])
def test_values_that_would_hang_are_refused(flags: list[str], tmp_path: Path) -> None:
    r = runner(_suite(tmp_path, GOOD), "--logdir", tmp_path / "logs", *flags, timeout=60)
    assert r.returncode == 2, r.stderr
    assert flags[-2] in one_line(r.stderr)
    assert not (tmp_path / "logs").exists()


# --- what a resume reads ------------------------------------------------------------------------


def _started(tmp_path: Path, metrics: bytes | None, spec: bytes | None = None) -> Path:
    """A run directory as a crash leaves it: spec, a checkpoint, metrics (given bytes)."""
    run = load_suite(_suite(tmp_path, GOOD), "quick")[0]
    logdir = tmp_path / "logs"
    d = logdir / run.name
    (d / "checkpoints").mkdir(parents=True)
    (d / "run.json").write_bytes(spec if spec is not None else
                                 json.dumps(run.to_json()).encode())
    (d / "checkpoints" / "step_000000000064.json").write_text('{"global_step": 64}')
    (d / "checkpoints" / "step_000000000064.safetensors").write_bytes(b"x")
    if metrics is not None:
        (d / "metrics.csv").write_bytes(metrics)
    return logdir


@pytest.mark.parametrize("spec", [b"", b"{garbage", b"\xff\xfe\x00", b"[1, 2]"],
                         ids=["empty", "garbage", "binary", "list"])
def test_resume_with_unreadable_run_json_is_one_line(
        spec: bytes, tmp_path: Path, cli: Callable[..., tuple[int, str]]) -> None:
    logdir = _started(tmp_path, b"step,wall_time,tag,value\n", spec)
    rc, err = cli(tmp_path / "suite.yaml", "--logdir", logdir)
    assert rc == 2, err
    assert "run.json" in one_line(err)


@pytest.mark.parametrize("metrics", [bytes(range(256)) * 4, b"not,a,metrics,file\n1,2,3,4\n"],
                         ids=["binary", "wrong-header"])
def test_resume_with_garbage_metrics_is_one_line_and_keeps_the_run(
        metrics: bytes, tmp_path: Path, cli: Callable[..., tuple[int, str]]) -> None:
    logdir = _started(tmp_path, metrics)
    before = sorted(p.name for p in logdir.rglob("*"))
    rc, err = cli(tmp_path / "suite.yaml", "--logdir", logdir)
    assert rc == 2, err
    assert "metrics" in one_line(err)
    assert sorted(p.name for p in logdir.rglob("*") if p.name != LOCK) == before


def test_truncation_drops_a_cut_off_last_row(tmp_path: Path) -> None:
    path = tmp_path / "metrics.csv"
    path.write_text("step,wall_time,tag,value\n32,1.0,a,1\n64,2.0,a,2\n96,3.0,a,3\n64,2.5,b")
    truncate_metrics(path, 64)
    with open(path, newline="") as f:
        assert list(csv.reader(f)) == [["step", "wall_time", "tag", "value"],
                                       ["32", "1.0", "a", "1"], ["64", "2.0", "a", "2"]]
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    truncate_metrics(empty, 64)  # nothing to keep, no IndexError


# --- finishing -----------------------------------------------------------------------------


def _finished(tmp_path: Path, summary: str = '{"eval/episodic_return": 1.5}',
              text: str = GOOD) -> Path:
    run = load_suite(_suite(tmp_path, text), "quick")[0]
    logdir = tmp_path / "logs"
    prepare(run, logdir)
    d = logdir / run.name
    for f in ("config.yaml", "metrics.csv", "train.log"):
        (d / f).write_text("x\n")
    (d / "summary.json").write_text(summary)
    return logdir


def test_finish_refuses_a_run_whose_outputs_are_gone(tmp_path: Path) -> None:
    logdir = _finished(tmp_path)
    run = load_suite(tmp_path / "suite.yaml", "quick")[0]
    (logdir / run.name / "metrics.csv").unlink()
    (logdir / run.name / "config.yaml").unlink()
    with pytest.raises(ExperimentError, match=r"without config\.yaml, metrics\.csv"):
        finish(run, logdir, 1.0)
    assert not (logdir / run.name / DONE).exists()


def test_a_done_run_missing_outputs_is_not_skipped(tmp_path: Path) -> None:
    logdir = _finished(tmp_path)
    run = load_suite(tmp_path / "suite.yaml", "quick")[0]
    finish(run, logdir, 1.0)
    assert run_state(run, logdir) == "done"
    (logdir / run.name / "metrics.csv").unlink()
    assert run_state(run, logdir) == "partial"


@pytest.mark.parametrize("keep_all", [False, True])
def test_a_finished_run_keeps_only_its_newest_checkpoint_unless_told_to_keep_all(
        keep_all: bool, tmp_path: Path) -> None:
    keep_all_suite = GOOD.replace("{algo: mappo}", "{algo: mappo, set: {log.keep_checkpoints: 0}}")
    suite = keep_all_suite if keep_all else GOOD
    logdir = _finished(tmp_path, text=suite)
    run = load_suite(tmp_path / "suite.yaml", "quick")[0]
    d = logdir / run.name
    for step in (100, 200, 300):
        save_checkpoint(checkpoint_path(d, step), {"w": np.zeros(2, np.float32)},
                        {"global_step": step})
    finish(run, logdir, 1.0)
    kept = (100, 200, 300) if keep_all else (300,)
    assert checkpoints(d) == [checkpoint_path(d, step) for step in kept]
    assert sorted(p.name for p in (d / "checkpoints").iterdir()) == sorted(
        f"step_{step:012d}.{ext}" for step in kept for ext in ("json", "safetensors"))


@pytest.mark.parametrize("value", ["Infinity", "-Infinity", "NaN"])
def test_non_finite_results_are_a_failure_not_a_result(value: str, tmp_path: Path) -> None:
    logdir = _finished(tmp_path, f'{{"eval/episodic_return": {value}}}')
    run = load_suite(tmp_path / "suite.yaml", "quick")[0]
    with pytest.raises(ExperimentError, match="non-finite"):
        finish(run, logdir, 1.0)
    assert not (logdir / run.name / DONE).exists()


# --- two runners -------------------------------------------------------------------------------


def test_second_runner_on_a_logdir_in_use_is_refused_even_after_the_first_is_killed(
        tmp_path: Path) -> None:
    """Runner A trains; runner B on the same log directory is refused (one line) and touches
    nothing. A is SIGKILLed alone, its trainer lives on: B is still refused, because the
    trainer holds the lock A took. Once the trainer is gone, B resumes the run."""
    suite = _suite(tmp_path, GOOD.replace("total_steps: 256", "total_steps: 100000"))
    logdir = tmp_path / "logs"
    run = load_suite(suite, "quick")[0]
    a = subprocess.Popen([sys.executable, "-m", "sdhn_experiments.experiments_cli",
                          str(suite), "--logdir", str(logdir), "--jobs", "1"], env=ENV,
                         start_new_session=True, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    try:
        log = logdir / run.name / "train.log"
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (logdir / run.name / "config.yaml").exists():
            time.sleep(0.05)
        assert (logdir / run.name / "config.yaml").exists(), "runner A never started its run"
        size = log.stat().st_size
        b = runner(suite, "--logdir", logdir, "--jobs", "1")
        assert b.returncode == 2 and "in use" in one_line(b.stderr), b.stderr
        assert (logdir / run.name / "run.json").exists() and log.stat().st_size >= size

        os.kill(a.pid, signal.SIGKILL)  # the runner only; its trainer keeps running
        a.wait()
        b = runner(suite, "--logdir", logdir, "--jobs", "1")
        assert b.returncode == 2 and "in use" in one_line(b.stderr), b.stderr
    finally:
        os.killpg(a.pid, signal.SIGKILL)
        a.wait()
    deadline = time.monotonic() + 30
    while True:  # the trainer, killed with its group, releases the lock once it is gone
        try:
            with LogdirLock(logdir):
                break
        except ExperimentError:
            assert time.monotonic() < deadline, "the lock outlived every process holding it"
            time.sleep(0.1)
    assert run_state(run, logdir) == "partial"


def test_sigint_stops_a_runner_started_in_the_background_by_a_script(tmp_path: Path) -> None:
    """`bash -c 'run_experiments ... &'` starts the runner with SIGINT ignored (a shell without
    job control does that to background commands, and Python keeps it). `kill -INT` must still
    stop it: exit 130 with the resume hint, its trainer stopped with it (the lock is free), the
    run resumable rather than finished or lost."""
    suite = _suite(tmp_path, GOOD.replace("total_steps: 256", "total_steps: 100000"))
    logdir = tmp_path / "logs"
    run = load_suite(suite, "quick")[0]
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # inherited through exec, as from
    try:                                                      # a shell without job control
        proc = subprocess.Popen([sys.executable, "-m", "sdhn_experiments.experiments_cli",
                                 str(suite), "--logdir", str(logdir), "--jobs", "1"], env=ENV,
                                start_new_session=True, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any(
                (logdir / run.name / "checkpoints").glob("*.json")):
            time.sleep(0.05)
        assert any((logdir / run.name / "checkpoints").glob("*.json")), "the run never started"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert "interrupted; rerun the same command to resume" in err, err
    with LogdirLock(logdir):  # taken: no trainer of the stopped runner holds it any more
        pass
    assert run_state(run, logdir) == "partial"


@pytest.mark.parametrize("name", ["../escape", "a/b", "..", ".", "a\\b"])
def test_trainer_run_name_is_one_directory_name(name: str) -> None:
    """The same class in the trainer: log.run_name is joined to log.root, so a separator or a
    dot name would put the run outside the root."""
    from sdhn_train.config import Config, ConfigError, validate

    cfg = Config()
    cfg.log.run_name = name
    with pytest.raises(ConfigError, match=r"log\.run_name"):
        validate(cfg)
    cfg.log.run_name = "maif-10__sdhn__1"
    validate(cfg)


def test_trainer_trim_drops_a_cut_off_last_row(tmp_path: Path) -> None:
    """The same class in the trainer's own resume (train --resume): its cut of metrics.csv
    also drops a row a crash cut off, which it used to keep when the step survived."""
    from sdhn_train.metrics_file import trim

    (tmp_path / "metrics.csv").write_text("step,wall_time,tag,value\n32,1.0,a,1\n64,2.0,a,2\n"
                                          "64,2.5,b")
    assert trim(tmp_path / "metrics.csv", 64) == 1
    assert (tmp_path / "metrics.csv").read_text().splitlines() == [
        "step,wall_time,tag,value", "32,1.0,a,1", "64,2.0,a,2"]
