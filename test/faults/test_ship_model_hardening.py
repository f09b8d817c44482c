"""scripts/ship_model.py on runs it cannot ship and outputs it must not write: one line, exit 2,
refused before the (minutes-long) evaluation, no temporary directory left behind."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from sdhn_train.config import Config

from .errors import one_line

ROOT = Path(__file__).resolve().parents[2]
SHIP = ROOT / "scripts" / "ship_model.py"
MODEL = ROOT / "models" / "maif-solo-mappo"  # a shipped maif-solo actor


def ship(tmp_path: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir(exist_ok=True)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "TMPDIR": str(tmpdir)}
    return subprocess.run([sys.executable, str(SHIP), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=300, check=False)


def make_run(root: Path, task: str = "maif-solo") -> Path:
    run = root / "run"
    run.mkdir(parents=True)
    cfg = Config()
    cfg.env.name, cfg.algo.name = task, "mappo"
    (run / "config.yaml").write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
    for suffix in (".safetensors", ".json"):
        shutil.copyfile(MODEL / f"actor{suffix}", run / f"actor{suffix}")
    return run


def test_rware_run_ships_with_deliveries_beside_the_baselines(tmp_path: Path) -> None:
    """An RWARE run ships too: its card gives greedy deliveries per episode on seeds no training
    draws, beside random and both scripted policies on the same seeds."""
    import json

    from sdhn_policy.actor_torch import Actor
    from sdhn_policy.weights import ActorSpec, save_actor_file
    from sdhn_sim.envs import make_env

    run = make_run(tmp_path, "rware-tiny-2ag")
    env = make_env("rware-tiny-2ag", num_envs=1, seed=0)
    save_actor_file(run / "actor.safetensors", Actor(ActorSpec(
        obs_size=env.obs_size, num_actions=env.num_actions, num_robots=env.num_robots,
        use_robot_id=True)).export(version=3))
    r = ship(tmp_path, run, tmp_path / "model", "--episodes", "2")
    assert r.returncode == 0, r.stderr
    card = json.loads((tmp_path / "model" / "card.json").read_text())
    ev = card["evaluation"]
    assert ev["episodes"] == 2 and ev["first_seed"] == 1_000_000
    assert len(ev["policy"]["deliveries"]) == 2
    assert set(ev) >= {"random", "scripted", "decentralised"}
    assert ev["decentralised"]["deliveries_mean"] > 0  # the scripted policies do deliver
    md = (tmp_path / "model" / "card.md").read_text()
    assert "deliveries per episode" in md and "scripted (centralised)" in md
    contract = json.loads((tmp_path / "model" / "actor.onnx.json").read_text())
    assert contract["actions"][4] == "toggle_load"


def test_actor_of_another_env_is_refused(tmp_path: Path) -> None:
    from sdhn_policy.actor_torch import Actor
    from sdhn_policy.weights import ActorSpec, save_actor_file

    run = make_run(tmp_path)
    save_actor_file(run / "actor.safetensors",
                    Actor(ActorSpec(obs_size=99, num_actions=5)).export(version=1))
    r = ship(tmp_path, run, tmp_path / "model", "--instances", "1")
    assert r.returncode == 2 and "obs size 99" in one_line(r.stderr)


@pytest.mark.parametrize("damage", ["missing-sidecar", "corrupt-actor", "garbage-sidecar",
                                    "garbage-config", "no-actor"])
def test_damaged_run_is_one_line(damage: str, tmp_path: Path) -> None:
    run = make_run(tmp_path)
    if damage == "missing-sidecar":
        (run / "actor.json").unlink()
    elif damage == "corrupt-actor":
        (run / "actor.safetensors").write_bytes(b"\x00" * 100)
    elif damage == "garbage-sidecar":
        (run / "actor.json").write_bytes(bytes(range(256)))
    elif damage == "garbage-config":
        (run / "config.yaml").write_text("env: [\n")
    else:
        (run / "actor.safetensors").unlink()
    r = ship(tmp_path, run, tmp_path / "model", "--instances", "1")
    assert r.returncode == 2, r.stderr
    one_line(r.stderr)
    assert not (tmp_path / "model").exists()


@pytest.mark.parametrize("case", ["instances-0", "missing-checkpoint", "out-is-run",
                                  "out-is-file"])
def test_bad_arguments_are_refused_before_evaluating(case: str, tmp_path: Path) -> None:
    run = make_run(tmp_path)
    out = tmp_path / "model"
    extra: list[str] = []
    if case == "instances-0":
        extra = ["--instances", "0"]
    elif case == "missing-checkpoint":
        extra = ["--checkpoint", "step_000000000999"]
    elif case == "out-is-run":
        out = run
    else:
        out.write_text("a file")
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    r = ship(tmp_path, run, out, *(extra or ["--instances", "1"]))
    assert r.returncode == 2, r.stderr
    one_line(r.stderr)
    assert "[ship]" not in r.stdout  # refused before any evaluation
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    if case == "out-is-file":
        assert out.read_text() == "a file"


def test_ship_a_checkpoint_leaves_no_temporary_directory(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    subprocess.run([sys.executable, "-m", "sdhn_train.cli", "--no-progress", "--env",
                    "maif-solo", "--algo", "mappo", "--total-steps", "64",
                    "--set", "env.num_envs=2", "--set", "ppo.rollout_len=32",
                    "--set", "ppo.num_minibatches=1", "--set", "eval.interval=0",
                    "--set", "log.checkpoint_interval=32", "--set", "log.tensorboard=false",
                    "--set", f"log.root={tmp_path}", "--run-name", "run"],
                   env=env, check=True, capture_output=True, timeout=300)
    ckpt = sorted((tmp_path / "run" / "checkpoints").glob("*.json"))[-1].stem
    r = ship(tmp_path, tmp_path / "run", tmp_path / "model", "--instances", "1",
             "--checkpoint", ckpt)
    assert r.returncode == 0, r.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "model").iterdir()) == [
        "actor.json", "actor.onnx", "actor.onnx.json", "actor.safetensors", "card.json",
        "card.md", "deploy.json"]
    assert list((tmp_path / "tmp").iterdir()) == []
