"""``ppo.critic_warmup_updates``: the first K updates of a run train the critic alone (a warm
actor is not pushed by a fresh critic's first advantages); from update K + 1 both learn, and a
bad value is refused naming the field."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sdhn_sim.envs import make_env
from sdhn_train import cli
from sdhn_train.algorithms.registry import get_algorithm
from sdhn_train.collector import RolloutCollector
from sdhn_train.config import Config
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.ppo import PPOLearner


def _params(module: torch.nn.Module) -> list[torch.Tensor]:
    return [p.detach().clone() for p in module.parameters()]


def _same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


@pytest.mark.parametrize("algo", ["sdhn", "mappo"])
def test_actor_waits_for_the_critic_then_learns(algo: str) -> None:
    env = make_env("maif-tiny", num_envs=2, seed=0, max_steps=12)
    cfg = Config()
    cfg.ppo.rollout_len = 8
    cfg.ppo.critic_warmup_updates = 2
    learner = get_algorithm(algo).build_learner(cfg, EnvInfo.of(env), np.random.default_rng(0))
    assert isinstance(learner, PPOLearner)
    col = RolloutCollector(env, learner.actor, rollout_len=8)
    for update in range(3):
        actor_before, critic_before = _params(learner.actor), _params(learner.critic)
        rollout, _ = col.collect(None)
        metrics = learner.update(rollout)
        assert not _same(_params(learner.critic), critic_before), update
        warming = update < 2
        assert _same(_params(learner.actor), actor_before) == warming, update
        assert (metrics["losses/actor_grad_norm"] == 0.0) == warming, metrics
        assert np.isfinite(metrics["losses/policy_loss"])  # still logged while the actor waits


@pytest.mark.parametrize("value", ["-1", "1.5", "true"])
def test_bad_warmup_is_refused_naming_the_field(value: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--set", f"ppo.critic_warmup_updates={value}"]) == 2
    err = capsys.readouterr().err
    assert "ppo.critic_warmup_updates" in err, err
