"""``train`` as a user drives it (the real console script, as a subprocess): resume takes the
run's saved config and never writes into the run before its checkpoint loaded, falls back past a
damaged checkpoint, refuses unsafe changes and reused names; Ctrl-C saves a checkpoint (with two
data-parallel ranks too, none left behind); a resume
after a kill leaves no duplicate metric rows; every bad input is one line and exit 2."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

from .errors import one_line

TRAIN = str(Path(sys.executable).with_name("train"))
SMALL = ["--env", "maif-tiny", "--num-envs", "2", "--no-progress",
         "--set", "ppo.rollout_len=32", "--set", "ppo.num_minibatches=1", "--set", "ppo.epochs=1",
         "--set", "eval.interval=0", "--set", "log.tensorboard=false",
         "--set", "log.checkpoint_interval=128", "--set", "eval.instances=1"]


def train(*args: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run([TRAIN, *args], capture_output=True, text=True, timeout=timeout,
                          check=False)


def snapshot(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("runs")
    r = train(*SMALL, "--set", f"log.root={root}", "--run-name", "r", "--total-steps", "256")
    assert r.returncode == 0, r.stderr
    return root / "r"


def copy_run(run: Path, to: Path) -> Path:
    subprocess.run(["cp", "-r", str(run), str(to)], check=True)
    return to


def test_resume_takes_the_saved_config(run: Path, tmp_path: Path) -> None:
    d = copy_run(run, tmp_path / "r")
    r = train("--resume", str(d), "--total-steps", "384", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "env:\n  name: maif-tiny" in (d / "config.yaml").read_text()
    assert json.loads((d / "summary.json").read_text())["global_step"] == 384


def test_resume_refuses_a_changed_hyper_parameter_and_writes_nothing(run: Path,
                                                                    tmp_path: Path) -> None:
    d = copy_run(run, tmp_path / "r")
    before = snapshot(d)
    for change in (["--set", "ppo.lr=0.5"], ["--env", "maif-10"], ["--algo", "mappo"]):
        r = train("--resume", str(d), *change)
        assert r.returncode == 2, r.stderr
        assert "cannot change" in one_line(r.stderr)
    assert snapshot(d) == before


def test_resume_falls_back_past_a_truncated_checkpoint(run: Path, tmp_path: Path) -> None:
    d = copy_run(run, tmp_path / "r")
    newest = d / "checkpoints" / "step_000000000256.safetensors"
    newest.write_bytes(newest.read_bytes()[:100])
    r = train("--resume", str(d), "--total-steps", "320")
    assert r.returncode == 0, r.stderr
    assert "resuming from" in r.stderr and "step_000000000128" in r.stderr, r.stderr
    assert "resumed from" in r.stderr and "at step 128" in r.stderr, r.stderr


def test_resume_of_a_checkpoint_for_another_algorithm_is_one_line(run: Path,
                                                                  tmp_path: Path) -> None:
    d = copy_run(run, tmp_path / "r")
    j = d / "checkpoints" / "step_000000000256.json"
    meta = json.loads(j.read_text())
    meta["config"]["algo"]["name"] = "mappo"
    j.write_text(json.dumps(meta))
    before = snapshot(d)
    r = train("--resume", str(j))
    assert r.returncode == 2, r.stderr
    assert "does not fit" in one_line(r.stderr)
    assert snapshot(d) == before


def test_only_the_newest_checkpoints_are_kept_and_the_run_resumes(tmp_path: Path) -> None:
    """A value-mixing checkpoint holds its replay buffer (GBs): log.keep_checkpoints bounds the
    disk a long run takes, deleting the oldest only after the newest is complete."""
    r = train(*SMALL, "--set", f"log.root={tmp_path}", "--run-name", "k", "--total-steps", "384",
              "--set", "log.checkpoint_interval=64", "--set", "log.keep_checkpoints=2")
    assert r.returncode == 0, r.stderr
    stems = sorted(p.name for p in (tmp_path / "k" / "checkpoints").iterdir())
    assert stems == [f"step_{s:012d}{x}" for s in (320, 384) for x in (".json", ".safetensors")]
    r = train("--resume", str(tmp_path / "k"), "--total-steps", "448", "--no-progress",
              "--set", "log.keep_checkpoints=1")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "k" / "checkpoints").iterdir()) == [
        "step_000000000448.json", "step_000000000448.safetensors"]


def test_a_reused_run_name_is_refused(run: Path) -> None:
    before = snapshot(run)
    r = train(*SMALL, "--set", f"log.root={run.parent}", "--run-name", "r",
              "--total-steps", "128")
    assert r.returncode == 2, r.stderr
    assert "already holds a run" in one_line(r.stderr)
    assert snapshot(run) == before


def test_a_directory_prepared_by_a_runner_is_not_a_run(tmp_path: Path) -> None:
    """The experiment runner writes its spec and config into the run directory first."""
    d = tmp_path / "r"
    d.mkdir()
    (d / "run_config.yaml").write_text("train: {seed: 3}\n")
    r = train(*SMALL, "--config", str(d / "run_config.yaml"), "--set", f"log.root={tmp_path}",
              "--run-name", "r", "--total-steps", "64")
    assert r.returncode == 0, r.stderr


def _wait_for(pred, timeout: float) -> None:  # type: ignore[no-untyped-def]
    t0 = time.monotonic()
    while not pred():
        assert time.monotonic() - t0 < timeout, "timed out"
        time.sleep(0.2)


def _metric_keys(d: Path) -> list[tuple[str, str]]:
    with open(d / "metrics.csv", newline="") as f:
        return [(r[0], r[2]) for r in list(csv.reader(f))[1:]]


def _steps(d: Path) -> list[int]:
    return sorted({int(s) for s, _ in _metric_keys(d)})


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_sigterm_saves_a_checkpoint(tmp_path: Path, sig: int) -> None:
    p = subprocess.Popen([TRAIN, *SMALL, "--set", f"log.root={tmp_path}", "--run-name", "r",
                          "--set", "log.checkpoint_interval=0", "--total-steps", "100000000"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    d = tmp_path / "r"
    _wait_for(lambda: (d / "metrics.csv").is_file() and len(_steps(d)) >= 2, 120)
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert "Traceback" not in err and "stopped at step" in err, err
    ckpts = sorted((d / "checkpoints").glob("*.json"))
    assert len(ckpts) == 1
    assert int(ckpts[0].stem[5:]) == _steps(d)[-1]  # no step logged past the checkpoint


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.parametrize("to_group", [True, False],
                         ids=["ctrl-c-to-the-process-group", "sigterm-to-rank-0"])
def test_two_learner_processes_stop_together_with_one_checkpoint(tmp_path: Path,
                                                                 to_group: bool) -> None:
    """A terminal's Ctrl-C reaches every process of the group; rank 1 ignores it and stops when
    rank 0 says so, after a checkpoint holding both ranks' shards; no process is left behind."""
    p = subprocess.Popen([TRAIN, *SMALL, "--set", f"log.root={tmp_path}", "--run-name", "r",
                          "--set", "log.checkpoint_interval=0", "--total-steps", "100000000",
                          "--set", "train.learner_processes=2"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    d = tmp_path / "r"
    _wait_for(lambda: (d / "metrics.csv").is_file() and len(_steps(d)) >= 2, 120)
    if to_group:
        os.killpg(p.pid, signal.SIGINT)
    else:
        p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert "Traceback" not in err and "stopped at step" in err, err
    ckpts = sorted((d / "checkpoints").glob("*.json"))
    assert len(ckpts) == 1, ckpts
    assert "rank1.env_values" in json.loads(ckpts[0].read_text()), "rank 1's shard is missing"
    _wait_for(lambda: not _group_alive(p.pid), 15)


def test_resume_after_a_kill_leaves_no_duplicate_metric_rows(tmp_path: Path) -> None:
    p = subprocess.Popen([TRAIN, *SMALL, "--set", f"log.root={tmp_path}", "--run-name", "r",
                          "--set", "log.checkpoint_interval=192", "--total-steps", "100000000"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    d = tmp_path / "r"
    _wait_for(lambda: (d / "metrics.csv").is_file() and max(_steps(d) or [0]) > 192, 120)
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    last = max(_steps(d))
    r = train("--resume", str(d), "--total-steps", str(last + 256))
    assert r.returncode == 0, r.stderr
    keys = _metric_keys(d)
    dupes = [k for k, n in Counter(keys).items() if n > 1]
    assert not dupes, dupes[:5]


BAD = {
    "negative-seed": ["--seed", "-1"],
    "seed-2**32": ["--seed", str(2**32)],
    "inf-int": ["--set", "train.total_steps=inf"],
    "1e400-int": ["--set", "env.num_envs=1e400"],
    "fractional-epochs": ["--set", "ppo.epochs=2.7"],
    "negative-keep-checkpoints": ["--set", "log.keep_checkpoints=-1"],
    "binary-config": ["--config", "{binary}"],
    "malformed-config": ["--config", "{malformed}"],
    "directory-config": ["--config", "{tmp}"],
    "resume-missing": ["--resume", "{tmp}/nope"],
    "resume-empty-dir": ["--resume", "{tmp}"],
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_and_exit_2(case: str, tmp_path: Path) -> None:
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))
    (tmp_path / "bad.yaml").write_text("ppo: {lr: [1, 2\n")
    args = [a.format(binary=tmp_path / "bin.yaml", malformed=tmp_path / "bad.yaml",
                     tmp=tmp_path) for a in BAD[case]]
    root = tmp_path / "runs"
    r = train(*args, "--set", f"log.root={root}", "--print-config"
              if not case.startswith("resume") else "--no-progress")
    assert r.returncode == 2, (r.returncode, r.stderr[-2000:])
    one_line(r.stderr)
    assert not root.exists()  # no junk run directory


def test_debug_shows_the_traceback(tmp_path: Path) -> None:
    r = train("--seed", "-1", "--debug", "--set", f"log.root={tmp_path}", "--print-config")
    assert r.returncode != 0 and "Traceback" in r.stderr and "train.seed" in r.stderr


def test_missing_warm_start_is_one_line_and_a_resume_does_not_need_it(tmp_path: Path) -> None:
    """actor.init_from is checked before anything starts; once a run has a checkpoint its actor
    comes from there, so resuming it elsewhere (the warm-start file gone) works and keeps the
    field in the run's config as provenance."""
    r = train(*SMALL, "--set", f"log.root={tmp_path}", "--set", "actor.init_from=gone.safetensors")
    assert r.returncode == 2 and "actor.init_from" in one_line(r.stderr), r.stderr
    assert not any(tmp_path.iterdir()), "a refused config must not create a run directory"
    warm = tmp_path / "warm"
    warm.mkdir()
    for suffix in (".safetensors", ".json"):
        src = Path(__file__).parents[2] / "models" / "maif-solo-mappo" / f"actor{suffix}"
        (warm / f"actor{suffix}").write_bytes(src.read_bytes())
    r = train(*SMALL, "--set", f"log.root={tmp_path}", "--run-name", "w", "--total-steps", "128",
              "--set", f"actor.init_from={warm / 'actor.safetensors'}")
    assert r.returncode == 0, r.stderr
    for f in warm.iterdir():
        f.unlink()
    r = train("--resume", str(tmp_path / "w"), "--total-steps", "256", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "w" / "summary.json").read_text())["global_step"] == 256
    assert str(warm / "actor.safetensors") in (tmp_path / "w" / "config.yaml").read_text()


@pytest.mark.parametrize("attack", ["deep_spec", "spec_overflow"])
def test_crafted_warm_start_file_is_one_line(tmp_path: Path, attack: str) -> None:
    """A hostile actor.init_from (deep nesting, an overflowing number) once escaped as a
    RecursionError / OverflowError traceback."""
    from sdhn_policy.weights import load_actor_file

    from .crafted_weights import write_crafted_file

    shipped = Path(__file__).parents[2] / "models" / "maif-solo-mappo" / "actor.safetensors"
    bad = write_crafted_file(tmp_path / "actor.safetensors", load_actor_file(shipped), attack)
    r = train(*SMALL, "--set", f"log.root={tmp_path / 'runs'}", "--total-steps", "64",
              "--set", f"actor.init_from={bad}")
    assert r.returncode == 2, r.stderr[-2000:]
    assert "actor.init_from" in one_line(r.stderr), r.stderr
