"""The learner re-runs the recurrent actor over stored sequences exactly as the collector ran it."""

from __future__ import annotations

import numpy as np
import torch

from sdhn_sim.envs import make_env
from sdhn_train.algorithms.sdhn import SDHN
from sdhn_train.collector import RolloutCollector
from sdhn_train.config import Config
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.ppo import PPOLearner


def test_replayed_log_probs_equal_behaviour_log_probs() -> None:
    env = make_env("maif-tiny", num_envs=3, seed=0, max_steps=7)  # episodes end inside rollouts
    cfg = Config()
    cfg.actor.use_robot_id = True
    learner = SDHN().build_learner(cfg, EnvInfo.of(env), np.random.default_rng(0))
    assert isinstance(learner, PPOLearner)
    with torch.no_grad():
        for p in learner.actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    col = RolloutCollector(env, learner.actor, rollout_len=20)
    col.collect(None)  # start the second rollout mid-episode with a non-zero hidden state
    rollout, _ = col.collect(None)
    assert rollout.truncated.any() and np.abs(rollout.actor_h0).sum() > 0
    r = {"obs": torch.from_numpy(rollout.obs), "resets": torch.from_numpy(rollout.resets()),
         "actor_h0": torch.from_numpy(rollout.actor_h0)}
    r["actor_in"] = learner.actor.with_robot_id(r["obs"])  # as PPOLearner.update builds it
    with torch.no_grad():
        logits = learner._actor_logits(r, torch.arange(3))
    logp = torch.log_softmax(logits, -1).gather(-1, torch.from_numpy(rollout.actions)[..., None])
    torch.testing.assert_close(logp.squeeze(-1), torch.from_numpy(rollout.log_probs),
                               atol=1e-5, rtol=0)
