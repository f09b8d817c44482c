"""Learning tests: trained policies complete MAIF formations (success and makespan, not return).

Training defaults of issue 13: egocentric features (``maif-ego/1``), the ``corrected`` reward,
training on many maps (``instance_set: large``), 100-step training episodes. One robot alone
(maif-solo, MAPPO, 100k steps, ~20 s) learns to reach its goal; four robots (maif-tiny) start
from that actor (warm start) and learn to complete the formation together. Greedy evaluation on
the first EVAL instances of the fixed training set and of the held-out set, at the task's
500-step limit. The measured values behind each threshold are written next to it.
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
SOLO_STEPS = 100_000
# maif-solo, MAPPO, seed 1, 100k steps: success 0.99 / 0.99 (training / held-out set), makespan
# 16.6 / 16.8 against a lower bound of 16.0 (17 s on one core).
SOLO_SUCCESS, SOLO_RATIO = 0.9, 1.15
TINY_STEPS = 200_000
# maif-tiny, warm start from the maif-solo actor, seed 1 (its zero-shot success is 0.32 / 0.28):
# this test at 200k: SDHN 0.88 / 0.64 (97 s), MAPPO 0.82 / 0.62 (33 s), makespan 16.8-17.4
# against 16.0; at 150k SDHN 0.74 / 0.52, MAPPO 0.64 / 0.54. With the fused GRU (equal to 1e-5,
# so a different float trajectory) at 200k: SDHN 1.00 / 0.80, MAPPO 0.84 / 0.52: the threshold
# sits well above the warm start's zero-shot 0.32 / 0.28 and below what one seed's numerics move.
# From scratch both stay at 0 success for the first ~250k steps (all robots learn to wait first).
TINY_SUCCESS, TINY_RATIO = 0.45, 1.3


def _cfg(env: str, algo: str, steps: int, root: Path) -> Config:
    cfg = Config()
    cfg.env.name, cfg.env.max_steps, cfg.env.instance_set = env, 100, "large"
    cfg.algo.name = algo
    cfg.train.seed, cfg.train.total_steps = 1, steps
    cfg.eval.interval, cfg.eval.instances = 1, EVAL  # > 0: build the evaluation envs
    cfg.log.tensorboard, cfg.log.progress, cfg.log.root = False, False, str(root)
    return cfg


def train(cfg: Config, run_dir: Path) -> Trainer:
    tr = Trainer(cfg, run_dir=run_dir)
    tr.run_dir.mkdir(parents=True)
    while tr.global_step < cfg.train.total_steps:
        tr.train_iteration()
    return tr


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
    assert np.isfinite(result["eval/episodic_return"])


@pytest.fixture(scope="module")
def solo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, float]]:
    """A maif-solo MAPPO actor file and its evaluation."""
    root = tmp_path_factory.mktemp("solo")
    cfg = _cfg("maif-solo", "mappo", SOLO_STEPS, root)
    cfg.env.num_envs, cfg.ppo.rollout_len, cfg.ppo.num_minibatches = 16, 64, 2
    tr = train(cfg, root / "run")
    from sdhn_policy.weights import save_actor_file

    path = root / "solo_actor.safetensors"
    save_actor_file(path, tr.learner.export_actor(1))
    return path, tr.evaluate()


@pytest.mark.learning
def test_one_robot_reaches_its_goal(solo: tuple[Path, dict[str, float]]) -> None:
    check(solo[1], "maif-solo", SOLO_SUCCESS, SOLO_RATIO)


@pytest.mark.learning
@pytest.mark.parametrize("algo", ["sdhn", "mappo"])
def test_four_robots_complete_maif_tiny(algo: str, solo: tuple[Path, dict[str, float]],
                                        tmp_path: Path) -> None:
    cfg = _cfg("maif-tiny", algo, TINY_STEPS, tmp_path)
    cfg.actor.init_from = str(solo[0])
    check(train(cfg, tmp_path / algo).evaluate(), "maif-tiny", TINY_SUCCESS, TINY_RATIO)
