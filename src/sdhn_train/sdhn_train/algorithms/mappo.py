"""MAPPO: the shared actor and an MLP critic on the global state, no target critic, on the PPO
learner."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from torch import Tensor, nn

from sdhn_train.algorithms.base import Settings, ppo_learner
from sdhn_train.envinfo import EnvInfo
from sdhn_train.learners.base import Learner
from sdhn_train.learners.ppo import Critic, CriticOutput
from sdhn_train.nets import mlp
from sdhn_train.sections import need


@dataclass
class MAPPOConfig:
    critic_hidden: list[int] = field(default_factory=lambda: [64, 64],
                                     metadata={"help": "MLP critic widths"})

    def validate(self) -> None:
        need(len(self.critic_hidden) >= 1 and all(h >= 1 for h in self.critic_hidden),
             "mappo.critic_hidden", "one or more widths >= 1", self.critic_hidden)


class MLPCritic(Critic):
    """MAPPO's centralised critic: V(s) from the global state, shared by all N robots."""

    def __init__(self, state_size: int, num_robots: int, hidden: tuple[int, ...] = (64, 64)):
        super().__init__()
        self.num_robots = num_robots
        self.net = nn.Sequential(mlp([state_size, *hidden]), nn.Linear(hidden[-1], 1))

    def forward_sequence(self, obs: Tensor, state: Tensor, h0: Tensor,
                         resets: Tensor) -> CriticOutput:
        values = self.net(state).expand(*state.shape[:-1], self.num_robots)
        hiddens = h0.unsqueeze(0).expand(state.shape[0], *h0.shape)
        return CriticOutput(values, hiddens, values.new_zeros(()))

    def value_step(self, obs: Tensor, state: Tensor, h: Tensor) -> Tensor:
        return self.net(state).expand(*state.shape[:-1], self.num_robots)


class MAPPO:
    name = "mappo"
    config = MAPPOConfig
    data_parallel = True
    default_lr = 3e-4
    default_target_tau = 1.0

    def build_learner(self, cfg: Settings, info: EnvInfo, rng: np.random.Generator) -> Learner:
        critic = MLPCritic(info.state_size, info.num_robots,
                           tuple(cfg.section(MAPPOConfig).critic_hidden))
        return ppo_learner(cfg, info, rng, critic, default_lr=self.default_lr,
                           default_target_tau=self.default_target_tau)
