"""QMIX: Rashid, T., Samvelyan, M., de Witt, C.S., Farquhar, G., Foerster, J.N., Whiteson, S.,
"QMIX: Monotonic Value Function Factorisation for Deep Multi-Agent Reinforcement Learning",
ICML 2018.

Mixer: Q_tot = w2(s)^T ELU(W1(s)^T Q + b1(s)) + V(s), with hypernetworks producing W1 and w2
and an absolute value keeping them non-negative (monotonic in every Q_i); on the value-mixing
learner (``sdhn_train.learners.value_mixing``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from sdhn_policy.actor_torch import Actor
from sdhn_train.algorithms.base import Settings
from sdhn_train.envinfo import EnvInfo, actor_spec
from sdhn_train.learners.base import Learner
from sdhn_train.learners.value_mixing import Mixer, ValueMixingConfig, ValueMixingLearner
from sdhn_train.sections import need_positive, opt


@dataclass
class QMIXConfig(ValueMixingConfig):
    """QMIX's section ``qmix``: the value-mixing learner's settings (also HGCN-MIX's) and the
    mixer's sizes."""

    mixer_embed: int = opt(32, "mixing network embedding size")
    hypernet_hidden: int = opt(64, "hypernetwork hidden size")

    def validate(self) -> None:
        super().validate()
        need_positive("qmix", {"mixer_embed": self.mixer_embed,
                               "hypernet_hidden": self.hypernet_hidden})


class QMixer(Mixer):
    """Monotonic mixing network with hypernetworks on the global state (Rashid et al. 2018)."""

    def __init__(self, state_size: int, num_robots: int, embed: int = 32,
                 hypernet_hidden: int = 64) -> None:
        super().__init__()
        self.num_robots, self.embed = num_robots, embed
        self.hyper_w1 = nn.Sequential(nn.Linear(state_size, hypernet_hidden), nn.ReLU(),
                                      nn.Linear(hypernet_hidden, num_robots * embed))
        self.hyper_b1 = nn.Linear(state_size, embed)
        self.hyper_w2 = nn.Sequential(nn.Linear(state_size, hypernet_hidden), nn.ReLU(),
                                      nn.Linear(hypernet_hidden, embed))
        self.hyper_v = nn.Sequential(nn.Linear(state_size, embed), nn.ReLU(),
                                     nn.Linear(embed, 1))

    def forward(self, q: Tensor, obs: Tensor, state: Tensor) -> Tensor:
        lead = q.shape[:-1]
        w1 = self.hyper_w1(state).abs().reshape(*lead, self.num_robots, self.embed)
        hidden = torch.nn.functional.elu((q.unsqueeze(-2) @ w1).squeeze(-2) + self.hyper_b1(state))
        w2 = self.hyper_w2(state).abs()
        return (hidden * w2).sum(-1) + self.hyper_v(state).squeeze(-1)


def value_mixing_learner(cfg: Settings, info: EnvInfo, rng: np.random.Generator, mixer: Mixer,
                         default_lr: float) -> ValueMixingLearner:
    """Agent net (the shared actor architecture) + ``mixer`` on the value-mixing learner, with
    the ``qmix`` section's settings (QMIX and HGCN-MIX)."""
    ppo = cfg.ppo
    return ValueMixingLearner(
        Actor(actor_spec(cfg.actor, info)), mixer, cfg.section(QMIXConfig),
        lr=ppo.lr if ppo.lr is not None else default_lr, gamma=ppo.gamma,
        reward_scale=ppo.reward_scale, max_grad_norm=ppo.max_grad_norm,
        num_envs=cfg.env.num_envs, info=info, rng=rng)


class QMIX:
    """QMIX (Rashid et al. 2018): monotonic hypernetwork mixer on the global state."""

    name = "qmix"
    config = QMIXConfig
    data_parallel = False
    default_lr = 5e-4

    def build_learner(self, cfg: Settings, info: EnvInfo, rng: np.random.Generator) -> Learner:
        q = cfg.section(QMIXConfig)
        mixer = QMixer(info.state_size, info.num_robots, q.mixer_embed, q.hypernet_hidden)
        return value_mixing_learner(cfg, info, rng, mixer, self.default_lr)
