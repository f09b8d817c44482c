"""scripts/train_curriculum.py: a malformed --stages is one line and exit 2; a finished stage is
skipped only if it was trained with exactly the requested spec, otherwise refused, never reused
with the old stage's config."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from .errors import one_line

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "train_curriculum.py"


def curriculum(*args: str | Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.parametrize("stages", ["maif-solo", "maif-solo:abc", "nope:100", "maif-solo:0",
                                    "maif-solo:-5", "rware-3:100", "maif-solo:100,",
                                    "maif-solo:1:2"])
def test_malformed_stages_are_one_line(stages: str, tmp_path: Path) -> None:
    r = curriculum("--stages", stages, "--out", tmp_path / "out")
    assert r.returncode == 2, r.stderr
    assert "--stages" in one_line(r.stderr)
    assert not (tmp_path / "out").exists()


def _finished_stage(out: Path, spec: dict[str, object] | None) -> Path:
    d = out / "maif-solo__mappo__1"
    d.mkdir(parents=True)
    (d / "summary.json").write_text("{}")
    (d / "actor.safetensors").write_bytes(b"weights")
    if spec is not None:
        (d / "curriculum_stage.json").write_text(json.dumps(spec))
    return d


SOLO_FLAGS = ["--set", "env.num_envs=16", "--set", "ppo.rollout_len=64",
              "--set", "ppo.num_minibatches=2", "--set", "env.max_steps=100"]


def _spec(steps: int, extra: list[str] | None = None) -> dict[str, object]:
    return {"env": "maif-solo", "algo": "mappo", "seed": 1, "total_steps": steps,
            "init_from": None, "flags": [*SOLO_FLAGS, *(extra or [])]}


def test_a_finished_stage_with_the_same_spec_is_skipped(tmp_path: Path) -> None:
    _finished_stage(tmp_path / "out", _spec(100))
    r = curriculum("--stages", "maif-solo:100", "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "done, skipped" in r.stdout


@pytest.mark.parametrize("case", ["other-steps", "other-set", "no-spec", "garbage-spec"])
def test_a_stage_trained_otherwise_is_refused(case: str, tmp_path: Path) -> None:
    spec: dict[str, object] | None = _spec(100)
    args = ["--stages", "maif-solo:100"]
    if case == "other-steps":
        args = ["--stages", "maif-solo:200"]
    elif case == "other-set":
        args += ["--set", "ppo.lr=1e-3"]
    elif case == "no-spec":
        spec = None
    d = _finished_stage(tmp_path / "out", spec)
    if case == "garbage-spec":
        (d / "curriculum_stage.json").write_bytes(b"\xff{")
    r = curriculum(*args, "--out", tmp_path / "out")
    assert r.returncode == 2, r.stdout + r.stderr
    assert "trained otherwise" in one_line(r.stderr)
    assert "skipped" not in r.stdout
    assert (d / "actor.safetensors").read_bytes() == b"weights"
